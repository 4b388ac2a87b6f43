"""Air drag on the cloth's surface, and its linearisation for the implicit solver."""

from __future__ import annotations

import math


from .._numba import kernel_only
from .common import _cross


@kernel_only
def vertex_normals(x, tris, out):
    """Area-weighted unit vertex normals (N, 3) from triangles; zero for particles in no triangle."""
    out[:] = 0.0
    for t in range(tris.shape[0]):
        i = tris[t, 0]
        j = tris[t, 1]
        k = tris[t, 2]
        n0, n1, n2 = _cross(x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2],
                            x[k, 0] - x[i, 0], x[k, 1] - x[i, 1], x[k, 2] - x[i, 2])
        for p in (i, j, k):
            out[p, 0] += n0
            out[p, 1] += n1
            out[p, 2] += n2
    for p in range(out.shape[0]):
        s = math.sqrt(out[p, 0] ** 2 + out[p, 1] ** 2 + out[p, 2] ** 2)
        if s > 0.0:
            out[p, 0] /= s
            out[p, 1] /= s
            out[p, 2] /= s


@kernel_only
def eval_air(x, v, tris, wind, c_air, area, normals, f):
    """Air drag, eq. (4) with the sign fixed as in docs/physics.md (forces): ``F = −C_air·A·|n·u|·u``,
    ``u = v − w``, A = ``area[p]`` the particle's area of fabric (cm², σ² inside the cloth).

    ``normals`` (N, 3) is scratch space for the vertex normals.
    """
    vertex_normals(x, tris, normals)
    for p in range(x.shape[0]):
        s2 = c_air * area[p]
        u0 = v[p, 0] - wind[0]
        u1 = v[p, 1] - wind[1]
        u2 = v[p, 2] - wind[2]
        un = abs(normals[p, 0] * u0 + normals[p, 1] * u1 + normals[p, 2] * u2)
        f[p, 0] -= s2 * un * u0
        f[p, 1] -= s2 * un * u1
        f[p, 2] -= s2 * un * u2


@kernel_only
def air_linearisation(x, v, tris, wind, c_air, area, normals, drag):
    """Per-particle drag coefficient ``2·C_air·A·|n·u|`` (g/s): the diagonal part of −∂F_air/∂v."""
    vertex_normals(x, tris, normals)
    for p in range(x.shape[0]):
        s2 = c_air * area[p]
        un = (normals[p, 0] * (v[p, 0] - wind[0]) + normals[p, 1] * (v[p, 1] - wind[1])
              + normals[p, 2] * (v[p, 2] - wind[2]))
        drag[p] = 2.0 * s2 * abs(un)  # d(|n·u|u)/du along u is 2|n·u|
