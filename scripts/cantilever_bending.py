"""A clamped strip bending under its own weight (the cantilever bending test of ASTM D1388) against
its continuum reference, the heavy elastica: tip drop and error by lattice spacing and mass lumping.

The scene, its rest state and the reference are :mod:`cloth_gym.scenes.cantilever`'s. Prints one
line per case; the error's ratio from one σ to the next half is 4 at second order, 2 at first.

    python scripts/cantilever_bending.py [--material thin_wool] [--overhang 4 2] [--direction warp]
"""

import argparse
import time

from cloth_gym.scenes.cantilever import (cantilever_strip, cantilever_tip_drop, heavy_elastica_tip_drop,
                                         settle_cantilever)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--material", default="thin_wool")
    ap.add_argument("--overhang", type=float, nargs="+", default=[4.0, 2.0], help="cm")
    ap.add_argument("--direction", choices=("warp", "weft"), default="warp")
    ap.add_argument("--sigma", type=float, nargs="+", default=[1.0, 0.5, 0.25], help="cm")
    args = ap.parse_args(argv)
    for L in args.overhang:
        ref = heavy_elastica_tip_drop(args.material, L, args.direction)
        print(f"overhang {L} cm ({args.direction}): reference tip drop {ref:.4f} cm")
        for lumping in ("uniform", "area"):
            previous = None
            for sigma in args.sigma:
                t = time.process_time()
                m = cantilever_strip(args.material, L, sigma, direction=args.direction, mass_lumping=lumping)
                drop = cantilever_tip_drop(m, settle_cantilever(m))
                err = 100 * (drop / ref - 1)
                ratio = f"  ratio {previous / err:.2f}" if previous else ""
                print(f"  {lumping:8s} sigma {sigma}: {drop:.4f} cm  error {err:+.2f} %{ratio}  "
                      f"({time.process_time() - t:.1f} CPU s)", flush=True)
                previous = err


if __name__ == "__main__":
    main()
