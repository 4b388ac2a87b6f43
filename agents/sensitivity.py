"""Material sensitivity: how a drape and a policy change when the fabric changes.

A sweep is a list of :class:`Variant` s — the shipped materials, Breen's
model, and each KES parameter group scaled by a factor — and for each variant
one or both jobs:

* ``drape``: the paper's drape test (:func:`cloth_gym.scenes.drape_test`),
  run until settled; drape coefficient and node count;
* ``policy``: a policy (``expert``, ``random`` or a training run directory)
  on an env with that material; success rate and return over seeded episodes.

:func:`library_variants` and :func:`library_sweep` run policies on every shipped fabric as
measured (no scaling), one column per (env, policy) case, drawn by :func:`heatmap`.

Jobs are independent and run in parallel: in processes on one machine
(``backend="process"``), or as Ray tasks (``backend="ray"``, on a cluster given
its address, or on a single-node Ray started on this machine). Both give the
same numbers: every job is deterministic. (Ray's ``local_mode``, a serial
in-process mode, was removed in Ray 2.x; the tests start a local single-node
Ray instead, which exercises the same code path as a cluster.)
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from cloth_gym.errors import ConfigError
from cloth_gym.materials import Material, available_materials, load_material

__all__ = ["GROUPS", "Variant", "default_variants", "heatmap", "library_sweep", "library_variants", "write_library_report", "variant_material",
           "run_sweep", "write_report"]

#: KES parameter groups that can be scaled, and what each scales.
GROUPS = {
    "areal_mass": "areal density W (g/cm²)",
    "stretch_warp": "tensile curve, warp",
    "stretch_weft": "tensile curve, weft",
    "bending_warp": "bending curve, warp",
    "bending_weft": "bending curve, weft",
    "shear": "shear curve (warp and weft)",
}


@dataclass(frozen=True)
class Variant:
    """One material of a sweep: ``base`` material scaled in ``group`` by ``factor`` (group
    ``None``: the base itself), simulated with the ``model`` (``kes`` or ``breen``)."""

    label: str
    base: str = "thick_cotton"
    group: str | None = None
    factor: float = 1.0
    model: str = "kes"

    def material(self) -> Material:
        return variant_material(load_material(self.base), self.group, self.factor)


def variant_material(base: Material, group: str | None, factor: float) -> Material:
    """``base`` with one KES parameter group multiplied by ``factor``."""
    if not (isinstance(factor, (int, float)) and math.isfinite(factor) and factor > 0):
        raise ConfigError("factor", f"must be a finite number > 0, got {factor!r}")
    if group is None:
        return base
    if group == "areal_mass":
        return base.replace(areal_density=base.areal_density * factor)
    if group == "stretch_warp":
        return base.replace(stretch=base.stretch.scaled(warp=factor))
    if group == "stretch_weft":
        return base.replace(stretch=base.stretch.scaled(weft=factor))
    if group == "bending_warp":
        return base.replace(bending=base.bending.scaled(warp=factor))
    if group == "bending_weft":
        return base.replace(bending=base.bending.scaled(weft=factor))
    if group == "shear":
        return base.replace(shear=base.shear.scaled(factor, factor))
    raise ConfigError("group", f"must be one of {list(GROUPS)}, got {group!r}")


def default_variants(base: str = "thick_cotton", factors=(0.25, 0.5, 2.0, 4.0), groups=None) -> list[Variant]:
    """Cotton, wool, ``base`` itself (when it is neither), Breen's model (on ``base``), and every
    group × factor on ``base``."""
    out = [Variant("thick_cotton", "thick_cotton"), Variant("thin_wool", "thin_wool")]
    if base not in ("thick_cotton", "thin_wool"):  # the row every scaled variant is compared with
        out.append(Variant(str(base), base))
    out.append(Variant(f"{base} (Breen)", base, model="breen"))
    for g in groups or GROUPS:
        if g not in GROUPS:
            raise ConfigError("groups", f"unknown group {g!r}; allowed: {list(GROUPS)}")
        for f in factors:
            out.append(Variant(f"{base} {g} x{f:g}", base, g, float(f)))
    return out


def library_variants(names=None) -> list[Variant]:
    """One variant per shipped material (``names``: those only), each as measured."""
    names = list(names or available_materials())
    unknown = [n for n in names if n not in available_materials()]
    if unknown:
        raise ConfigError("materials", f"not shipped: {unknown}; shipped: {available_materials()}")
    return [Variant(n, n) for n in names]


# ----------------------------------------------------------------------------- jobs
def drape_job(variant: Variant, sigma: float, max_time_s: float) -> dict:
    """Drape test of one variant: DC, node count, settle time, wall time."""
    from cloth_gym.scenes.paper import drape_metrics, drape_test, run_until_settled

    t0 = time.perf_counter()
    sc = drape_test(variant.material(), model=variant.model, sigma=sigma, max_time_s=max_time_s)
    res = run_until_settled(sc)
    meas = drape_metrics(sc, res.state)
    return {"drape_coefficient": meas["drape_coefficient"], "node_count": meas["node_count"],
            "settled": bool(res.settled),
            "drape_settle_time_s": res.settle_time_s, "drape_wall_s": time.perf_counter() - t0}


def policy_job(variant: Variant, policy: str, env_id: str | None, episodes: int, seed: int, env_kwargs: dict) -> dict:
    """A policy on ``env_id`` (None: a training run's own env and env kwargs) with the variant's
    material and model: success rate and return."""
    from .evaluation import evaluate_policy_source

    kw = {**env_kwargs, "material": variant.material(), "model": variant.model}
    t0 = time.perf_counter()
    r = evaluate_policy_source(policy, env_id, episodes, seed, kw)
    return {"success_rate": r["success_rate"], "return_mean": r["return_mean"], "return_std": r["return_std"],
            "diverged": r["diverged"], "policy_wall_s": time.perf_counter() - t0}


def _run_job(job: dict) -> dict:
    v = Variant(**job["variant"])
    row = {"label": v.label, "base": v.base, "group": v.group or "", "factor": v.factor, "model": v.model}
    if job.get("drape"):
        row.update(drape_job(v, **job["drape"]))
    if job.get("policy"):
        row.update(policy_job(v, **job["policy"]))
    return row


def run_sweep(variants: list[Variant], drape: dict | None = None, policy: dict | None = None,
              backend: str = "process", workers: int = 2, ray_address: str | None = None,
              progress: bool = True) -> list[dict]:
    """Run every variant's jobs; returns one row (dict) per variant, in the order given.

    drape: ``{"sigma": cm, "max_time_s": s}`` or None. policy: ``{"policy": ..., "env_id": ...,
    "episodes": n, "seed": s, "env_kwargs": {...}}`` or None. backend: ``"process"`` (a pool
    of ``workers`` processes; 1: in this process) or ``"ray"`` (the cluster at ``ray_address``,
    or, without one, a single-node Ray with ``workers`` CPUs started here and stopped after)."""
    if drape is None and policy is None:
        raise ConfigError("jobs", "nothing to run: give drape and/or policy settings")
    jobs = [{"variant": asdict(v), "drape": drape, "policy": policy} for v in variants]
    if backend == "process":
        if workers <= 1:
            return [_run_job(j) for j in _progress(jobs, progress)]
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=workers) as pool:
            return list(_progress(pool.map(_run_job, jobs), progress, total=len(jobs)))
    if backend == "ray":
        from .config import require_ray

        ray = require_ray("backend")

        started = not ray.is_initialized()
        if started:
            kw = {} if ray_address else {"num_cpus": max(1, workers)}
            ray.init(address=ray_address, include_dashboard=False, log_to_driver=False, **kw)
        try:
            task = ray.remote(_run_job)
            refs = [task.remote(j) for j in jobs]
            return [ray.get(r) for r in _progress(refs, progress)]
        finally:
            if started:
                ray.shutdown()
    raise ConfigError("backend", f"must be 'process' or 'ray', got {backend!r}")


def library_sweep(cases: list[tuple[str, str]], variants: list[Variant], episodes: int, seed: int,
                  backend: str = "process", workers: int = 2, ray_address: str | None = None) -> list[dict]:
    """Each ``(env_id, policy)`` case on every variant: rows as :func:`run_sweep`'s with the
    case's ``env_id`` and ``policy`` added. ``policy``: ``expert``, ``random``, ``published``
    (the policy published for ``env_id``, :mod:`cloth_gym.agents.published`) or a run directory.
    The episodes of every cell start from the same seeds ``seed``, ``seed + 1``, ..."""
    from .published import published_path

    rows = []
    for env_id, policy in cases:
        source = str(published_path(env_id)) if policy == "published" else policy
        job = {"policy": source, "env_id": env_id, "episodes": episodes, "seed": seed, "env_kwargs": {}}
        for row in run_sweep(variants, None, job, backend=backend, workers=workers, ray_address=ray_address):
            rows.append({"env_id": env_id, "policy": policy, **row})
    return rows


def _progress(it, on, total=None):
    if not on:
        return it
    from tqdm import tqdm

    return tqdm(it, total=total, desc="variants")


# ----------------------------------------------------------------------------- report
METRICS = ("drape_coefficient", "node_count", "success_rate", "return_mean")


def write_report(rows: list[dict], out_dir: str | Path, meta: dict | None = None) -> dict:
    """``sensitivity.csv``, ``sensitivity.md``, ``sensitivity.json`` and, per metric present,
    a tornado chart (``tornado_<metric>.png``: for each group, the metric's range over its
    factors around the base value, groups sorted by that range)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(out / "sensitivity.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    metrics = [m for m in METRICS if any(m in r for r in rows)]
    # whether each number can be trusted: a drape that did not settle, episodes that diverged
    columns = metrics + [c for c in ("settled", "diverged") if any(c in r for r in rows)]
    lines = ["| variant | model | " + " | ".join(columns) + " |", "|---|---|" + "---|" * len(columns)]
    for r in rows:
        cells = [f"{r[m]:.3f}" if isinstance(r.get(m), float) else str(r.get(m, "")) for m in columns]
        lines.append(f"| {r['label']} | {r['model']} | " + " | ".join(cells) + " |")
    if any("settled" in r for r in rows):
        unsettled = [r["label"] for r in rows if r.get("settled") is False]
        if len(unsettled) == sum("settled" in r for r in rows):
            lines += ["", "**No drape settled** within the time allowed: every drape number above is of a "
                      "cloth still moving. Allow more time (`max_time_s`) or a coarser lattice."]
        elif unsettled:
            lines += ["", f"Not settled within the time allowed (their drape numbers are of a moving cloth): "
                      f"{', '.join(unsettled)}."]
    (out / "sensitivity.md").write_text("\n".join(lines) + "\n")
    (out / "sensitivity.json").write_text(json.dumps({"meta": meta or {}, "rows": rows}, indent=2))
    files = {"csv": out / "sensitivity.csv", "md": out / "sensitivity.md"}
    for m in metrics:
        p = tornado(rows, m, out / f"tornado_{m}.png")
        if p is not None:
            files[f"tornado_{m}"] = p
    return files


def tornado(rows: list[dict], metric: str, path: Path) -> Path | None:
    """Tornado chart of ``metric``: one bar per group from its lowest to its highest value over
    the factors swept, against the base material's value (a vertical line); the sweep's other
    whole materials and models (wool, Breen's model) as dashed lines, for scale."""
    from cloth_gym.reports import figure  # an Agg canvas of its own: pyplot's backend is left alone

    scaled = [r for r in rows if r.get("group") and metric in r]
    if not scaled:
        return None
    base_name = scaled[0]["base"]
    base = [r[metric] for r in rows if not r.get("group") and r["base"] == base_name and r["model"] == "kes"
            and metric in r]
    ref = base[0] if base else float(np.median([r[metric] for r in scaled]))
    spans = {}
    for r in scaled:
        lo, hi, flo, fhi = spans.get(r["group"], (math.inf, -math.inf, None, None))
        v = r[metric]
        if v < lo:
            lo, flo = v, r["factor"]
        if v > hi:
            hi, fhi = v, r["factor"]
        spans[r["group"]] = (lo, hi, flo, fhi)
    # the bar spans the base value too; an end that is the base value gets no factor label
    spans = {g: (min(lo, ref), max(hi, ref), flo if lo < ref else None, fhi if hi > ref else None)
             for g, (lo, hi, flo, fhi) in spans.items()}
    order = sorted(spans, key=lambda g: spans[g][1] - spans[g][0])
    fig = figure((7, 0.5 * len(order) + 1.5))
    ax = fig.subplots()
    for k, g in enumerate(order):
        lo, hi, flo, fhi = spans[g]
        ax.barh(k, hi - lo, left=lo, color="C0", alpha=0.7)
        ax.text(hi, k, f" ×{fhi:g}" if fhi is not None else "", va="center", fontsize=8)
        ax.text(lo, k, f"×{flo:g} " if flo is not None else "", va="center", ha="right", fontsize=8)
    ax.axvline(ref, color="k", lw=1, label=f"{base_name} (the base)")
    # the other whole materials and models of the sweep (wool, Breen's model), for scale
    others = [r for r in rows if not r.get("group") and metric in r and not (r["base"] == base_name
                                                                             and r["model"] == "kes")]
    for k, r in enumerate(others):
        ax.axvline(r[metric], color=f"C{k + 1}", lw=1, ls="--", label=f"{r['label']} = {r[metric]:.3g}")
    if all(hi == lo for lo, hi, _, _ in spans.values()):
        ax.text(0.5, 0.5, f"no parameter group changes {metric}\nover the factors swept", transform=ax.transAxes,
                ha="center", va="center", fontsize=9, color="0.3")
    lo_all = min([v[0] for v in spans.values()] + [r[metric] for r in others])
    hi_all = max([v[1] for v in spans.values()] + [r[metric] for r in others])
    pad = 0.15 * (hi_all - lo_all) or 0.05 * max(abs(ref), 1.0)
    ax.set_xlim(lo_all - pad, hi_all + pad)  # room for the factor labels at both ends
    ax.set_yticks(range(len(order)), [f"{g}\n({GROUPS.get(g, '')})" for g in order], fontsize=8)
    ax.set_xlabel(f"{metric} ({base_name} = {ref:.3g})")
    ax.set_title(f"Sensitivity of {metric} to each KES parameter group", fontsize=10)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return path


def heatmap(rows: list[dict], path: Path, metric: str = "success_rate") -> Path:
    """A fabric × case grid of ``metric`` (rows of :func:`library_sweep`): one row per fabric, one
    column per (env, policy), each cell coloured by the success rate and labelled with it and the
    mean return."""
    from cloth_gym.reports import figure

    cases = list(dict.fromkeys((r["env_id"], r["policy"]) for r in rows))
    fabrics = list(dict.fromkeys(r["label"] for r in rows))
    cell = {(r["label"], (r["env_id"], r["policy"])): r for r in rows}
    grid = np.full((len(fabrics), len(cases)), np.nan)
    for i, f in enumerate(fabrics):
        for j, c in enumerate(cases):
            if (f, c) in cell:
                grid[i, j] = cell[f, c][metric]
    fig = figure((1.6 * len(cases) + 3.2, 0.42 * len(fabrics) + 1.8))
    ax = fig.subplots()
    im = ax.imshow(grid, cmap="RdYlGn", vmin=0.0, vmax=1.0 if metric == "success_rate" else None, aspect="auto")
    for i, f in enumerate(fabrics):
        for j, c in enumerate(cases):
            r = cell.get((f, c))
            if r is not None:
                text = f"{r[metric]:.2f}" + (f"\n{r['return_mean']:.0f}" if "return_mean" in r else "")
                ax.text(j, i, text, ha="center", va="center", fontsize=7)
    ax.set_xticks(range(len(cases)), [f"{e.split('/')[-1]}\n{p}" for e, p in cases], fontsize=8)
    ax.set_yticks(range(len(fabrics)), fabrics, fontsize=8)
    ax.set_title(f"{metric} (colour, top) and mean return (bottom) per fabric", fontsize=10)
    fig.colorbar(im, ax=ax, fraction=0.04)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    return path


def write_library_report(rows: list[dict], out_dir: str | Path, meta: dict | None = None) -> dict:
    """``library.json`` (meta and rows), ``library.md`` (a fabric × case table: success rate,
    mean return, episodes diverged) and ``heatmap_success_rate.png`` in ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cases = list(dict.fromkeys((r["env_id"], r["policy"]) for r in rows))
    cell = {(r["label"], (r["env_id"], r["policy"])): r for r in rows}
    lines = ["| fabric | " + " | ".join(f"{e.split('/')[-1]} {p}" for e, p in cases) + " |",
             "|---|" + "---|" * len(cases)]
    for f in dict.fromkeys(r["label"] for r in rows):
        cells = []
        for c in cases:
            r = cell.get((f, c))
            cells.append("—" if r is None else f"{r['success_rate']:.2f} ({r['return_mean']:.0f})"
                         + (f", {r['diverged']} diverged" if r.get("diverged") else ""))
        lines.append(f"| {f} | " + " | ".join(cells) + " |")
    (out / "library.md").write_text("success rate (mean return) per fabric\n\n" + "\n".join(lines) + "\n")
    (out / "library.json").write_text(json.dumps({"meta": meta or {}, "rows": rows}, indent=2) + "\n")
    return {"md": out / "library.md", "json": out / "library.json",
            "heatmap": heatmap(rows, out / "heatmap_success_rate.png")}
