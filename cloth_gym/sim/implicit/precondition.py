"""The preconditioner's kernels for its family, chosen while numba compiles the step.

:attr:`~cloth_gym.sim.implicit.bundles.SolveOptions.family` is a :class:`~.bundles.Band`, a
:class:`~.bundles.OneLevel` or a :class:`~.bundles.Multigrid`, each its own type. The functions
here take it as their first argument and are resolved by that type when numba types their caller
(:func:`~cloth_gym.sim._numba.chosen_by_type`): the step compiled for the band factor calls the
band's kernels and holds none of the line smoothers' or the V-cycle's code, and the other way
round. A user of one preconditioner therefore compiles only its kernels (docs/cli.md, "Where the
first run's CPU goes"); each family's arithmetic is the same as the generic code's, so
trajectories do not depend on the split.

They are callable from compiled code only.
"""

from __future__ import annotations

from .._numba import chosen_by_type
from .band import band_apply, band_factor
from .bundles import BAND_WARP, Band, Multigrid, OneLevel
from .multigrid import (_smooth_level, band_setup, mg_precondition, mg_setup, one_level_setup, refresh_band,
                        refresh_multigrid, refresh_one_level)

__all__ = ["setup", "apply", "factor", "refresh"]


def _family(family) -> type | None:
    """The bundle class (:class:`Band`, :class:`OneLevel`, :class:`Multigrid`) of a family's numba type."""
    return getattr(family, "instance_class", None)


@chosen_by_type
def setup(family, x, h2, precond, fd, lv, ws, con, cn, assemble):
    """H on every level and the preconditioner's set-up (:func:`~.multigrid.mg_setup`,
    :func:`~.multigrid.one_level_setup` or :func:`~.multigrid.band_setup`); False if a
    coarsest matrix is not SPD."""
    kind = _family(family)
    if kind is Band:
        return lambda family, x, h2, precond, fd, lv, ws, con, cn, assemble: band_setup(
            x, h2, fd, lv, ws, con, cn, assemble)
    if kind is OneLevel:
        return lambda family, x, h2, precond, fd, lv, ws, con, cn, assemble: one_level_setup(
            x, h2, precond, fd, lv, ws, con, cn, assemble)
    if kind is Multigrid:
        return lambda family, x, h2, precond, fd, lv, ws, con, cn, assemble: mg_setup(
            x, h2, precond, fd, lv, ws, con, cn, assemble)
    return None


@chosen_by_type
def apply(family, r, z, h2, precond, omega, lv, ws):
    """``z = B r``: the band factor's solve, one level's smoother or the V-cycle."""
    kind = _family(family)
    if kind is Band:
        def band(family, r, z, h2, precond, omega, lv, ws):
            n = lv.n_off[1]
            band_apply(ws.band, lv.lw_idx[0:n] if precond == BAND_WARP else lv.lf_idx[0:n], ws.free, r, z, ws.cvec)
        return band
    if kind is OneLevel:
        return lambda family, r, z, h2, precond, omega, lv, ws: _smooth_level(0, r, z, 1.0, precond, lv, ws)
    if kind is Multigrid:
        return lambda family, r, z, h2, precond, omega, lv, ws: mg_precondition(r, z, h2, precond, omega, lv, ws)
    return None


@chosen_by_type
def factor(family, Dblk, free, h2, H0, bslot, band):
    """The band factor from the level-0 blocks (:func:`~.band.band_factor`; False if not SPD);
    nothing (True) for the other families."""
    kind = _family(family)
    if kind is Band:
        return lambda family, Dblk, free, h2, H0, bslot, band: band_factor(Dblk, free, h2, H0, bslot, band)
    if kind is OneLevel or kind is Multigrid:
        return lambda family, Dblk, free, h2, H0, bslot, band: True
    return None


@chosen_by_type
def refresh(family, x, h2, precond, fd, lv, ws, con, cn, md, md_before, stale):
    """The preconditioner after the friction re-solve raised the diagonal
    (:func:`~.multigrid.refresh_band`, ``refresh_one_level``, ``refresh_multigrid``)."""
    kind = _family(family)
    if kind is Band:
        return lambda family, x, h2, precond, fd, lv, ws, con, cn, md, md_before, stale: refresh_band(
            x, lv, ws, con, cn, md, md_before, stale)
    if kind is OneLevel:
        return lambda family, x, h2, precond, fd, lv, ws, con, cn, md, md_before, stale: refresh_one_level(
            x, precond, lv, ws, con, cn, md, md_before, stale)
    if kind is Multigrid:
        return lambda family, x, h2, precond, fd, lv, ws, con, cn, md, md_before, stale: refresh_multigrid(
            x, h2, precond, fd, lv, ws, con, cn, md, md_before, stale)
    return None
