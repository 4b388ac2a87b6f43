"""Where the first env step's CPU goes: numba's compile, kernel by kernel, from an empty cache.

For each env id, a fresh Python process with an empty kernel cache (its own
``NUMBA_CACHE_DIR``) makes the env, resets it and takes one step, then renders one
frame; a second process with that cache, now filled, does the same. Each child
records process CPU seconds from interpreter start to the end of the first step
(imports included), the first ``render()``'s CPU, and every numba compile
(``numba:compile`` events, CPU seconds read at their start and end): inclusive time,
and exclusive time (less the compiles nested inside it, the callees compiled while
typing their caller), grouped by kernel and by module, with the number of type
signatures each kernel was compiled for; and LLVM's share of it: the CPU of its
optimisation passes and of machine-code emission (the rest is numba's own Python:
typing, lowering, building the IR).

Writes ``outputs/compile_cost/compile_cost.json`` (``--docs``: also
``docs/data/compile_cost.json``) and prints, per id, the cold and warm first step and
the kernels that take most of the compile:

    .venv/bin/python scripts/compile_cost.py --docs
    .venv/bin/python scripts/compile_cost.py --ids cloth_gym/CornerLift-v2 --top 40
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cloth_gym.reports.options import command_line  # noqa: E402
from cloth_gym.reports.provenance import load_average, stamp, write_results  # noqa: E402

# The child: runs in a fresh interpreter, prints one JSON line. Kept as source text so that the
# process CPU it reports starts at that interpreter's own start.
CHILD = r'''
import json, sys, time, warnings
from numba.core import event

class CpuRecorder(event.Listener):
    """numba:compile events stamped with this process's CPU seconds."""
    def __init__(self):
        self.buffer = []
    def on_start(self, ev):
        self.buffer.append(("start", time.process_time(), ev))
    def on_end(self, ev):
        self.buffer.append(("end", time.process_time(), ev))

recorder = CpuRecorder()
event.register("numba:compile", recorder)

# LLVM's share: CPU in its optimisation passes and in machine-code emission (the rest of a compile
# is numba's own Python: typing, lowering, building the IR)
from llvmlite.binding import newpassmanagers
from numba.core import codegen
llvm = {"optimise": 0.0, "emit": 0.0}

def timed(fn, key):
    def wrapper(*a, **k):
        t0 = time.process_time()
        try:
            return fn(*a, **k)
        finally:
            llvm[key] += time.process_time() - t0
    return wrapper

newpassmanagers.NewPassManager.run = timed(newpassmanagers.NewPassManager.run, "optimise")
codegen.JitEngine.finalize_object = timed(codegen.JitEngine.finalize_object, "emit")

import gymnasium as gym
import numpy as np
import cloth_gym  # noqa: F401

env_id = sys.argv[1]
cpu_import = time.process_time()
with warnings.catch_warnings():
    warnings.filterwarnings("ignore", message=".*is out of date", category=DeprecationWarning)
    env = gym.make(env_id, render_mode="rgb_array")
env.reset(seed=0)
env.step(np.zeros(env.action_space.shape, dtype=env.action_space.dtype))
cpu_first_step = time.process_time()
compiles_before_render = len(recorder.buffer)
env.render()
cpu_render = time.process_time() - cpu_first_step

stack, compiles = [], []
for kind, cpu, ev in recorder.buffer:
    if kind == "start":
        stack.append([cpu, 0.0])
        continue
    start, nested = stack.pop()
    total = cpu - start
    if stack:
        stack[-1][1] += total
    func = ev.data["dispatcher"].py_func
    compiles.append({"module": func.__module__, "kernel": func.__qualname__, "inclusive_cpu_s": total,
                     "exclusive_cpu_s": total - nested, "top_level": not stack,
                     "args": str(ev.data.get("args"))[:300]})
print(json.dumps({"cpu_import_s": cpu_import, "cpu_first_step_s": cpu_first_step, "cpu_render_s": cpu_render,
                  "llvm_optimise_cpu_s": llvm["optimise"], "llvm_emit_cpu_s": llvm["emit"],
                  "compile_events_before_render": compiles_before_render // 2, "compiles": compiles}))
'''


def child(env_id: str, cache: str) -> dict:
    """One fresh interpreter's measurement of ``env_id`` with ``cache`` as its NUMBA_CACHE_DIR."""
    env = {**os.environ, "NUMBA_CACHE_DIR": cache, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "PYTHONWARNINGS": "ignore"}
    out = subprocess.run([sys.executable, "-c", CHILD, env_id], env=env, capture_output=True, text=True,
                         cwd=ROOT, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"{env_id}: the child process failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def summarise(compiles: list[dict], top: int) -> dict:
    """Compile CPU by kernel and by module (exclusive seconds), largest first."""
    kernels: dict[str, dict] = {}
    modules: dict[str, float] = {}
    for c in compiles:
        name = f"{c['module']}.{c['kernel']}"
        k = kernels.setdefault(name, {"kernel": name, "signatures": 0, "exclusive_cpu_s": 0.0})
        k["signatures"] += 1
        k["exclusive_cpu_s"] += c["exclusive_cpu_s"]
        modules[c["module"]] = modules.get(c["module"], 0.0) + c["exclusive_cpu_s"]
    ranked = sorted(kernels.values(), key=lambda k: -k["exclusive_cpu_s"])
    for k in ranked:
        k["exclusive_cpu_s"] = round(k["exclusive_cpu_s"], 3)
    return {"compile_cpu_s": round(sum(c["exclusive_cpu_s"] for c in compiles), 2),
            "kernels_compiled": len(kernels), "signatures_compiled": len(compiles),
            "multi_signature_kernels": [k for k in ranked if k["signatures"] > 1],
            "by_module": {m: round(s, 2) for m, s in sorted(modules.items(), key=lambda kv: -kv[1])},
            "top_kernels": ranked[:top]}


def measure(env_id: str, top: int) -> dict:
    """Cold (empty cache) and warm (the cache it filled) first step of ``env_id``."""
    with tempfile.TemporaryDirectory(prefix="cloth_gym_compile_") as cache:
        cold = child(env_id, cache)
        warm = child(env_id, cache)
    result = {"env_id": env_id,
              "cold": {k: round(cold[k], 2) for k in ("cpu_import_s", "cpu_first_step_s", "cpu_render_s",
                                                      "llvm_optimise_cpu_s", "llvm_emit_cpu_s")},
              "warm": {k: round(warm[k], 2) for k in ("cpu_import_s", "cpu_first_step_s", "cpu_render_s")}}
    result["cold"].update(summarise(cold["compiles"], top))
    result["warm"]["signatures_compiled"] = len(warm["compiles"])
    return result


def main(argv=None) -> dict:
    import cloth_gym  # noqa: F401  (registers the ids)
    from cloth_gym.envs import CURRENT_IDS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ids", nargs="+", default=list(CURRENT_IDS), help="env ids (default: the current ids)")
    ap.add_argument("--top", type=int, default=25, help="kernels listed per id")
    ap.add_argument("--out", type=Path, default=ROOT / "outputs" / "compile_cost")
    ap.add_argument("--docs", action="store_true", help="also write docs/data/compile_cost.json")
    args = ap.parse_args(argv)

    results = stamp(command_line("python scripts/compile_cost.py", sys.argv[1:] if argv is None else argv))
    results["machine"]["load_average_at_start"] = load_average()
    results["ids"] = []
    for env_id in args.ids:
        r = measure(env_id, args.top)
        results["ids"].append(r)
        cold, warm = r["cold"], r["warm"]
        print(f"\n{env_id}: cold first step {cold['cpu_first_step_s']:.1f} CPU s (imports {cold['cpu_import_s']:.1f}, "
              f"compile {cold['compile_cpu_s']:.1f} in {cold['signatures_compiled']} signatures of "
              f"{cold['kernels_compiled']} kernels), first render {cold['cpu_render_s']:.2f} s; warm: first step "
              f"{warm['cpu_first_step_s']:.1f} s, render {warm['cpu_render_s']:.2f} s; of the compile, LLVM's "
              f"passes {cold['llvm_optimise_cpu_s']:.1f} s and code emission {cold['llvm_emit_cpu_s']:.1f} s",
              flush=True)
        for m, s in list(cold["by_module"].items())[:8]:
            print(f"  {s:7.2f} s  {m}")
        for k in cold["top_kernels"]:
            print(f"  {k['exclusive_cpu_s']:7.2f} s  x{k['signatures']}  {k['kernel']}")
    write_results(results, args.out / "compile_cost.json", ROOT / "docs" / "data" / "compile_cost.json" if args.docs else None)
    return results


if __name__ == "__main__":
    main()
