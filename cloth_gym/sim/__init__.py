"""The particle cloth simulator: model, state, forces, integrators."""

from .forces import compute_forces
from .integrators import StabilityEstimate, SymplecticEuler, explicit_stability_limit
from .lattice import Disc, Rectangle, Ribbon, build_cloth
from .model import Control, ForceOptions, Model, SolverMemory, State

__all__ = [
    "build_cloth", "Rectangle", "Disc", "Ribbon", "ForceOptions", "Model", "State", "SolverMemory", "Control",
    "compute_forces", "SymplecticEuler", "explicit_stability_limit", "StabilityEstimate",
]
