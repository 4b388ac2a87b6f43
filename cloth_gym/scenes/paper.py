"""The paper's validation scenes (§5) as data, and a loop that runs one until it settles.

Each builder returns a :class:`Scene`: the immutable :class:`~cloth_gym.sim.model.Model`
plus the numbers needed to run and measure it (start positions, recommended
integrator and step, settle criterion, the drape pedestal or the table). A scene is
data, not code: :func:`make_integrator` and :func:`run_until_settled` read it.

Each builder switches on only the forces and collision passes its scene needs
and says which in its docstring:

* :func:`drape_test` — the drape tester: a disc of cloth on a circular pedestal
  (the paper's 10-inch disc on a 5-inch pedestal, or Cusick's 30 cm on 18 cm);
* :func:`tablecloth_scene` — the paper's fig. 10: a 40 cm square on a 20 cm table;
* :func:`ribbon` — the paper's figs. 12–13: a strip falling onto the floor, folding
  onto itself, with or without angular momentum in the collision response.

Units: CGS (cm, g, s, dyne, erg).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from collections.abc import Iterable
from typing import Callable, Literal

import numpy as np

from ..errors import ConfigError, ConfigTypeError
from ..sim import Disc, ForceOptions, Ribbon, SymplecticEuler, build_cloth
from ..sim.collision import CollisionOptions
from ..sim.diagnostics import edge_strain, kinetic_energy
from ..sim.implicit import ImplicitEuler
from ..sim.model import Model, State
from ..sim.obstacles import Cylinder, Plane
from ..validation import flag, integer, one_of, real
from ..validation import seed as check_seed

__all__ = [
    "Scene", "SettleResult", "DRAPE_GEOMETRIES", "drape_test", "tablecloth_scene", "ribbon",
    "make_integrator", "run_until_settled", "settle_threshold", "table_corner_strain", "drape_metrics",
]

INCH_CM = 2.54

DRAPE_GEOMETRIES = {
    # name: (specimen diameter, pedestal diameter), cm
    "paper": (10.0 * INCH_CM, 5.0 * INCH_CM),  # the paper's §5: 10-inch disc on a 5-inch pedestal
    "cusick": (30.0, 18.0),  # Cusick's drape meter (BS 5058): 30 cm disc on an 18 cm pedestal
}
"""Drape-test geometries: ``name → (cloth diameter, pedestal diameter)`` in cm."""


@dataclass(frozen=True, eq=False)
class Scene:
    """A scene of the paper: the model and how to run and measure it (data only).

    Attributes
    ----------
    name
        ``"drape_test"``, ``"tablecloth"`` or ``"ribbon"``.
    model
        the immutable cloth model (forces, obstacles, collision options).
    initial_q
        (N, 3) start positions, cm (the model's rest positions, perhaps perturbed).
    initial_qd
        (N, 3) start velocities, cm/s.
    integrator
        recommended integrator, ``"implicit"`` (:class:`~cloth_gym.sim.implicit.ImplicitEuler`)
        or ``"explicit"`` (:class:`~cloth_gym.sim.SymplecticEuler`, substepping).
    max_dt
        largest (sub)step of the implicit integrator, s (contact needs ≤ 1 ms at σ = 1 cm).
    frame_dt
        time between recorded frames, s.
    max_time_s
        simulated time after which :func:`run_until_settled` gives up, s.
    ke_threshold_erg
        settled when the kinetic energy stays below this, erg.
    hold_s
        ... for at least this long, s.
    pedestal_radius_cm
        drape test only: the pedestal's radius, cm (else ``None``).
    table_half_cm
        tablecloth only: half the table's side, cm (else ``None``).
    center_xy
        (2,) centre of the pedestal / table in the floor plane, cm.
    description
        one line for reports.
    """

    name: str
    model: Model
    initial_q: np.ndarray
    initial_qd: np.ndarray
    integrator: Literal["implicit", "explicit"]
    max_dt: float
    frame_dt: float
    max_time_s: float
    ke_threshold_erg: float
    hold_s: float
    pedestal_radius_cm: float | None = None
    table_half_cm: float | None = None
    center_xy: tuple = (0.0, 0.0)
    description: str = ""
    params: dict = field(default_factory=dict)

    def state(self) -> State:
        """A new state at the scene's start (positions ``initial_q``, velocities ``initial_qd``), t = 0."""
        return State(np.array(self.initial_q, dtype=float), np.array(self.initial_qd, dtype=float))


def _positive(name, v, hi=1e12):
    return real(name, v, 0.0, hi, lo_open=True)


def _kes_or_breen(model):
    return one_of("model", model, ("kes", "breen"))


def settle_threshold(model: Model, rms_speed_cm_s: float) -> float:
    """Kinetic energy (erg) of the whole cloth moving at ``rms_speed_cm_s``: ``½·M·v²``."""
    v = _positive("rms_speed_cm_s", rms_speed_cm_s, 1e4)
    return 0.5 * float(np.sum(model.particle_mass)) * v ** 2


def _implicit_dt(sigma: float) -> float:
    """Implicit substep with obstacle contact: 1 ms at σ ≥ 1 cm, 0.5 ms at σ = 0.5 cm (in between: σ ms)."""
    return 1e-3 * min(1.0, max(0.5, sigma))


# ============================================================================ drape test
def drape_test(material="thick_cotton", model: str = "kes", sigma: float = 1.0,
               geometry: Literal["paper", "cusick"] = "paper", drop_cm: float = 0.25,
               perturb_cm: float = 0.05, seed: int = 0, self_collision: bool = False,
               rms_speed_cm_s: float = 0.5, max_time_s: float = 6.0) -> Scene:
    """The drape tester (paper §5, fig. 8): a disc of cloth released flat just above a pedestal.

    Geometry (``geometry``, :data:`DRAPE_GEOMETRIES`): ``"paper"`` a 10-inch (25.4 cm)
    disc on a 5-inch (12.7 cm) diameter pedestal; ``"cusick"`` a 30 cm disc on an 18 cm
    pedestal. The pedestal is a :class:`~cloth_gym.sim.obstacles.Cylinder` with its top
    at z = 0, centred on the origin, 20 cm tall, standing on a floor (a
    :class:`~cloth_gym.sim.obstacles.Plane` at z = −20 cm) that the cloth never reaches.
    The disc's centre is on the axis, warp along x, at z = ``drop_cm``.

    Forces: gravity, stretch, bending, shear (the ``model``'s laws: ``"kes"`` proposed,
    ``"breen"`` baseline), air drag (no wind) and viscous damping. Collision: the two
    analytic obstacles (pedestal and floor, material's friction and restitution); **no**
    self-collision unless ``self_collision`` (a drape's folds hang side by side without
    touching at these sizes; with it on, the run costs several times more).

    Symmetry breaking: a perfectly flat disc on a square lattice drapes into a shape with
    the lattice's 4-fold symmetry; a real specimen never starts perfectly flat. The start
    heights get a seeded uniform perturbation in ``[0, perturb_cm]`` (0: none).

    Settled: kinetic energy below that of the whole cloth at an rms speed of
    ``rms_speed_cm_s`` for 0.25 s; give up at ``max_time_s``.
    """
    one_of("geometry", geometry, sorted(DRAPE_GEOMETRIES))
    sigma = _positive("sigma", sigma, 10.0)
    _kes_or_breen(model)
    perturb_cm = real("perturb_cm", perturb_cm, 0.0, 1.0, unit="cm")
    seed = check_seed("seed", seed)
    self_collision = flag("self_collision", self_collision)
    max_time_s = _positive("max_time_s", max_time_s, 1e4)
    d_cloth, d_ped = DRAPE_GEOMETRIES[geometry]
    height = 20.0
    obstacles = [Cylinder((0.0, 0.0, 0.0), d_ped / 2, height), Plane((0.0, 0.0, -height))]
    m = build_cloth(Disc(d_cloth), material, sigma=sigma, options=ForceOptions.paper(model=model),
                    origin=(0.0, 0.0, _positive("drop_cm", drop_cm, 50.0)), obstacles=obstacles,
                    contact_thickness=0.1,
                    collision=CollisionOptions(self_collision=True) if self_collision else None)
    q = m.particle_q0.copy()
    if perturb_cm > 0:
        q[:, 2] += np.random.default_rng(seed).uniform(0.0, perturb_cm, m.particle_count)
    return Scene(
        name="drape_test", model=m, initial_q=q, initial_qd=np.zeros_like(q), integrator="implicit",
        max_dt=_implicit_dt(sigma), frame_dt=0.05, max_time_s=float(max_time_s),
        ke_threshold_erg=settle_threshold(m, rms_speed_cm_s), hold_s=0.25, pedestal_radius_cm=d_ped / 2,
        description=f"drape test ({geometry}: {d_cloth:.1f} cm disc on {d_ped:.1f} cm pedestal), "
                    f"{m.material.name}, {model}, sigma {sigma} cm",
        params=dict(material=m.material.name, model=model, sigma_cm=sigma, geometry=geometry,
                    cloth_diameter_cm=d_cloth, pedestal_diameter_cm=d_ped, drop_cm=drop_cm,
                    perturb_cm=perturb_cm, seed=seed, self_collision=self_collision,
                    rms_speed_cm_s=rms_speed_cm_s),
    )


# ============================================================================ tablecloth
def tablecloth_scene(material="thick_cotton", model: str = "kes", sigma: float = 1.0, size_cm: float = 40.0,
                     table_cm: float = 20.0, drop_cm: float = 2.0, friction: float | None = None,
                     rms_speed_cm_s: float = 0.5, max_time_s: float = 5.0) -> Scene:
    """The paper's tablecloth (fig. 10, fig. 11): a ``size_cm`` square (40 cm) released flat
    ``drop_cm`` above a square table of side ``table_cm`` (20 cm), top at z = 0, on a floor at
    z = −80 cm; built by :func:`cloth_gym.scenes.basic.tablecloth` (warp along x).

    Forces: gravity, stretch, bending, shear (``model``: ``"kes"`` or ``"breen"``), air drag,
    damping. Collision: the table (a :class:`~cloth_gym.sim.obstacles.Box`) and the floor; no
    self-collision (the four hanging flaps do not touch). The fig. 10 claim is measured by
    :func:`table_corner_strain`: Breen's quartic stretch law is almost slack at small strain,
    so the cloth hanging over the table's corners stretches far more than with the KES law.
    """
    from .basic import tablecloth as _tablecloth

    sigma = _positive("sigma", sigma, 10.0)
    _kes_or_breen(model)
    max_time_s = _positive("max_time_s", max_time_s, 1e4)
    m = _tablecloth(material, size_cm=size_cm, table_cm=table_cm, sigma=sigma, drop_cm=drop_cm,
                    model=model, friction=friction)
    q = m.particle_q0.copy()
    return Scene(
        name="tablecloth", model=m, initial_q=q, initial_qd=np.zeros_like(q), integrator="implicit",
        max_dt=_implicit_dt(sigma), frame_dt=0.05, max_time_s=float(max_time_s),
        ke_threshold_erg=settle_threshold(m, rms_speed_cm_s), hold_s=0.25, table_half_cm=table_cm / 2,
        description=f"tablecloth {size_cm:g} cm on a {table_cm:g} cm table, {m.material.name}, {model}, "
                    f"sigma {sigma} cm",
        params=dict(material=m.material.name, model=model, sigma_cm=sigma, size_cm=size_cm, table_cm=table_cm,
                    drop_cm=drop_cm, friction=friction, rms_speed_cm_s=rms_speed_cm_s),
    )


def drape_metrics(scene: Scene, state: State, n_bins: int = 360) -> dict:
    """The drape test's measurements of ``state``: ``drape_coefficient``
    (:func:`~cloth_gym.metrics.drape_coefficient` over the pedestal), ``node_count`` and the
    projected outline ``outline_radius_cm`` (``n_bins`` values, cm) it is counted on.

    The outline samples the lattice edges as well as the particles
    (:func:`~cloth_gym.metrics.outline_radius` with ``edges``): from the particles alone a
    coarse cloth's outline has a notch between every two boundary particles, which the node
    count takes for folds (thick cotton at σ = 1 cm: 11 nodes instead of 4)."""
    from ..metrics import drape_coefficient, node_count, outline_radius

    if scene.pedestal_radius_cm is None:
        raise ConfigError("scene", "drape_metrics needs a drape-test scene")
    m = scene.model
    r = outline_radius(state.particle_q, scene.center_xy, n_bins=n_bins, edges=m.edge_indices)
    return {"drape_coefficient": float(drape_coefficient(m, state, scene.pedestal_radius_cm, scene.center_xy)),
            "node_count": int(node_count(r)), "outline_radius_cm": r}


def table_corner_strain(scene: Scene, state: State, radius_cm: float = 4.0) -> dict:
    """Strain (percent) of the edges near the table's four vertical corner edges (fig. 10).

    An edge counts when its midpoint lies, in the floor (xy) plane, within ``radius_cm`` of
    a table corner ``center ± (table_half, table_half)`` and below the table top (z < 0.5 cm):
    the cloth that hangs over the corners. Returns ``max`` and ``mean`` over those edges,
    and ``max_all`` over the whole cloth (percent)."""
    if scene.table_half_cm is None:
        raise ConfigError("scene", "table_corner_strain needs a tablecloth scene")
    m = scene.model
    q = state.particle_q
    e = m.edge_indices
    mid = 0.5 * (q[e[:, 0]] + q[e[:, 1]])
    eps = edge_strain(m, state)
    h = scene.table_half_cm
    c = np.asarray(scene.center_xy, dtype=float)
    near = np.zeros(len(e), dtype=bool)
    for sx in (-1.0, 1.0):
        for sy in (-1.0, 1.0):
            d = np.hypot(mid[:, 0] - c[0] - sx * h, mid[:, 1] - c[1] - sy * h)
            near |= d < radius_cm
    near &= mid[:, 2] < 0.5
    sel = eps[near]
    return {"max": float(sel.max()) if sel.size else 0.0, "mean": float(sel.mean()) if sel.size else 0.0,
            "max_all": float(eps.max()), "edges": int(sel.size), "radius_cm": float(radius_cm)}


# ============================================================================ ribbon
def ribbon(material="thin_wool", angular_momentum: bool = True, length_cm: float = 30.0, width_cm: float = 3.0,
           sigma: float = 1.0, drop_cm: float = 0.6, tilt_cm_s: float = 5.0, response: str = "paper",
           model: str = "kes", max_time_s: float = 2.0, rms_speed_cm_s: float = 0.5) -> Scene:
    """The paper's falling ribbon (figs. 12–13): a ``length_cm`` × ``width_cm`` strip held
    vertically (warp, its length, along z; its lowest edge ``drop_cm`` above the floor at z = 0)
    and released with a small tilt (horizontal velocity rising linearly to ``tilt_cm_s`` at the
    top) so it folds onto itself as it piles up on the floor.

    Forces: gravity, stretch, bending, shear (``model``), damping; **no** air drag (kept out
    so that the comparison isolates the collision response). Collision: the floor
    (:class:`~cloth_gym.sim.obstacles.Plane`) and **self-collision** (vertex–triangle and
    edge–edge), with the rigid-triangle response (docs/physics.md, collision), impulse magnitude
    ``response`` (``"paper"``: eq. 22), and rotation of the struck triangle on or off
    (``angular_momentum``, the paper's fig. 13 comparison).
    """
    sigma = _positive("sigma", sigma, 10.0)
    _kes_or_breen(model)
    angular_momentum = flag("angular_momentum", angular_momentum)
    tilt_cm_s = real("tilt_cm_s", tilt_cm_s, -1e4, 1e4, unit="cm/s")
    max_time_s = _positive("max_time_s", max_time_s, 1e4)
    R = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # local warp → world z
    opts = ForceOptions.paper(model=model, air=False)
    m = build_cloth(Ribbon(length_cm, width_cm), material, sigma=sigma, options=opts, rotation=R,
                    origin=(0.0, 0.0, length_cm / 2 + _positive("drop_cm", drop_cm, 100.0)),
                    obstacles=[Plane()],
                    collision=CollisionOptions(self_collision=True, response=response,
                                               angular_momentum=bool(angular_momentum)))
    q = m.particle_q0.copy()
    qd = np.zeros_like(q)
    z0 = q[:, 2].min()
    qd[:, 0] = tilt_cm_s * (q[:, 2] - z0) / max(float(np.ptp(q[:, 2])), 1e-9)
    return Scene(
        name="ribbon", model=m, initial_q=q, initial_qd=qd, integrator="implicit", max_dt=_implicit_dt(sigma),
        frame_dt=0.02, max_time_s=float(max_time_s), ke_threshold_erg=settle_threshold(m, rms_speed_cm_s),
        hold_s=0.2,
        description=f"ribbon {length_cm:g} x {width_cm:g} cm, {m.material.name}, angular momentum "
                    f"{'on' if angular_momentum else 'off'}, sigma {sigma} cm",
        params=dict(material=m.material.name, model=model, sigma_cm=sigma, length_cm=length_cm, width_cm=width_cm,
                    drop_cm=drop_cm, tilt_cm_s=tilt_cm_s, response=response,
                    angular_momentum=bool(angular_momentum)),
    )


# ============================================================================ running
def make_integrator(scene: Scene):
    """The scene's recommended integrator: ``ImplicitEuler(max_dt=scene.max_dt)`` or
    ``SymplecticEuler(on_unstable="substep")``."""
    if scene.integrator == "implicit":
        return ImplicitEuler(max_dt=scene.max_dt)
    if scene.integrator == "explicit":
        return SymplecticEuler(on_unstable="substep")
    raise ConfigError("scene.integrator", f"must be 'implicit' or 'explicit', got {scene.integrator!r}")


@dataclass
class SettleResult:
    """What :func:`run_until_settled` recorded.

    state: the final state (positions cm, velocities cm/s).
    times: (F,) frame times, s; kinetic_energy: (F,) erg, at those times (frame 0: the start).
    settled: whether the criterion was met before ``max_time_s``.
    settle_time_s: :func:`cloth_gym.metrics.settle_time` of the series (``None`` if not settled).
    wall_s: wall-clock time of the run, s.
    frames: rendered frames (H, W, 3) uint8, if a renderer was given.
    snapshots: ``{time: State}`` copies at the requested snapshot times.
    """

    state: State
    times: np.ndarray
    kinetic_energy: np.ndarray
    settled: bool
    settle_time_s: float | None
    wall_s: float
    frames: list = field(default_factory=list)
    snapshots: dict = field(default_factory=dict)


def _settle_setup(scene_or_model, integrator, max_time_s, ke_threshold, frame_dt, hold_s, state):
    """:func:`run_until_settled`'s model, integrator, limits (s, erg) and start state: a scene's own
    unless given, a bare model's as given (then integrator, max_time_s and ke_threshold are
    required), each checked."""
    if isinstance(scene_or_model, Scene):
        sc = scene_or_model
        model = sc.model
        integrator = make_integrator(sc) if integrator is None else integrator
        max_time_s = sc.max_time_s if max_time_s is None else max_time_s
        ke_threshold = sc.ke_threshold_erg if ke_threshold is None else ke_threshold
        frame_dt = sc.frame_dt if frame_dt is None else frame_dt
        hold_s = sc.hold_s if hold_s is None else hold_s
        state = sc.state() if state is None else state
    elif isinstance(scene_or_model, Model):
        model = scene_or_model
        if integrator is None or max_time_s is None or ke_threshold is None:
            raise ConfigError("run_until_settled", "a bare Model needs integrator, max_time_s and ke_threshold")
        frame_dt = 0.05 if frame_dt is None else frame_dt
        hold_s = 0.25 if hold_s is None else hold_s
        state = model.state() if state is None else state
    else:
        raise ConfigError("scene_or_model", f"must be a Scene or a Model, got {type(scene_or_model).__name__}")
    max_time_s = _positive("max_time_s", max_time_s, 1e4)
    frame_dt = _positive("frame_dt", frame_dt, max_time_s)
    if not callable(getattr(integrator, "step", None)):
        raise ConfigTypeError("integrator", f"needs a step(model, state, control, dt) method, got {integrator!r}")
    if not isinstance(state, State):
        raise ConfigTypeError("state", f"expected a State, got {type(state).__name__}")
    ke_threshold = real("ke_threshold", ke_threshold, 0.0, 1e30, lo_open=True, unit="erg")
    hold_s = real("hold_s", hold_s, 0.0, 1e4, unit="s")

    return model, integrator, max_time_s, ke_threshold, frame_dt, hold_s, state


def run_until_settled(scene_or_model, integrator=None, max_time_s: float | None = None,
                      ke_threshold: float | None = None, *, frame_dt: float | None = None,
                      hold_s: float | None = None, state: State | None = None, control=None,
                      render: Callable | None = None, render_every: int = 1,
                      snapshot_times=(), min_time_s: float = 0.0, progress: Callable | None = None) -> SettleResult:
    """Advance frame by frame until the kinetic energy stays below ``ke_threshold`` for ``hold_s``;
    a divergence raises the integrator's :class:`~cloth_gym.errors.SimulationDiverged`.

    Parameters
    ----------
    scene_or_model
        a :class:`Scene` (its values are the defaults of every argument below)
        or a bare :class:`~cloth_gym.sim.model.Model` (then ``integrator``, ``max_time_s``,
        ``ke_threshold`` are required; ``frame_dt`` defaults to 0.05 s, ``hold_s`` to 0.25 s).
    integrator
        anything with ``step(model, state, control, dt)``; default :func:`make_integrator`.
    max_time_s, ke_threshold, frame_dt, hold_s
        give up after ``max_time_s`` of simulated time (s); the kinetic energy threshold (erg), the
        time between frames (KE samples, renders) and how long KE must stay below it (s).
    state
        start state (default ``scene.state()`` / ``model.state()``); advanced in place.
    render
        optional ``f(model, state) -> (H, W, 3) uint8``, called every ``render_every`` frames and on the last.
    snapshot_times, min_time_s
        simulated times (s) at which to keep a copy of the state (nearest frame); never stop
        before ``min_time_s``.
    progress
        optional ``f(time_s, kinetic_energy_erg)`` called after every frame.
    """
    from ..metrics import settle_time

    model, integrator, max_time_s, ke_threshold, frame_dt, hold_s, state = _settle_setup(
        scene_or_model, integrator, max_time_s, ke_threshold, frame_dt, hold_s, state)
    if render is not None and not callable(render):
        raise ConfigTypeError("render", f"must be callable or None, got {render!r}")
    render_every = integer("render_every", render_every, 1, 10**9)
    min_time_s = real("min_time_s", min_time_s, 0.0, 1e4, unit="s")
    if isinstance(snapshot_times, (str, bytes)) or not isinstance(snapshot_times, Iterable):
        raise ConfigTypeError("snapshot_times", f"must be a list of times in s, got {snapshot_times!r}")
    snap_left = sorted(real("snapshot_times", t, 0.0, 1e4, unit="s") for t in snapshot_times)
    snapshots = {}
    frames = []
    t0_state = state.time
    times = [0.0]
    ke = [kinetic_energy(model, state)]
    if render is not None:
        frames.append(render(model, state))
    while snap_left and snap_left[0] <= 0.5 * frame_dt:
        snapshots[snap_left.pop(0)] = state.copy()
    n_max = int(math.ceil(max_time_s / frame_dt - 1e-9))
    below_since = None
    settled = False
    wall0 = time.perf_counter()
    for k in range(1, n_max + 1):
        integrator.step(model, state, control, frame_dt)
        t = round(state.time - t0_state, 12)  # s; the substeps' float sum, without its last-digit noise
        e = kinetic_energy(model, state)
        times.append(t)
        ke.append(e)
        if progress is not None:
            progress(t, e)
        while snap_left and snap_left[0] <= t + 0.5 * frame_dt:
            snapshots[snap_left.pop(0)] = state.copy()
        if e < ke_threshold:
            below_since = t if below_since is None else below_since
        else:
            below_since = None
        settled = below_since is not None and t - below_since >= hold_s - 1e-9 and t >= min_time_s
        if render is not None and (k % render_every == 0 or settled or k == n_max):
            frames.append(render(model, state))
        if settled:
            break
    wall = time.perf_counter() - wall0
    times_a = np.asarray(times)
    ke_a = np.asarray(ke)
    st = settle_time(ke_a, times_a, ke_threshold) if settled else None
    for t in snap_left:  # asked for beyond the end: the final state
        snapshots[t] = state.copy()
    return SettleResult(state=state, times=times_a, kinetic_energy=ke_a, settled=settled, settle_time_s=st,
                        wall_s=wall, frames=frames, snapshots=snapshots)
