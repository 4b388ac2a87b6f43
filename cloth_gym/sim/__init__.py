"""The particle cloth simulator: model, state, forces, integrators."""

from .forces import compute_forces
from .integrators import StabilityEstimate, SymplecticEuler, explicit_stability_limit
from .model import Control, Disc, ForceOptions, Model, Rectangle, Ribbon, State, build_cloth

__all__ = [
    "build_cloth", "Rectangle", "Disc", "Ribbon", "ForceOptions", "Model", "State", "Control",
    "compute_forces", "SymplecticEuler", "explicit_stability_limit", "StabilityEstimate",
]
