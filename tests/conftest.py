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


def lattice_areas(nx, ny):
    """(nx·ny,) the area shares (in σ²) of a full nx × ny lattice in row-major order: 1 inside, ½ on
    an edge, ¼ at a corner (the hand values of area lumping)."""
    wx = np.ones(nx)
    wx[[0, -1]] = 0.5
    wy = np.ones(ny)
    wy[[0, -1]] = 0.5
    return np.outer(wx, wy).ravel()


@pytest.fixture
def small_cloth():
    return build_cloth(Rectangle(2.0, 2.0), "thick_cotton", sigma=0.5)
