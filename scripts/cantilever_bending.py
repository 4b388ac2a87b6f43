"""A clamped strip bending under its own weight (the heavy-elastica cantilever of the bending-length
test, ASTM D1388) against its continuum reference: tip drop by lattice spacing and mass lumping.

The reference integrates the inextensible heavy elastica with the material's moment law M(K)
(the simulator's regularised root), shooting on the clamp moment. The lattice strip is pinned at
u <= 0 (two columns) and run to rest with the implicit integrator. Prints the tip drop and its
error for each sigma and lumping.

    python scripts/cantilever_bending.py [--material thin_wool] [--overhang 4 2]
"""

import argparse
import math
import time

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from cloth_gym import load_material
from cloth_gym.sim import Rectangle, build_cloth
from cloth_gym.sim.implicit import ImplicitEuler
from cloth_gym.sim.model import ForceOptions
from cloth_gym.units import G


def moment(K, c, x0):
    c0, c1, c2 = c
    root = K / math.sqrt(K + x0) if x0 > 0 else math.sqrt(K)
    return (c0 * root + c1 * K + c2 * K * K) * G   # dyne·cm per cm of width

def curvature(m, c, x0):
    if m <= 0: return 0.0
    hi = 1.0
    while moment(hi, c, x0) < m: hi *= 2
    return brentq(lambda K: moment(K, c, x0) - m, 0.0, hi, xtol=1e-14, rtol=1e-13)

def reference_tip_drop(material, L, x0=0.004, direction=0):
    c = [material.bending.warp, material.bending.weft][direction]
    c = (c.c0, c.c1, c.c2)
    q = material.areal_density * G
    def rhs(s, y):
        th, m, z = y
        return [curvature(m, c, x0), -q * (L - s) * math.cos(th), -math.sin(th)]
    def end_moment(m0):
        sol = solve_ivp(rhs, (0, L), [0.0, m0, 0.0], rtol=1e-10, atol=1e-12)
        return sol.y[1, -1], -sol.y[2, -1]
    m_hi = q * L * L / 2  # the moment of a horizontal strip: an upper bound
    m0 = brentq(lambda m: end_moment(m)[0], 1e-9 * m_hi, m_hi, xtol=1e-13 * m_hi)
    return end_moment(m0)[1]

def sim_tip_drop(material, L, sigma, lumping, width=1.0):
    opts = ForceOptions(air=False, damping_model="absolute", mass_lumping=lumping)
    mat = material.replace(damping=30.0)
    clamp = sigma
    m = build_cloth(Rectangle(L + clamp, width), mat, sigma=sigma, options=opts, origin=(L/2 - clamp/2, 0, 0))
    u = m.particle_q0[:, 0]
    m = m.with_pinned(np.nonzero(u <= 1e-9)[0])
    st = m.state()
    integ = ImplicitEuler(tol=1e-8)
    for k in range(60):
        integ.advance(m, st, None, 0.1, 0.005)
    tip = np.abs(u - L) < 1e-9
    return -st.particle_q[tip, 2].mean(), np.abs(st.particle_qd).max()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--material", default="thin_wool")
    ap.add_argument("--overhang", type=float, nargs="+", default=[4.0, 2.0], help="cm")
    args = ap.parse_args(argv)
    mat = load_material(args.material)
    for L in args.overhang:
        ref = reference_tip_drop(mat, L)
        print(f"overhang {L} cm: reference tip drop {ref:.4f} cm")
        for lump in ("uniform", "area"):
            for sig in (1.0, 0.5, 0.25):
                t = time.process_time()
                d, _ = sim_tip_drop(mat, L, sig, lump)
                print(f"  {lump:8s} sigma {sig}: {d:.4f} cm  error {100 * (d / ref - 1):+.2f} %  "
                      f"({time.process_time() - t:.1f} CPU s)", flush=True)


if __name__ == "__main__":
    main()
