"""Implicit (backward Euler) integration, Baraff & Witkin 1998 (docs/physics.md, integrators).

One linearised Newton step per time step h:

    (M + h·(D + C) + h²·H) Δv = h·(f(x, v) − h·H·v),   v ← v + Δv,   x ← x + h·v

where ``H ≈ −∂f/∂x`` is a positive semi-definite approximation of the
stiffness, ``C`` the strain-rate damping matrix (``−C·v`` is the material's damping force:
β times the material part of each element's stiffness, ``Material.strain_damping``; with the
paper's absolute damping instead, ``C = λ·M``), and ``D`` the diagonal linearisation of air drag
(``2·C_air·σ²·|n·u|`` per particle, g/s). ``H + C/h`` is assembled once per Newton pass as one
block-sparse matrix
(:class:`~cloth_gym.sim.implicit.bundles.Matrix`, a 3×3 block per pair of particles sharing an
element), each force adding its blocks from its own module (:mod:`cloth_gym.sim.forces`):

* stretch: the exact edge Jacobian ``p'(r)·d̂d̂ᵀ + (p/r)·(I − d̂d̂ᵀ)`` with the
  transverse term clamped at 0 in compression (p < 0), which keeps H PSD;
* bending: ``k·JᵀJ`` with ``b = ê2 − ê1`` (|b| ≈ ψ for small ψ), ``J = ∂b/∂x``
  — the Gauss–Newton term of ``½k|b|²``, well defined at the flat state where
  ∇ψ is not — with ``k = max(dT/dψ, T/ψ, 0)`` (the tangent for bending in the
  plane of the triple, the secant for turning that plane);
* shear: Gauss–Newton ``k·∇γ∇γᵀ`` with ``k = max(dT/dφ, 0)``.

The linear system is solved by preconditioned conjugate gradients; pinned
particles are filtered out (their rows and columns removed, Δv = 0).
Preconditioners (``preconditioner=``):

* ``"jacobi"``: 3×3 block diagonal;
* ``"lines"``: exact block-tridiagonal solves along warp lines and along weft
  lines, averaged, ``½(L_warp⁻¹ + L_weft⁻¹)``, each line's matrix its principal submatrix of A
  with the couplings two steps along it bounded onto the diagonal: it captures the stiff stretch
  coupling (alone, stretch gives a condition number of ~3) but not shear, whose near-rigid
  rotation modes need coarse-grid information, so it pays only for small steps;
* ``"band"`` (what ``"auto"`` picks for small lattices: 11 × 11, ribbons): the whole matrix,
  penalty included, factored by a banded Cholesky in the order of the shorter lattice lines, but
  for the blocks beyond the band (the two ends of a bending triple across lines), each replaced
  by a bound on its particles' diagonal blocks that keeps it SPD
  (:func:`~cloth_gym.sim.implicit.band.band_assemble`). Exact without bending (one CG
  iteration); its cost, ``3N·(3w + 3)²`` for lines of w − 1 particles, limits it to small lattices;
* ``"multigrid"`` (what ``"auto"`` picks from 1000 particles, but for small steps below 4000):
  a geometric V-cycle on the lattice, coarsened by
  2 in each direction, with the coarse operators *rediscretised* (the same
  KES model on a 2σ lattice whose positions are injected from the fine one),
  bilinear interpolation, full-weighting restriction, one damped line-smoother
  sweep before and after, and a dense solve at the coarsest level.

The package, one module per stage of the solve: :mod:`~cloth_gym.sim.implicit.solver` (the
:class:`ImplicitEuler` settings and what a call keeps in ``State.solver``),
:mod:`~cloth_gym.sim.implicit.step` (the step as a list of named stages),
:mod:`~cloth_gym.sim.implicit.levels` (lattice levels and stencils),
:mod:`~cloth_gym.sim.implicit.bundles` (the solver's typed bundles),
:mod:`~cloth_gym.sim.implicit.matrix` (block-sparse algebra),
:mod:`~cloth_gym.sim.implicit.lines` and :mod:`~cloth_gym.sim.implicit.band` (preconditioners),
:mod:`~cloth_gym.sim.implicit.multigrid`, :mod:`~cloth_gym.sim.implicit.precondition` (each
preconditioner family's kernels, picked by type when the step compiles, so a step compiles only the
family it uses), :mod:`~cloth_gym.sim.implicit.contact` (contact and friction) and
:mod:`~cloth_gym.sim.implicit.cg` (the PCG solve).
"""

from .solver import (AUTO_BAND_WORK, AUTO_LINES_PARTICLES, AUTO_LINES_STIFFNESS, AUTO_MULTIGRID_PARTICLES,
                     ImplicitEuler, ImplicitStepInfo)

__all__ = ["ImplicitEuler", "ImplicitStepInfo", "AUTO_BAND_WORK", "AUTO_LINES_PARTICLES", "AUTO_LINES_STIFFNESS",
           "AUTO_MULTIGRID_PARTICLES"]
