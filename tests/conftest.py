import numpy as np
import pytest

from cloth_gym.sim import ForceOptions, Rectangle, build_cloth


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def only(**on):
    """ForceOptions with every force off except those named (model via model=...)."""
    model = on.pop("model", "kes")
    flags = dict(gravity=False, stretch=False, bending=False, shear=False, air=False, damping=False)
    flags.update(on)
    return ForceOptions(model=model, **flags)


@pytest.fixture
def small_cloth():
    return build_cloth(Rectangle(2.0, 2.0), "thick_cotton", sigma=0.5)
