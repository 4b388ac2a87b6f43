"""Measurements on a state: strains, energies (CGS)."""

from __future__ import annotations

import numpy as np

from .model import WARP, WEFT, Model, State


def edge_strain(model: Model, state: State) -> np.ndarray:
    """(E,) engineering strain of every stretch edge, percent (``100·(r − σ)/σ``)."""
    e = model.edge_indices
    r = np.linalg.norm(state.particle_q[e[:, 1]] - state.particle_q[e[:, 0]], axis=1)
    return 100.0 * (r - model.edge_rest_length) / model.edge_rest_length


def strain_summary(model: Model, state: State) -> dict:
    """Max and mean tensile strain (percent) per direction."""
    eps = edge_strain(model, state)
    out = {}
    for name, d in (("warp", WARP), ("weft", WEFT)):
        sel = eps[model.edge_dir == d]
        out[f"max_strain_{name}_percent"] = float(sel.max()) if sel.size else 0.0
        out[f"mean_strain_{name}_percent"] = float(sel.mean()) if sel.size else 0.0
    return out


def kinetic_energy(model: Model, state: State) -> float:
    """Kinetic energy, erg (g·cm²/s²)."""
    return float(0.5 * np.sum(model.particle_mass[:, None] * state.particle_qd ** 2))


def gravity_energy(model: Model, state: State) -> float:
    """Gravitational potential energy relative to the rest configuration, erg."""
    dz = state.particle_q - model.particle_q0
    return float(-np.sum(model.particle_mass * (dz @ model.gravity)))
