"""cloth_gym: Gymnasium environments on a KES-measured particle cloth simulator.

The simulator (:mod:`cloth_gym.sim`) implements the particle model of Mitsui
et al. (docs/physics.md): nonlinear, anisotropic stretch, bending and shear fitted from
KES measurements, with Breen's model as the baseline. CGS units throughout.
"""

from .errors import (ClothGymError, ConfigError, ConfigTypeError, InsideObstacle, MaterialError, MaterialTypeError,
                     RemoteEnvError, ResetNeeded, SimulationDiverged, SizeError, SnapshotError, SnapshotTypeError,
                     StabilityError)
from .materials import KESCurve, Material, available_materials, fit_kes_curve, load_material
from . import envs as _envs  # registers the Gymnasium ids (lazy entry points: no numba, no torch)

__version__ = "0.1.0"


def warmup(envs: bool = True, verbose: bool = True) -> float:
    """Compile every simulator kernel now (about three CPU minutes, once; cached on disk).

    See :func:`cloth_gym._warmup.warmup`; returns the CPU seconds it took.
    """
    from ._warmup import warmup as _warmup

    return _warmup(envs=envs, verbose=verbose)


__all__ = [
    "ClothGymError", "ConfigError", "ConfigTypeError", "InsideObstacle", "MaterialError", "MaterialTypeError",
    "RemoteEnvError", "ResetNeeded", "SimulationDiverged", "SizeError", "SnapshotError", "SnapshotTypeError",
    "StabilityError",
    "KESCurve", "Material", "available_materials", "fit_kes_curve", "load_material", "warmup", "__version__",
]
