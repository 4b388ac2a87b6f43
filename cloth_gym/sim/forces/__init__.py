"""The cloth's forces, one module each: what the particle model computes and the implicit solver
linearises.

* :mod:`.stretch` — lattice edges, KES (warp/weft) or Breen's law;
* :mod:`.bending` — triples along lattice lines;
* :mod:`.shear` — lattice corners;
* :mod:`.air` — air drag on the surface;
* :mod:`.gravity` — gravity and the paper's absolute-velocity damping.

The material's strain-rate damping (``ForceOptions.damping_model = "strain-rate"``) lives with
each elastic force (``damp_stretch``, ``damp_bending``, ``damp_shear``): it damps the rate of the
same strain the force resists, with that force's stiffness times ``Material.strain_damping``.

Each force's module is its one home: its scalar law (so tests can check it against hand values
and integrate it into energies), its ``eval_*`` kernel, which *adds* the force (dyne) into ``f``
(N, 3), and — for the elastic forces — its ``linearise_*`` kernel, which adds its 3×3 stiffness
blocks to the implicit solver's block matrix. :func:`eval_forces` and :func:`linearise_forces`
sum them. Formulas and sign conventions are those of the paper's proposed model and of Breen's
baseline (``docs/``).

Conventions: positions ``x`` in cm, velocities in cm/s, forces in dyne, torques in dyne·cm (per
radian of the angle they act on), stiffness in dyne/cm.
"""

from __future__ import annotations

import numpy as np

from .._numba import kernel_only, runtime
from ..bundles import Force, ForceData
from .air import air_linearisation, eval_air, vertex_normals
from .bending import (bend_slope, breen_bend_torque, breen_curvature, damp_bending, eval_bending, kes_bend_torque,
                      kes_curvature, linearise_bending)
from .common import PI, _cross, angle_geometry, bend_angle, edge_vector, kes_poly, reg_root, reg_root_deriv
from .gravity import eval_gravity_damping, lumped_mass
from .shear import breen_shear_torque, damp_shear, eval_shear, kes_shear_torque, linearise_shear, shear_slope
from .stretch import (breen_stretch_slope, breen_stretch_tension, damp_stretch, eval_stretch, kes_stretch_slope,
                      kes_stretch_tension, linearise_stretch, stretch_pull_and_slope)

# the Force bits as plain ints, for the kernels
GRAVITY, STRETCH, BENDING, SHEAR, AIR, DAMPING, BREEN, STRAIN_DAMPING = (int(b) for b in Force)

__all__ = [
    "eval_forces", "eval_forces_at", "eval_strain_damping", "linearise_forces", "compute_forces", "force_data",
    "force_flags",
    # stretch
    "kes_stretch_tension", "breen_stretch_tension", "kes_stretch_slope", "breen_stretch_slope",
    "stretch_pull_and_slope", "eval_stretch", "damp_stretch", "linearise_stretch",
    # bending
    "kes_curvature", "kes_bend_torque", "breen_curvature", "breen_bend_torque", "bend_slope", "eval_bending",
    "damp_bending", "linearise_bending",
    # shear
    "kes_shear_torque", "breen_shear_torque", "shear_slope", "eval_shear", "damp_shear", "linearise_shear",
    # air, gravity and damping
    "vertex_normals", "eval_air", "air_linearisation", "eval_gravity_damping", "lumped_mass",
    # shared helpers
    "PI", "reg_root", "reg_root_deriv", "kes_poly", "edge_vector", "angle_geometry", "bend_angle", "_cross",
    "GRAVITY", "STRETCH", "BENDING", "SHEAR", "AIR", "DAMPING", "BREEN", "STRAIN_DAMPING",
]


# ============================================================================ all forces
@kernel_only
def eval_forces(x, v, wind, fd, normals, f):
    """Total force (5) on every particle into ``f`` (overwritten), dyne; ``fd`` a
    :class:`~cloth_gym.sim.bundles.ForceData`, ``wind`` (3,) cm/s, ``normals`` (N, 3) scratch."""
    eval_forces_at(x, v, wind, fd, normals, f, runtime(True))


@kernel_only
def eval_forces_at(x, v, wind, fd, normals, f, with_strain_damping):
    """:func:`eval_forces`, leaving out the strain-rate damping when ``with_strain_damping`` is
    False (the implicit solver's first pass, whose matrix carries it)."""
    f[:] = 0.0
    flags = fd.flags
    breen = (flags & BREEN) != 0
    eval_gravity_damping(v, fd.mass, fd.gravity, fd.damping_rate, (flags & GRAVITY) != 0, (flags & DAMPING) != 0, f)
    if flags & STRETCH:
        eval_stretch(x, fd.edges, fd.edge_dir, fd.rest, fd.edge_width, fd.stretch_coef, fd.alpha, breen, fd.breen_c0,
                     f)
    if flags & BENDING:
        eval_bending(x, fd.triples, fd.bend_dir, fd.bend_width, fd.bend_length, fd.bend_coef, fd.sigma, fd.x0_curv,
                     breen, f)
    if flags & SHEAR:
        eval_shear(x, fd.corners, fd.shear_coef, fd.sigma, fd.x0_shear, breen, f)
    if flags & AIR:
        eval_air(x, v, fd.tris, wind, fd.c_air, fd.area, normals, f)
    if with_strain_damping and (flags & STRAIN_DAMPING) != 0:
        eval_strain_damping(x, v, fd, f)


@kernel_only
def eval_strain_damping(x, u, fd, f):
    """Add the strain-rate damping force ``−C(x)·u`` (dyne) of the elastic forces switched on in
    ``fd.flags`` at positions ``x`` (cm) and velocities ``u`` (cm/s) to ``f``; ``C`` is the damping
    matrix that :func:`linearise_forces` adds to the implicit matrix (β = ``fd.damping_time``)."""
    flags = fd.flags
    breen = (flags & BREEN) != 0
    beta = fd.damping_time
    if flags & STRETCH:
        damp_stretch(x, u, fd.edges, fd.edge_dir, fd.rest, fd.edge_width, fd.stretch_coef, fd.alpha, breen,
                     fd.breen_c0, beta, f)
    if flags & BENDING:
        damp_bending(x, u, fd.triples, fd.bend_dir, fd.bend_width, fd.bend_length, fd.bend_coef, fd.sigma,
                     fd.x0_curv, breen, beta, f)
    if flags & SHEAR:
        damp_shear(x, u, fd.corners, fd.shear_coef, fd.sigma, fd.x0_shear, breen, beta, f)


def force_flags(options) -> int:
    """:class:`~cloth_gym.sim.bundles.Force` bits from :class:`~cloth_gym.sim.model.ForceOptions`."""
    damping = Force.DAMPING if options.damping_model == "absolute" else Force.STRAIN_DAMPING
    bits = [(options.gravity, Force.GRAVITY), (options.stretch, Force.STRETCH), (options.bending, Force.BENDING),
            (options.shear, Force.SHEAR), (options.air, Force.AIR), (options.damping, damping),
            (options.model == "breen", Force.BREEN)]
    return sum(int(bit) for on, bit in bits if on)


def force_data(model) -> ForceData:
    """The model's :class:`~cloth_gym.sim.bundles.ForceData` (read it as ``model.force_data``: built once)."""
    m = model.material
    o = model.options
    return ForceData(
        flags=force_flags(o), mass=model.particle_mass, area=model.particle_area, gravity=model.gravity, damping_rate=float(m.damping),
        damping_time=float(m.strain_damping),
        alpha=float(m.compression_factor), c_air=float(m.air_drag), sigma=float(model.sigma),
        edges=model.edge_indices, edge_dir=model.edge_dir, rest=model.edge_rest_length, edge_width=model.edge_width,
        stretch_coef=model.stretch_coef, breen_c0=float(o.breen_c0), triples=model.bend_indices,
        bend_dir=model.bend_dir, bend_width=model.bend_width, bend_length=model.bend_length,
        bend_coef=model.bend_coef, x0_curv=float(o.sqrt_reg_curvature),
        corners=model.shear_indices, shear_coef=model.shear_coef, x0_shear=float(o.sqrt_reg_shear),
        tris=model.tri_indices)


def compute_forces(model, state, control=None, out: np.ndarray | None = None) -> np.ndarray:
    """Total force (dyne, (N, 3)) on each particle of ``state`` (pinned ones included)."""
    n = model.particle_count
    f = np.empty((n, 3)) if out is None else out
    wind = np.zeros(3) if control is None else np.asarray(control.wind, dtype=float)
    eval_forces(state.particle_q, state.particle_qd, wind, model.force_data, np.empty((n, 3)), f)
    return f


@kernel_only
def linearise_forces(x, fd, el, damp, maps, vals):
    """The stiffness approximation H (dyne/cm) of the elastic forces at positions ``x`` (cm) into the
    block matrix ``vals`` (nnz, 3, 3), overwritten: each force switched on in ``fd.flags`` adds its
    blocks (``linearise_stretch``, ``linearise_bending``, ``linearise_shear``). ``el`` holds the
    elements of the lattice level assembled: (sigma (cm), edges, edge_dir, rest, edge_width,
    triples, bend_dir, bend_width, bend_length, corners); the laws are ``fd``'s. ``damp`` = β/h adds the
    strain-rate damping matrix over the step h (0: none); ``maps`` = (edge, triple, corner) block
    indices into ``vals``."""
    vals[:] = 0.0
    flags = fd.flags
    breen = (flags & BREEN) != 0
    sigma, edges, edge_dir, rest, edge_width, triples, bend_dir, bend_width, bend_length, corners = el
    if flags & STRETCH:
        linearise_stretch(x, edges, edge_dir, rest, edge_width, fd.stretch_coef, fd.alpha, breen, fd.breen_c0, damp,
                          maps[0], vals)
    if flags & BENDING:
        linearise_bending(x, triples, bend_dir, bend_width, bend_length, fd.bend_coef, sigma, fd.x0_curv, breen, damp,
                          maps[1], vals)
    if flags & SHEAR:
        linearise_shear(x, corners, fd.shear_coef, sigma, fd.x0_shear, breen, damp, maps[2], vals)
