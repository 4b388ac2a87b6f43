"""The explicit integrator and its stability estimate.

:class:`SymplecticEuler` (a :class:`~cloth_gym.sim.solver.SolverBase`) is the explicit integrator (semi-implicit Euler:
``v ← v + Δt·F/m``, then ``x ← x + Δt·v``). It estimates its own stability
limit from the model (:func:`explicit_stability_limit`, docs/physics.md, integrators) and refuses a
larger Δt, or splits it into substeps when asked to. Every step checks the
state; a non-finite or exploding state raises
:class:`~cloth_gym.errors.SimulationDiverged` naming the step, time and
particle — never silent NaNs.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np

from ..errors import SimulationDiverged, StabilityError
from ..units import G
from ..validation import one_of, real
from ._numba import copy_into, cycles, njit
from .bundles import DIVERGE_REASONS, N_PHASES, P_FORCES, P_SOLVE, Status, Unlimited
from .collision_kernels import COLLISION_PASS_BITS
from .forces import (breen_bend_torque, breen_shear_torque, breen_stretch_tension, eval_forces, kes_bend_torque,
                     kes_shear_torque)
from .model import Model
from .solver import (SolverBase, check_dt, check_steps, check_strain_guard, effective_mass, make_world,
                     strain_guard)
from .substep import finish_substep, needs_previous_positions

__all__ = ["StabilityEstimate", "explicit_stability_limit", "SymplecticEuler", "StepInfo"]

#: what a diverged explicit step can still change
EXPLICIT_HINT = "reduce dt or the safety factor, or use the implicit integrator (ImplicitEuler)"


@dataclass(frozen=True)
class StabilityEstimate:
    """Estimated stability limit of explicit (symplectic Euler) integration.

    The stiffest mode of each force, linearised about the flat rest state
    (stretch at ``strain_percent``), with ω in rad/s; symplectic Euler needs
    ``Δt < 2/ω``. Stretch: alternating mode of a lattice line,
    ``ω² = 4k/m``, ``k = dF/dr`` of an edge (``100·c1·G`` for KES at rest).
    Bending: checkerboard out-of-plane mode, ``ω² = 16·(k_warp + k_weft)/(m·σ²)``
    with ``k = max dT/dψ`` near ψ = 0. Shear: ``ω² = 16·k/(m·σ²)`` with
    ``k = max dT/dφ`` near φ = 0. The Hessians add, so the total uses
    ``ω² = ω_stretch² + ω_bend² + ω_shear²`` (an upper bound on the largest
    eigenvalue of the sum). ``dt_limit_warp_s`` / ``dt_limit_weft_s`` are the
    stretch-only limits ``2/(2·sqrt(k/m))`` of each direction (the table of docs/physics.md, integrators).
    """

    dt_limit_s: float
    dt_limit_stretch_s: float
    dt_limit_warp_s: float
    dt_limit_weft_s: float
    omega_stretch: float
    omega_bend: float
    omega_shear: float
    edge_stiffness_dyne_per_cm: float
    particle_mass_g: float
    strain_percent: float

    def as_dict(self) -> dict:
        return asdict(self)


def _max_slope(fn, hi: float) -> float:
    """max |dT/dx| of a torque law on [0, hi] (geometric grid: the regularised root is steep at 0)."""
    xs = np.concatenate([[0.0], np.geomspace(1e-9, hi, 600)])
    ts = np.array([fn(x) for x in xs])
    return float(np.max(np.abs(np.diff(ts) / np.diff(xs))))


def explicit_stability_limit(model: Model, strain_percent: float | None = None) -> StabilityEstimate:
    """Estimate the largest stable Δt (s) of symplectic Euler for ``model``.

    ``strain_percent``: strain at which the (nonlinear) stretch stiffness is
    taken. Default 0 for the KES law (its tangent at rest, which reproduces the
    table of docs/physics.md, integrators) and 10 % for Breen's quartic law, which has no stiffness
    at rest. A cloth under large strain is stiffer than at rest: the
    integrator's ``safety`` factor leaves room for that.
    """
    o = model.options
    sigma = model.sigma
    m = effective_mass(model)
    breen = o.model == "breen"
    if strain_percent is None:
        strain_percent = 10.0 if breen else 0.0
    eps = float(strain_percent)

    k_stretch = 0.0
    k_dir = (0.0, 0.0)
    if o.stretch:
        if breen:
            d = sigma * eps / 100.0
            k_stretch = 20.0 * o.breen_c0 * d ** 3 / sigma ** 5
            # compression side at the same strain
            h = 1e-7 * sigma
            r = sigma - d
            k_c = abs(breen_stretch_tension(r + h, sigma, o.breen_c0) - breen_stretch_tension(r - h, sigma, o.breen_c0)) / (2 * h)
            k_stretch = max(k_stretch, k_c)
            k_dir = (k_stretch, k_stretch)
        else:
            c = model.stretch_coef
            k_dir = tuple(float(k) for k in 100.0 * G * (c[:, 0] + 2.0 * c[:, 1] * eps))
            k_stretch = max(k_dir)
    w2_stretch = 4.0 * k_stretch / m

    w2_bend = 0.0
    if o.bending:
        law = breen_bend_torque if breen else kes_bend_torque
        x0 = o.sqrt_reg_curvature
        # a clamp's triples (bend_length ½) turn over half the length: their torque law is law(ψ; ℓ)/ℓ
        ell = float(model.bend_length[model.bend_length > 0].min(initial=1.0))
        kb = [_max_slope(lambda p, c=model.bend_coef[d]: law(p, c[0], c[1], c[2], sigma * ell, x0) / ell, 0.3)
              for d in (0, 1)]
        w2_bend = 16.0 * (kb[0] + kb[1]) / (m * sigma * sigma)

    w2_shear = 0.0
    if o.shear:
        law = breen_shear_torque if breen else kes_shear_torque
        c = model.shear_coef
        ks = _max_slope(lambda p: law(p, c[0], c[1], c[2], sigma, o.sqrt_reg_shear), 0.3)
        w2_shear = 16.0 * ks / (m * sigma * sigma)

    w_total = math.sqrt(w2_stretch + w2_bend + w2_shear)
    w_s = math.sqrt(w2_stretch)
    # the strain-rate damping (β) of the same modes: symplectic Euler on x'' = −ω²x − βω²x' is
    # stable for h²ω² + 2βω²h < 4, i.e. h < −β + sqrt(β² + 4/ω²)
    beta = model.material.strain_damping if (o.damping and o.damping_model == "strain-rate") else 0.0
    return StabilityEstimate(
        dt_limit_s=(-beta + math.sqrt(beta * beta + 4.0 / w_total ** 2)) if w_total > 0 else math.inf,
        dt_limit_stretch_s=2.0 / w_s if w_s > 0 else math.inf,
        dt_limit_warp_s=math.sqrt(m / k_dir[0]) if k_dir[0] > 0 else math.inf,
        dt_limit_weft_s=math.sqrt(m / k_dir[1]) if k_dir[1] > 0 else math.inf,
        omega_stretch=w_s,
        omega_bend=math.sqrt(w2_bend),
        omega_shear=math.sqrt(w2_shear),
        edge_stiffness_dyne_per_cm=k_stretch,
        particle_mass_g=m,
        strain_percent=eps,
    )


@njit
def integrate_symplectic_euler(x, v, f, inv_mass, dt):
    """``v += Δt·f/m``, ``x += Δt·v``. Pinned particles (inv_mass 0) are kinematic: their velocity
    is prescribed (held in the state, 0 for a fixed pin) and only ``x += Δt·v`` applies."""
    for p in range(x.shape[0]):
        w = inv_mass[p]
        for k in range(3):
            v[p, k] += dt * f[p, k] * w
            x[p, k] += dt * v[p, k]


@njit
def run_symplectic_euler(n_steps, dt, x, v, inv_mass, wind, fd, world, guard, prof):
    """``n_steps`` steps of Δt = ``dt`` s on positions ``x`` (cm) and velocities ``v`` (cm/s), in place.

    ``fd``: :class:`~cloth_gym.sim.bundles.ForceData`; ``world``: :class:`~cloth_gym.sim.bundles.World`
    (obstacles translate with ``world.vel``, ``world.offset`` is advanced in place); ``guard``:
    :class:`~cloth_gym.sim.bundles.Guard`; ``prof`` (PROFILE_SIZE,) int64: cycle counts per
    :class:`~cloth_gym.sim.bundles.Phase` and of the whole loop, added to. Returns (status, step,
    particle, value) of the first bad state (status ``Status.OK``: none)."""
    start = cycles()
    n = x.shape[0]
    f = np.empty((n, 3))
    normals = np.empty((n, 3))
    keep_prev = needs_previous_positions(world)
    vt_pairs = np.zeros((0, 2), dtype=np.int64)  # self-collision pair lists, kept across steps
    ee_pairs = np.zeros((0, 2), dtype=np.int64)
    ref_x = np.full((n if (world.collision.flags & COLLISION_PASS_BITS) != 0 else 0, 3), np.inf)
    x_prev = np.empty((n, 3))
    for s in range(n_steps):
        t0 = cycles()
        eval_forces(x, v, wind, fd, normals, f)
        t1 = cycles()
        if keep_prev:
            copy_into(x_prev, x)
        integrate_symplectic_euler(x, v, f, inv_mass, dt)
        prof[P_FORCES] += t1 - t0
        prof[P_SOLVE] += cycles() - t1
        status, p, value, vt_pairs, ee_pairs = finish_substep(x, v, x_prev, inv_mass, dt, fd, world, guard,
                                                              vt_pairs, ee_pairs, ref_x, prof)
        if status != Status.OK:
            prof[N_PHASES] += cycles() - start
            return status, s, p, value
    prof[N_PHASES] += cycles() - start
    return Status.OK, n_steps, -1, 0.0


@dataclass(frozen=True)
class StepInfo:
    """What one call of ``step`` did: substeps taken and the substep length (s)."""

    substeps: int
    dt_sub: float


class SymplecticEuler(SolverBase):
    """Explicit symplectic Euler with a stability check.

    Parameters
    ----------
    safety
        fraction of the estimated stability limit that Δt may use (0, 1].
        The estimate is sharp for a smooth law (a symmetric one, α = 1: stable
        at 0.9×, divergent at 1.1×), but the KES law has a kink at ε = 0
        (compression is α = 0.1 times softer), and symplectic Euler is not
        energy-stable across such a kink near its limit: an undamped cotton
        cloth perturbed by 1e-6 σ grows without bound at 0.9× and slowly at
        0.7×, and stays bounded at 0.5× (tests/test_integrator.py). Hence the
        default 0.5.
    on_unstable
        what ``step`` does with a Δt above ``safety × limit``:
        ``"raise"`` (default) a :class:`~cloth_gym.errors.StabilityError` that
        states the limit; ``"substep"`` split Δt into enough equal substeps;
        ``"ignore"`` take the step anyway (the divergence check still raises).
    max_speed
        speed (cm/s) above which the state counts as exploded.
    max_strain_percent
        edge strain (%) above which the state counts as exploded; None (the default): the
        model's :attr:`~cloth_gym.sim.model.Model.strain_guard_percent` (100 % for the KES model,
        no strain guard for Breen's).
    design_strain_percent
        strain (%) at which the stretch stiffness of the
        stability estimate is taken. The KES stretch laws stiffen with strain
        (cotton warp: 3× at 1 %), so a limit taken at rest is exceeded as soon
        as the cloth is loaded. Default: 1 % for the KES model, 10 % for
        Breen's (whose quartic law has no stiffness at rest).
    """

    def __init__(self, safety: float = 0.5, on_unstable: Literal["raise", "substep", "ignore"] = "raise",
                 max_speed: float = 1.0e5, max_strain_percent: float | None = None,
                 design_strain_percent: float | None = None):
        self.safety = real("safety", safety, 0.0, 1.0, lo_open=True)
        self.on_unstable = one_of("on_unstable", on_unstable, ("raise", "substep", "ignore"))
        self.max_speed = real("max_speed", max_speed, 0.0, 3e10, lo_open=True, unit="cm/s")
        self.max_strain_percent = check_strain_guard(max_strain_percent)
        if design_strain_percent is not None:
            design_strain_percent = real("design_strain_percent", design_strain_percent, 0.0, 100.0, unit="%")
        self.design_strain_percent = design_strain_percent
        self._limit: tuple[Model, StabilityEstimate] | None = None  # the last model's estimate

    def stability(self, model: Model) -> StabilityEstimate:
        """:func:`explicit_stability_limit` of ``model`` at ``design_strain_percent``, kept for the
        last model asked about (the model itself is the key: an id could be reused). The profile
        (:attr:`last_profile`) has ``forces``; ``solve``, the velocity and position update;
        ``obstacles``, ``collision``, ``checks``; the implicit phases are 0 here."""
        if self._limit is None or self._limit[0] is not model:
            strain = self.design_strain_percent
            if strain is None:
                strain = 10.0 if model.options.model == "breen" else 1.0
            self._limit = (model, explicit_stability_limit(model, strain_percent=strain))
        return self._limit[1]

    def substeps_for(self, model: Model, dt: float) -> int:
        """Number of equal substeps ``step`` uses for a step of ``dt`` seconds."""
        dt = check_dt("dt", dt)
        allowed = self.safety * self.stability(model).dt_limit_s
        if dt <= allowed or self.on_unstable == "ignore":
            return 1
        if self.on_unstable == "substep":
            return check_steps("dt", math.ceil(dt / allowed * (1 + 1e-12)))
        est = self.stability(model)
        raise StabilityError(
            dt, est.dt_limit_s,
            f"dt = {dt:.3g} s exceeds the explicit stability limit {est.dt_limit_s:.3g} s "
            f"(x safety {self.safety} = {allowed:.3g} s; stretch alone: {est.dt_limit_stretch_s:.3g} s) "
            f"for {model.material.name} at sigma = {model.sigma} cm and {est.strain_percent:g} % strain; use dt <= {allowed:.3g} s, "
            "on_unstable='substep', or the implicit integrator")

    def _run(self, model, state, control, n, h, context) -> StepInfo:
        wind = np.zeros(3) if control is None else np.asarray(control.wind, dtype=float)
        inv_mass = model.particle_inv_mass if control is None else control.inv_mass(model)
        world = make_world(model, state, control)
        guard = Unlimited(self.max_speed, strain_guard(model, self.max_strain_percent), 0.0, 1)
        status, s, p, value = self._timed(run_symplectic_euler, n, h, state.particle_q, state.particle_qd, inv_mass,
                                          wind, model.force_data, world, guard)
        done = n if status == Status.OK else s + 1
        state.step += done
        state.time += done * h
        if status != Status.OK:
            raise SimulationDiverged(state.step, state.time, p, DIVERGE_REASONS[Status(status)], value,
                                     EXPLICIT_HINT)
        return StepInfo(n, h)
