"""What a calibration-map run will cost, from its grid and from runs already made.

The plan counts, per method, the cells it applies to and the posterior runs
(cells x scenes per cell).  The expected CPU multiplies each (group, method)'s
run count by the mean CPU per run measured by earlier studies of the same
method, the same K and the same emcee step cap (the ``seconds`` column of every
``*.nc`` result found in the output folder, whatever its mode); where no such
run exists it falls back to the same method and K under any cap, then to the
same method at any K, and says so.  Nothing here is a hard-coded timing: with
an empty folder the plan is printed without a CPU figure (run the quick mode
first, into the same folder, to calibrate the estimate).
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np

__all__ = ["plan", "measured_cpu", "estimate_text"]


def plan(group_list: list[tuple[str, dict, dict]], methods: dict, names: list[str],
         n: int) -> list[dict]:
    """One row per (group, method): ``cells`` it applies to and ``runs`` = cells x n."""
    rows = []
    for tag, grid, fixed in group_list:
        cells = [{**fixed, **dict(zip(grid, c))} for c in itertools.product(*grid.values())]
        for name in names:
            k = sum(bool(methods[name].applies(c)) for c in cells)
            rows.append(dict(group=tag, method=name, k=int(fixed["n_sources"]), cells=k,
                             runs=k * n))
    return rows


def measured_cpu(out: Path) -> dict[tuple[str, int, int], tuple[float, int]]:
    """``{(method, K, max_steps): (mean CPU s per run, runs)}`` from the results in ``out``."""
    import xarray as xr

    acc: dict[tuple[str, int, int], list[float]] = {}
    for path in sorted(Path(out).glob("*.nc")) if Path(out).is_dir() else ():
        try:
            with xr.open_dataset(path) as ds:
                fx = json.loads(ds.attrs["fixed_settings"])
                ok = ds["applies"].values.astype(bool)
                sec = ds["seconds"].values[ok]
        except (OSError, KeyError, ValueError):  # not a calibration-map result
            continue
        key = (str(fx["method"]), int(fx["n_sources"]), int(fx.get("max_steps", 0)))
        acc.setdefault(key, []).extend(float(s) for s in sec if np.isfinite(s))
    return {k: (float(np.mean(v)), len(v)) for k, v in acc.items() if v}


def _per_run(measured: dict, method: str, k: int, max_steps: int) -> tuple[float, str]:
    """Mean CPU per run for (method, K, cap), with the fall-backs of the module docstring."""
    if (method, k, max_steps) in measured:
        return measured[(method, k, max_steps)][0], ""
    same_k = [(v, cap) for (m, kk, cap), v in measured.items() if m == method and kk == k]
    if same_k and not method.startswith("emcee"):  # the step cap bounds emcee only
        return _pooled([v for v, _ in same_k]), ""
    if same_k:
        lower = max_steps > max(cap for _, cap in same_k) and method.startswith("emcee")
        return _pooled([v for v, _ in same_k]), ("measured under a lower step cap: a lower "
                                                 "bound" if lower else "other step cap")
    any_k = [v for (m, _, _), v in measured.items() if m == method]
    if any_k:
        return _pooled(any_k), "other K"
    return np.nan, "not measured"


def _pooled(values: list[tuple[float, int]]) -> float:
    return float(sum(m * c for m, c in values) / sum(c for _, c in values))


def estimate_text(rows: list[dict], measured: dict, max_steps: int, mode: str, n: int
                  ) -> str:
    """The plan of a run and its expected CPU, one line per method and a total."""
    by_method: dict[str, list[dict]] = {}
    for r in rows:
        by_method.setdefault(r["method"], []).append(r)
    n_cells = max((sum(r["cells"] for r in rs) for rs in by_method.values()), default=0)
    lines = [f"calibration map, {mode} mode: up to {n_cells} cells x {n} scenes per cell x "
             f"{len(by_method)} method(s), emcee capped at {max_steps} steps"]
    total, unknown = 0.0, False
    for method, rs in by_method.items():
        runs = sum(r["runs"] for r in rs)
        cpu, notes = 0.0, set()
        for r in rs:
            if r["runs"]:
                per, note = _per_run(measured, method, r["k"], max_steps)
                cpu += per * r["runs"]
                notes.add(note)
        notes.discard("")
        what = "CPU unknown" if not np.isfinite(cpu) else f"~{cpu / 3600:.2f} CPU-h"
        extra = f" ({'; '.join(sorted(notes))})" if notes else ""
        lines.append(f"  {method:15s} {sum(r['cells'] for r in rs):4d} cells "
                     f"{runs:6d} runs  {what}{extra}")
        if np.isfinite(cpu):
            total += cpu
        elif runs:
            unknown = True
    if unknown and total == 0:
        lines.append("  expected total unknown: no method was measured in this folder yet")
        return "\n".join(lines)
    tail = " + the methods never measured in this folder" if unknown else ""
    lines.append(f"  expected total ~{total / 3600:.2f} CPU-h{tail} (from the mean CPU per "
                 "run of earlier results in --out; divide by the workers for wall time)")
    return "\n".join(lines)
