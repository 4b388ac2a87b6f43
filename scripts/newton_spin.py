"""Rotation kept by the implicit step: a free spinning cloth's angular momentum after 1 s, per scheme.

A 10 cm thick-cotton square (sigma = 1 cm), weightless, no air, no damping, spins in its plane at
``--rev`` rev/s about its centre. Backward Euler solved to convergence loses
``1 − 1/√(1 + 2ω²hT)`` of a rigid spin's angular momentum over T (docs/numerics.md); each row
gives the loss, its ratio to that formula, linear solves per step (1 + Newton corrections) and CPU s.

    python scripts/newton_spin.py                       # the table at 1 and 10 ms, printed
    python scripts/newton_spin.py --out docs/data/newton_spin.json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from cloth_gym.reports.provenance import stamp

from cloth_gym.sim import ForceOptions, Rectangle, build_cloth
from cloth_gym.sim.implicit import ImplicitEuler


SCHEMES = {
    "euler, 1 pass": dict(scheme="euler", newton_iters=1),
    "euler, Newton to 1e-3 cm/s": dict(scheme="euler", newton_iters=10, newton_tol=1e-3),
    "euler, Newton to 0.1 cm/s": dict(scheme="euler", newton_iters=10, newton_tol=0.1),
    "bdf2, 1 pass": dict(scheme="bdf2", newton_iters=1),
    "bdf2, Newton to 1e-3 cm/s": dict(scheme="bdf2", newton_iters=10, newton_tol=1e-3),
    "bdf2, Newton to 0.1 cm/s": dict(scheme="bdf2", newton_iters=10, newton_tol=0.1),
}


def backward_euler_loss(omega: float, h: float, t: float) -> float:
    """Fraction of a rigid spin's angular momentum converged backward Euler loses over ``t`` s."""
    return 1.0 - 1.0 / math.sqrt(1.0 + 2.0 * omega * omega * h * t)


def spinning_cloth(rev_per_s: float):
    m = build_cloth(Rectangle(10.0, 10.0), "thick_cotton", sigma=1.0, gravity=(0, 0, 0),
                    options=ForceOptions(air=False, damping=False))
    s = m.state()
    centre = s.particle_q.mean(axis=0)
    s.particle_qd[:] = np.cross((0.0, 0.0, 2 * math.pi * rev_per_s), s.particle_q - centre)
    return m, s, centre


def angular_momentum_z(m, s, centre) -> float:
    """L_z about the centre of mass, g·cm²/s."""
    com = (m.particle_mass[:, None] * s.particle_q).sum(0) / m.particle_mass.sum()
    return float((m.particle_mass[:, None] * np.cross(s.particle_q - com, s.particle_qd)).sum(0)[2])


def run(kwargs: dict, h: float, rev_per_s: float, duration: float = 1.0) -> dict:
    m, s, centre = spinning_cloth(rev_per_s)
    L0 = angular_momentum_z(m, s, centre)
    solver = ImplicitEuler(max_dt=h, **kwargs)
    steps = int(round(duration / h))
    solves = []
    c0, w0 = time.process_time(), time.perf_counter()
    for _ in range(steps):
        solver.step(m, s, None, h)
        solves.append(solver.last_stats[:, 2].mean())
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    loss = 1.0 - angular_momentum_z(m, s, centre) / L0
    ref = backward_euler_loss(2 * math.pi * rev_per_s, h, duration)
    return {"h_s": h, "rev_per_s": rev_per_s, "loss": loss, "backward_euler_converged_loss": ref,
            "ratio_to_converged_be": loss / ref, "solves_per_step": float(np.mean(solves)), "steps": steps,
            "cpu_s": cpu, "wall_s": wall}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--dt", type=float, nargs="+", default=[1e-3, 1e-2], help="substeps, s")
    p.add_argument("--rev", type=float, default=1.0, help="spin, rev/s")
    p.add_argument("--out", type=Path, help="save the table as JSON")
    args = p.parse_args(argv)
    run(SCHEMES["euler, 1 pass"], 1e-2, args.rev, 0.02)  # compile first
    rows = []
    for h in args.dt:
        for name, kw in SCHEMES.items():
            r = {"scheme": name, **kw, **run(kw, h, args.rev)}
            rows.append(r)
            print(f"h = {h * 1e3:4.0f} ms  {name:28s} loss {100 * r['loss']:7.3f} %  "
                  f"(converged BE {100 * r['backward_euler_converged_loss']:.2f} %, ratio {r['ratio_to_converged_be']:.2f})"
                  f"  solves/step {r['solves_per_step']:.2f}  cpu {r['cpu_s']:.2f} s", flush=True)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        command = " ".join(["python scripts/newton_spin.py", *(argv if argv is not None else sys.argv[1:])])
        args.out.write_text(json.dumps({"stamp": stamp(command), "rows": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
