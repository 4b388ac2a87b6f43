"""The implicit solver's own typed bundles: what its kernels read besides the simulator's
(:mod:`cloth_gym.sim.bundles`).

Static, built once per model (:mod:`~cloth_gym.sim.implicit.levels`): :class:`Levels`, the lattice
levels with their stencils. Scratch, overwritten every step: :class:`Work` and :class:`CGWork`.
Per call: :class:`SolveOptions` (the settings, with the preconditioner's family: :class:`Band`,
:class:`OneLevel` or :class:`Multigrid`, and Newton's passes: :class:`OnePass` or
:class:`NewtonPasses`) and :class:`Carry` (what a run hands from step to step and, through
``State.solver``, from call to call). :class:`Matrix` is one level's linearised
stiffness as a block-sparse matrix.
"""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple

import numpy as np



class Precond(IntEnum):
    """The preconditioner code of :class:`SolveOptions` (multigrid: LINES with more than one level)."""

    JACOBI = 0  # 3×3 block diagonal
    LINES = 1  # block-tridiagonal solves along warp and weft lines (the multigrid smoother too)
    BAND_WARP = 2  # banded Cholesky, particles in warp-line order
    BAND_WEFT = 3  # banded Cholesky, particles in weft-line order



JACOBI, LINES, BAND_WARP, BAND_WEFT = (int(c) for c in Precond)


# The preconditioner's family, :attr:`SolveOptions.family`. numba compiles a kernel once per type
# of its arguments, so each family is its own type (the value is the number of levels): a step
# compiled for the band factor holds none of the smoothers' or the V-cycle's code, and a user of
# one preconditioner compiles only its code (:mod:`~cloth_gym.sim.implicit.precondition` picks each
# family's kernels while numba types the step).
class Band(NamedTuple):
    """The band factor (``Precond.BAND_WARP`` or ``BAND_WEFT``), one level."""

    levels: int


class OneLevel(NamedTuple):
    """Lines or block Jacobi (``Precond.LINES``, ``JACOBI``) on one level."""

    levels: int


class Multigrid(NamedTuple):
    """The V-cycle over more than one level, smoothed by lines or block Jacobi."""

    levels: int


# Newton's passes, :attr:`SolveOptions.newton`: two types, like the families above, so that a step
# taking one linearised pass holds none of the further passes' code
# (:func:`~cloth_gym.sim.implicit.newton.newton_passes` is resolved by this type).
class OnePass(NamedTuple):
    """One linearised Newton pass (Baraff–Witkin): the first solve is the step's answer."""

    passes: int


class NewtonPasses(NamedTuple):
    """Up to ``passes`` Newton passes a step (more than one), stopped by ``newton_tol``."""

    passes: int


def newton_kind(passes: int) -> OnePass | NewtonPasses:
    """The :attr:`SolveOptions.newton` value for ``passes`` Newton passes a step."""
    return OnePass(1) if passes <= 1 else NewtonPasses(int(passes))



class Matrix(NamedTuple):
    """The linearised stiffness H (dyne/cm) of one lattice level as a block-sparse matrix (block
    CSR on the lattice's stencil): row q's blocks are ``vals[row_off[q]:row_off[q+1]]`` (3×3 each),
    in the columns ``col[...]`` (ascending); ``diag[q]`` indexes block (q, q). Every force adds its
    blocks to ``vals`` (:func:`~cloth_gym.sim.forces.linearise_forces`); everything the solver does
    with H — products, diagonal blocks, line couplings, the band and dense factors — reads this."""

    row_off: np.ndarray
    col: np.ndarray
    diag: np.ndarray
    vals: np.ndarray



class Levels(NamedTuple):
    """The lattice levels of the multigrid hierarchy (one level without multigrid), concatenated:
    level l's particle rows are ``n_off[l]:n_off[l+1]`` of every particle-sized array, its edges
    rows ``e_off[l]:e_off[l+1]``, its bending triples ``b_off``, shear corners ``c_off``, injected
    nodes ``i_off``, warp and weft line offsets ``lwo_off`` and ``lfo_off``. Indices inside a level
    are local. Static: built once per model (:class:`~cloth_gym.sim.implicit.levels.Hierarchy`)."""

    n_levels: int
    n_off: np.ndarray
    e_off: np.ndarray
    b_off: np.ndarray
    c_off: np.ndarray
    i_off: np.ndarray
    lwo_off: np.ndarray
    lfo_off: np.ndarray
    sigma: np.ndarray  # (L,) lattice spacing of each level, cm
    inject: np.ndarray  # fine index of each coarse node
    P_idx: np.ndarray  # (N, 4) coarse parents of each fine node (−1: none)
    P_w: np.ndarray  # (N, 4) their bilinear weights
    rest: np.ndarray
    edges: np.ndarray
    edge_dir: np.ndarray
    edge_width: np.ndarray
    triples: np.ndarray
    bend_dir: np.ndarray
    bend_width: np.ndarray
    bend_length: np.ndarray
    corners: np.ndarray
    lw_off: np.ndarray  # warp lines (CSR offsets, particles in line order, each particle's slot)
    lw_idx: np.ndarray
    lw_slot: np.ndarray
    lf_off: np.ndarray  # weft lines
    lf_idx: np.ndarray
    lf_slot: np.ndarray
    row_off: np.ndarray  # the block matrices' rows: level l's at n_off[l] + l : n_off[l+1] + l + 1
    col: np.ndarray  # their columns, level l's blocks at z_off[l]:z_off[l+1] (level-local indices)
    z_off: np.ndarray
    diag: np.ndarray  # (N,) each particle's diagonal block
    e_map: np.ndarray  # (E, 4) the blocks (a,a), (a,b), (b,a), (b,b) of each edge
    b_map: np.ndarray  # (B, 9) the 3×3 blocks of each bending triple
    c_map: np.ndarray  # (S, 9) the 3×3 blocks of each shear corner
    lw_prev: np.ndarray  # (N,) block coupling each particle to its predecessor on its warp line (−1: first)
    lf_prev: np.ndarray  # (N,) the same on its weft line
    lw_prev2: np.ndarray  # (N,) block coupling each particle to the one two steps back on its warp line (−1: none)
    lf_prev2: np.ndarray  # (N,) the same on its weft line



class Work(NamedTuple):
    """Scratch of the solve on every level, overwritten each step (nothing in it outlives a step):
    positions, the stiffness matrices' blocks, lumped mass and free flags, diagonal blocks and their inverses, the
    line factors, the V-cycle's vectors, the dense coarsest (or band) factor and the contact
    penalty blocks."""

    xl: np.ndarray
    vals: np.ndarray  # the blocks of every level's Matrix
    mdiag: np.ndarray
    free: np.ndarray
    Dblk: np.ndarray
    Dinv: np.ndarray
    lw_piv: np.ndarray
    lw_low: np.ndarray
    lf_piv: np.ndarray
    lf_low: np.ndarray
    lw_add: np.ndarray  # (N,) the line matrices' diagonal raise, by slot (set_line_couplings)
    lf_add: np.ndarray
    work: np.ndarray
    rin: np.ndarray
    zl: np.ndarray
    res: np.ndarray
    corr: np.ndarray
    chol: np.ndarray  # the coarsest level's dense factor (float64)
    band: np.ndarray  # the band preconditioner's factor ((0, 1) when unused; band_cholesky)
    cvec: np.ndarray
    cout: np.ndarray
    pen: np.ndarray



class SolveOptions(NamedTuple):
    """The implicit solve's settings (:class:`~cloth_gym.sim.implicit.ImplicitEuler`): CG relative
    tolerance, absolute floor (cm/s), iteration cap, :class:`Precond` code, the line smoother's
    damping ω, BDF2 or backward Euler, Newton passes per step (:class:`OnePass` or
    :class:`NewtonPasses`, each its own type), whether each step's solve starts
    from the previous step's velocity change, whether a step is solved again with raised friction
    dampers where the first solve left particles sliding more slowly than their dampers assumed
    (:func:`~cloth_gym.sim.implicit.contact.refine_friction`), the Newton tolerance (cm/s) and
    whether solves in free flight keep momentum exactly
    (:func:`~cloth_gym.sim.implicit.cg.exact_momentum`), the largest correction any particle may
    keep, the line search, the preconditioner's family (:class:`Band`, :class:`OneLevel`,
    :class:`Multigrid`), consistent with ``precond`` and the number of levels, and whether the
    collision pass's displacements are fed back into the step's linear system
    (:func:`~cloth_gym.sim.implicit.coupling.couple_collision_response`)."""

    tol: float
    vtol: float
    max_iter: int
    precond: int
    omega: float
    bdf2: bool
    newton: OnePass | NewtonPasses  # Newton passes per step (its type selects the compiled code)
    warm_start: bool
    friction_resolve: bool
    newton_tol: float  # cm/s: Newton stops once the nonlinear residual's mass-weighted RMS is below (0: never)
    momentum_exact: bool  # in free flight, each solve's Δv corrected to the exact momentum balance
    newton_tol_max: float  # cm/s: ... and every particle's correction is within this (0: no per-particle test)
    line_search: bool  # Newton corrections taken as α·δ, α halved until the residual falls enough
    family: Band | OneLevel | Multigrid  # the preconditioner's family (its type selects the compiled code)
    couple_collisions: bool  # the collision pass's displacements fed back into the step's linear system



class CGWork(NamedTuple):
    """PCG's vectors (N, 3): residual, preconditioned residual, search direction, A·p."""

    r: np.ndarray
    z: np.ndarray
    p: np.ndarray
    Ap: np.ndarray



class Carry(NamedTuple):
    """What a run carries from step to step, and through ``State.solver`` from call to call: BDF2's
    previous positions ``x`` (cm) and velocities ``v`` (cm/s), set when ``ok[0] == 1`` (else the next
    step is backward Euler, which sets them); and the last step's velocity change ``dv`` (cm/s),
    set when ``dv_ok[0] == 1``, the first guess of the next step's solve (``SolveOptions.warm_start``)."""

    x: np.ndarray
    v: np.ndarray
    ok: np.ndarray
    dv: np.ndarray
    dv_ok: np.ndarray
