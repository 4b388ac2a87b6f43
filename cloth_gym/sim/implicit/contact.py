"""Contact with analytic obstacles inside the implicit solve: each touching particle's velocity
constrained along the surface normal (filtered out of the solve, Baraff–Witkin), Coulomb friction
as a linearised damper, its re-solve where the first solve left a particle sliding more slowly than
its damper assumed, and the penalty blocks that keep the preconditioner aware of the constraint.
"""

from __future__ import annotations

import math

from .._numba import kernel_only

from ..obstacles import signed_distance
from .matrix import zero_row


# ============================================================================ contact constraints
# Regularisation speed of Coulomb friction (cm/s): below it friction acts as a viscous damper of
# coefficient μ|f_n|/V_EPS, so a particle under a tangential load below μ|f_n| creeps at most this fast.
FRICTION_V_EPS = 1e-2
FRICTION_PASSES = 1  # at most this many re-solves per step with raised friction dampers (refine_friction)
FRICTION_REFINE_SPEED = 0.5  # cm/s: refine_friction leaves particles sliding slower than this at the end of the solve
FRICTION_REFINE_RATIO = 2.0  # refine_friction raises a damper that brakes with less than 1/this of μ|f_n|


@kernel_only
def contact_constraints(x, v, f, world, mass, h, cn, con, cfric, md, free, fmax):
    """Contact constraints and implicit Coulomb friction for the solve (Baraff–Witkin filter).

    A particle that touched an obstacle last step and is pressed into it (``f·n < 0``) is
    constrained (``con = 1``): its normal velocity is set to the obstacle's and kept there by
    the filter. Friction is Coulomb's, taken *implicitly*: a damper of coefficient
    ``c = μ|f_n| / max(s, V_EPS)`` (g/s, into ``cfric``), with ``f_n = f·n`` from the forces at
    the start of the step, ``s = |u_t + h·f_t/m| − h·μ|f_n|/m`` the end-of-step sliding speed
    predicted from the step's forces (``u_t`` the tangential velocity relative to the
    obstacle, ``f_t`` the tangential force) and V_EPS = :data:`FRICTION_V_EPS`. Its force
    ``−c·u_t`` is added to ``f`` and its ``h·c`` to the particle's diagonal ``md``. For a lone
    particle the update is then exact Coulomb: sliding at speed s against μ|f_n|, or held
    (``s ≤ 0``: creep below V_EPS) when the tangential load is below μ|f_n|. A damper cannot
    reverse the motion and keeps the system SPD whatever Δt: this is what makes large steps
    onto a table stable (the explicit friction force that this replaced made the 41×41
    tablecloth explode at Δt = 5 ms).
    Pinned and kinematic particles (``free`` False) keep their prescribed velocity: no constraint.
    ``fmax`` gets the friction bound μ|f_n| (dyne) of each constrained particle (0 elsewhere), for
    :func:`refine_friction`. ``world``: a :class:`~cloth_gym.sim.bundles.World` (its obstacles where
    they are now, ``world.touching`` the contact record of the last step).
    """
    touching, types, params, friction, ob_vel = (world.touching, world.obstacles.types, world.prm,
                                                 world.obstacles.friction, world.vel)
    for p in range(x.shape[0]):
        con[p] = 0
        cfric[p] = 0.0
        fmax[p] = 0.0
        k = touching[p]
        if k < 0 or not free[p]:
            continue
        d, n0, n1, n2 = signed_distance(types[k], params[k], x[p, 0], x[p, 1], x[p, 2])
        fn = f[p, 0] * n0 + f[p, 1] * n1 + f[p, 2] * n2
        if fn >= 0.0:
            continue
        cn[p, 0] = n0
        cn[p, 1] = n1
        cn[p, 2] = n2
        w0 = ob_vel[k, 0]
        w1 = ob_vel[k, 1]
        w2 = ob_vel[k, 2]
        vn = (v[p, 0] - w0) * n0 + (v[p, 1] - w1) * n1 + (v[p, 2] - w2) * n2
        v[p, 0] -= vn * n0
        v[p, 1] -= vn * n1
        v[p, 2] -= vn * n2
        con[p] = 1
        u0 = v[p, 0] - w0
        u1 = v[p, 1] - w1
        u2 = v[p, 2] - w2
        # the end-of-step sliding speed predicted from this step's forces: |u + h·f_t/m| − h·μ|f_n|/m
        # (≤ 0: it sticks); with c = μ|f_n|/speed the damped update reproduces Coulomb exactly for a
        # lone particle, instead of over-braking a particle that starts to slide
        im = 1.0 / mass[p]
        p0 = u0 + h * (f[p, 0] - fn * n0) * im
        p1 = u1 + h * (f[p, 1] - fn * n1) * im
        p2 = u2 + h * (f[p, 2] - fn * n2) * im
        slide = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2) + h * friction[k] * fn * im
        c = -friction[k] * fn / max(slide, FRICTION_V_EPS)
        cfric[p] = c
        fmax[p] = -friction[k] * fn
        md[p] += h * c
        f[p, 0] -= c * u0
        f[p, 1] -= c * u1
        f[p, 2] -= c * u2



@kernel_only
def refine_friction(v, dv, con, cn, cfric, fmax, touching, ob_vel, h, md, rhs):
    """Second friction pass after a solve: where the solve's end-of-step sliding speed ``s`` is
    below 1/:data:`FRICTION_REFINE_RATIO` (= ½) of the one :func:`contact_constraints` predicted
    (the damper then brakes with less than half of μ|f_n|), raise the damper to
    ``c = μ|f_n|/s`` — for particles still sliding faster than :data:`FRICTION_REFINE_SPEED`
    (a slower one's velocity could change by less than that): its extra force
    ``−Δc·u_t`` goes into ``rhs`` (× h) and ``h·Δc`` into ``md``. Returns whether anything changed
    (then solve again). The prediction uses the particle's own mass: it overestimates the sliding
    of a cloth whose internal forces cancel over the solve, e.g. one released stretched at
    Δt = 50 ms, which without this pass kept most of its speed and skated on the table. Raising c
    from a speed reached with the smaller c keeps the friction force below μ|f_n|. The thresholds
    trade accuracy for solves: a ratio of 1.2 with two re-solves braked the released CornerLift
    cloth at Coulomb's rate, these settings at about 70 % of it, for far fewer CG iterations on the
    41×41 drop. A 20 cm cloth stretched by 1 % and sliding at 30 cm/s on a table slides within 4 %
    of Coulomb's distance at h = 10 ms, but 1.47 cm instead of 0.79 at h = 50 ms (ratio 1.25 with
    two re-solves: 1.13 cm); unstretched, 0.74 cm at 50 ms."""
    changed = False
    for p in range(v.shape[0]):
        if con[p] != 1 or fmax[p] == 0.0:
            continue
        k = touching[p]
        e0 = v[p, 0] + dv[p, 0] - ob_vel[k, 0]
        e1 = v[p, 1] + dv[p, 1] - ob_vel[k, 1]
        e2 = v[p, 2] + dv[p, 2] - ob_vel[k, 2]
        en = e0 * cn[p, 0] + e1 * cn[p, 1] + e2 * cn[p, 2]
        e0 -= en * cn[p, 0]
        e1 -= en * cn[p, 1]
        e2 -= en * cn[p, 2]
        sl = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        if sl <= FRICTION_REFINE_SPEED:  # the re-solve could change its velocity by at most sl
            continue
        c = fmax[p] / sl
        if c <= FRICTION_REFINE_RATIO * cfric[p]:
            continue
        dc = c - cfric[p]
        u0 = v[p, 0] - ob_vel[k, 0]  # tangential at the start (the normal part was removed)
        u1 = v[p, 1] - ob_vel[k, 1]
        u2 = v[p, 2] - ob_vel[k, 2]
        rhs[p, 0] -= h * dc * u0
        rhs[p, 1] -= h * dc * u1
        rhs[p, 2] -= h * dc * u2
        md[p] += h * dc
        cfric[p] = c
        changed = True
    return changed



@kernel_only
def friction_force(v, con, cn, cfric, touching, ob_vel, out):
    """The implicit friction force ``−c·u_t`` (dyne) at velocity ``v`` (for further Newton passes)."""
    for p in range(v.shape[0]):
        zero_row(out, p)
        if con[p] != 1 or cfric[p] == 0.0:
            continue
        k = touching[p]
        u0 = v[p, 0] - ob_vel[k, 0]
        u1 = v[p, 1] - ob_vel[k, 1]
        u2 = v[p, 2] - ob_vel[k, 2]
        un = u0 * cn[p, 0] + u1 * cn[p, 1] + u2 * cn[p, 2]
        out[p, 0] = -cfric[p] * (u0 - un * cn[p, 0])
        out[p, 1] = -cfric[p] * (u1 - un * cn[p, 1])
        out[p, 2] = -cfric[p] * (u2 - un * cn[p, 2])



@kernel_only
def filter_vec(r, free, con, cn):
    """Baraff–Witkin filter S: zero at pinned and sticking particles, normal component removed
    at sliding ones."""
    for p in range(r.shape[0]):
        if not free[p] or con[p] != 0:
            r[p, 0], r[p, 1], r[p, 2] = filtered_row(r[p, 0], r[p, 1], r[p, 2], free[p], con[p], cn[p, 0],
                                                     cn[p, 1], cn[p, 2])



@kernel_only
def filtered_row(x0, x1, x2, free, con, n0, n1, n2):
    """Row ``x`` of a vector filtered by S (:func:`filter_vec`) at a particle ``free`` or not, with
    the constraint ``con`` and normal ``n``. Scalars in and out: a kernel that takes the arrays
    and is called per row costs an order of magnitude more."""
    if not free or con == 2:
        return 0.0, 0.0, 0.0
    if con == 1:
        d = x0 * n0 + x1 * n1 + x2 * n2
        return x0 - d * n0, x1 - d * n1, x2 - d * n2
    return x0, x1, x2


# ============================================================================ contact penalty (preconditioner only)
CONTACT_PENALTY = 1.0e3



@kernel_only
def contact_penalty(Dblk, con, cn, pen):
    """``pen_q = κ·(tr D_q / 3)·n nᵀ`` for constrained particles, 0 elsewhere (see :func:`mg_setup`)."""
    for q in range(Dblk.shape[0]):
        if con[q] != 1:
            for i in range(3):
                for j in range(3):
                    pen[q, i, j] = 0.0
            continue
        k = CONTACT_PENALTY * (Dblk[q, 0, 0] + Dblk[q, 1, 1] + Dblk[q, 2, 2]) / 3.0
        for i in range(3):
            for j in range(3):
                pen[q, i, j] = k * cn[q, i] * cn[q, j]



@kernel_only
def raise_diagonal(md, md_before, con, cn, Dblk, pen):
    """Add the rise ``δ_q = md_q − md_before_q`` of the lumped diagonal (the friction re-solve's
    raised dampers) to level 0's preconditioner blocks in place: ``D_q += δ_q·I`` and, at a
    constrained particle, its contact penalty ``κ·(tr D_q/3)·n nᵀ`` grows by ``κ·δ_q·n nᵀ``.
    The same blocks as :func:`mg_setup` would rebuild from scratch (up to rounding), without
    re-assembling the diagonal blocks and line couplings of the particles that did not change."""
    for q in range(md.shape[0]):
        d = md[q] - md_before[q]
        if d == 0.0:
            continue
        for i in range(3):
            Dblk[q, i, i] += d
        if con[q] == 1:
            k = CONTACT_PENALTY * d
            for i in range(3):
                for j in range(3):
                    Dblk[q, i, j] += k * cn[q, i] * cn[q, j]
                    pen[q, i, j] += k * cn[q, i] * cn[q, j]
