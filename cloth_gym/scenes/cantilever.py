"""The cantilever bending test (the bending length of ASTM D1388): a strip of fabric clamped
horizontally at one end bends under its own weight. Its tip drop is a measure of the fabric's
bending stiffness against its weight, and a check of the lattice that no one tuned: the
continuum answer is the inextensible heavy elastica, ``dθ/ds = K(M)``, ``dM/ds = −q·(L − s)·cos θ``,
with the material's moment law M(K) (docs/physics.md, forces), θ(0) = 0 at the clamp and
M(L) = 0 at the free tip.

* :func:`cantilever_strip`: the strip's :class:`~cloth_gym.sim.model.Model`, clamped;
* :func:`settle_cantilever`: its rest state (implicit integrator, damped to rest);
* :func:`cantilever_tip_drop`: how far below the clamp the tip hangs, cm;
* :func:`heavy_elastica_tip_drop`: the continuum reference, cm.
"""

from __future__ import annotations

import math

import numpy as np

from ..materials import Material, load_material
from ..sim import ForceOptions, Rectangle, build_cloth
from ..sim.implicit import ImplicitEuler
from ..sim.model import Model, State
from ..units import G
from ..validation import one_of, real

__all__ = ["cantilever_strip", "settle_cantilever", "cantilever_tip_drop", "heavy_elastica_tip_drop"]

#: the strip's local axes → world for each direction: the direction tested runs along world x
_ALONG_X = {"warp": np.eye(3), "weft": np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])}


def cantilever_strip(material="thin_wool", overhang_cm: float = 4.0, sigma: float = 0.5, width_cm: float = 1.0,
                     direction: str = "warp", mass_lumping: str = "area", damping_per_s: float = 30.0) -> Model:
    """A strip ``overhang_cm`` long beyond its clamp and ``width_cm`` wide, its ``direction``
    (``"warp"`` or ``"weft"``) along world x, flat at z = 0: the clamp holds the particles at
    x ≤ 0 (the strip starts one σ inside it), the tip row is at x = ``overhang_cm``.

    Only weight and bending shape the rest state, so air drag is off and the material's damping is
    the absolute kind at ``damping_per_s`` (1/s), strong enough to settle the strip in a few
    seconds without moving where it settles. ``mass_lumping`` as :class:`~cloth_gym.sim.ForceOptions`.
    ``overhang_cm`` and ``width_cm`` must be whole multiples of σ."""
    one_of("direction", direction, tuple(_ALONG_X))
    overhang_cm = real("overhang_cm", overhang_cm, 0.0, 1e4, lo_open=True, unit="cm")
    width_cm = real("width_cm", width_cm, 0.0, 1e4, lo_open=True, unit="cm")
    damping_per_s = real("damping_per_s", damping_per_s, 0.0, 1e4, unit="1/s")
    mat = material if isinstance(material, Material) else load_material(material)
    options = ForceOptions(air=False, damping_model="absolute", mass_lumping=mass_lumping)
    length = overhang_cm + sigma  # one σ of fabric inside the clamp
    shape = Rectangle(length, width_cm) if direction == "warp" else Rectangle(width_cm, length)
    m = build_cloth(shape, mat.replace(damping=damping_per_s), sigma=sigma, options=options,
                    rotation=_ALONG_X[direction], origin=(overhang_cm / 2 - sigma / 2, 0.0, 0.0))
    return m.with_pinned(np.nonzero(m.particle_q0[:, 0] <= 1e-9 * sigma)[0])


def settle_cantilever(model: Model, duration_s: float = 6.0) -> State:
    """The strip's state after ``duration_s`` of implicit steps (5 ms, CG tolerance 1e-8) from
    flat: at rest for the strips of :func:`cantilever_strip` (its largest speed tells)."""
    state = model.state()
    ImplicitEuler(tol=1e-8).advance(model, state, None, duration_s, 5e-3)
    return state


def cantilever_tip_drop(model: Model, state: State) -> float:
    """How far (cm) the tip row (the particles farthest along x) hangs below the clamp's height, on average."""
    x = model.particle_q0[:, 0]
    tip = x >= x.max() - 1e-9 * model.sigma
    return float(-state.particle_q[tip, 2].mean())


def heavy_elastica_tip_drop(material="thin_wool", overhang_cm: float = 4.0, direction: str = "warp",
                            x0_curvature: float | None = None) -> float:
    """The continuum tip drop (cm) of an inextensible strip ``overhang_cm`` long, clamped
    horizontally, under its own weight ``q = W·g`` per unit area (module docstring), with the
    ``direction``'s bending law ``M(K) = (c0·K^½ + c1·K + c2·K²)·g`` per unit width (the root
    regularised as the simulator's, ``x0_curvature`` 1/cm; None: ``ForceOptions``' default).
    Solved by shooting on the clamp moment (scipy ``solve_ivp`` to 1e-10, ``brentq``)."""
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    one_of("direction", direction, tuple(_ALONG_X))
    mat = material if isinstance(material, Material) else load_material(material)
    x0 = ForceOptions().sqrt_reg_curvature if x0_curvature is None else float(x0_curvature)
    c = getattr(mat.bending, direction)
    q = mat.areal_density * G
    L = float(overhang_cm)

    def moment(K):
        root = K / math.sqrt(K + x0) if x0 > 0 else math.sqrt(K)
        return (c.c0 * root + c.c1 * K + c.c2 * K * K) * G

    def curvature(m):
        if m <= 0.0:
            return 0.0
        hi = 1.0
        while moment(hi) < m:
            hi *= 2.0
        return brentq(lambda K: moment(K) - m, 0.0, hi, xtol=1e-14, rtol=1e-13)

    def rhs(s, y):
        theta, m, _ = y
        return [curvature(m), -q * (L - s) * math.cos(theta), -math.sin(theta)]

    def shoot(m0):  # (moment left at the tip, tip drop) from clamp moment m0
        sol = solve_ivp(rhs, (0.0, L), [0.0, m0, 0.0], rtol=1e-10, atol=1e-12)
        return sol.y[1, -1], -sol.y[2, -1]

    m_max = q * L * L / 2.0  # the clamp moment of a strip held horizontal: an upper bound
    m0 = brentq(lambda m: shoot(m)[0], 1e-9 * m_max, m_max, xtol=1e-13 * m_max)
    return float(shoot(m0)[1])
