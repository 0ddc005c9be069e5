"""Calibration map: where each posterior method is calibrated, where it fails, by how much.

For every cell -- geometry (ring of 30, Fibonacci sphere of 64), number of
sources K, separation of neighbouring sources (sensor spacings; a chain of K
sources) and per-source SNR (intensity / sigma, intensities Uniform(0.7, 1.3)),
plus, for K = 4 rings, the distance of the nearest pair from antipodal as an
axis of its own (uniform scenes with neighbours >= 2 spacings apart, binned by
that distance) -- scenes are simulated and given to every posterior method of
``_calmap.METHODS`` (emcee default -- the automatic choice --, one ensemble, one ensemble
per mode, Laplace = ML + inverse-Fisher Gaussian, the
exact grid posterior where it applies, imaging at the known directions).  Per
cell and method:

* SBC: Kolmogorov-Smirnov uniformity of the posterior CDF at the truth, per
  parameter, Bonferroni-combined (``sbc_p``);
* coverage of the central 50 % and 90 % intervals, pooled over parameters; for
  emcee rows with both kinds of runs also the 90 % coverage of the runs that
  converged (``cov90_conv``: is a failure hidden in runs that raise no
  ConvergenceWarning?);
* for the Laplace rows also the ML efficiency (1 / mean squared error in CRLB
  units, the worse of directions and intensities, over scenes with a regular
  Fisher matrix), the share of such scenes, and the accuracy of K selected by
  Laplace evidences (k_max = K + 1).

A cell is *calibrated* when sbc_p > 0.01 and both coverages are within 0.03
of nominal; it *fails* when sbc_p <= 0.01 or a coverage is outside that band by
more than three binomial standard errors of a coverage over the cell's scenes
(the parameters of one scene often miss together, so scenes, not parameters,
are counted); otherwise it is *undecided* (too few scenes to tell).  Scenes of a
cell are drawn from the cell, not from the posterior's prior (uniform
directions, intensities Uniform(0, 2)), so ranks and coverage are conditional
on the cell: exactly uniform only where the likelihood dominates the prior;
the exact grid posterior (K <= 2, SNR <= 300) is the control that shows how
large that effect is.

Each (group, method) is its own resumable study (checkpoint in --out); methods
of a group share the study seed, so they see the same scenes.  Modes (the
grids of :data:`MODES`; cells counted over all groups, methods where they apply):

* quick (default): 13 cells x 6 scenes x 7 methods, emcee capped at 3000 steps;
* ``--medium``: 50 cells x 16 scenes x 7 methods (800 runs of the default emcee,
  704 of each of the two other emcee variants);
* ``--full`` (the reference grid): 81 cells x 100 scenes x 7 methods -- 8100 runs
  of the default emcee, 7200 of each other emcee variant, 8100 Laplace and
  imaging runs, 1200 exact-grid runs -- at the sampler's step cap of 20000;
  emcee dominates, so this is a many-CPU-hour job (``--estimate`` projects it).

--ks / --groups / --methods / --trials / --max-steps restrict a run.  Before
it starts, a run prints its plan (cells x scenes x methods) and the CPU it is
expected to take, projected from the CPU per run of earlier results in --out
(:mod:`_calmap_cost`); ``--estimate`` prints that and stops.  ``--report`` runs
nothing and summarises the (group, method) studies already finished in --out, so
a long run can be read while it goes on.  Outputs in --out:
calibration_map-<mode>.png, .csv and .txt, and the studies' checkpoints and
NetCDF files.
"""

from __future__ import annotations

import json
import os
import sys

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _calmap import METHODS, calmap_trial  # noqa: E402
from _calmap_cost import estimate_text, measured_cpu, plan  # noqa: E402
from _calmap_plot import plot_map  # noqa: E402
from _study_cli import parser, study, table  # noqa: E402

from olsbayes._io import write_text_atomic  # noqa: E402

__all__ = ["main", "groups", "summarise", "cell_state", "reference_table"]

#: Per mode: Ks of the ring, separations, SNRs, trials per cell, emcee step cap.
MODES = {
    "quick": dict(ks=(1, 2, 4), seps=(1.0, 3.0), snrs=(30.0, 1000.0), n=6, max_steps=3000,
                  anti=(0.0, 2.0), anti_snrs=(1000.0,), sphere=((2, 2.0, 100.0),)),
    "medium": dict(ks=(1, 2, 3, 4), seps=(0.5, 1.0, 2.0, 5.0), snrs=(10.0, 100.0, 1e4), n=16,
                   max_steps=20000, anti=(0.0, 0.5, 1.0, 2.0), anti_snrs=(100.0, 1e4),
                   sphere=((1, 0.0, 100.0), (2, 1.0, 100.0), (2, 3.0, 100.0))),
    "full": dict(ks=(1, 2, 3, 4), seps=(0.5, 1.0, 2.0, 3.0, 5.0), snrs=(10.0, 100.0, 1e3, 1e4),
                 n=100, max_steps=20000, anti=(0.0, 0.5, 1.0, 2.0),
                 anti_snrs=(100.0, 1e3, 1e4),
                 sphere=((1, 0.0, 100.0), (2, 1.0, 100.0), (2, 3.0, 100.0),
                         (2, 1.0, 1e3), (2, 3.0, 1e3))),
}
NOMINAL = (0.5, 0.9)
BAND = 0.03


def groups(mode: dict, ks: tuple | None = None) -> list[tuple[str, dict, dict]]:
    """``(tag, grid, fixed)`` of every group of cells (one study per group and method).

    The x axis of a group is ``separation`` or, for the antipodal group, ``antipodal``.
    """
    out = []
    for k in mode["ks"]:
        if ks and k not in ks:
            continue
        seps = [0.0] if k == 1 else list(mode["seps"])
        out.append((f"ring-k{k}", {"separation": seps, "snr": list(mode["snrs"])},
                    {"geometry": "ring", "n_sources": k, "antipodal": -1.0}))
    if not ks or 4 in ks:
        out.append(("ring-k4-antipodal", {"antipodal": list(mode["anti"]),
                                          "snr": list(mode["anti_snrs"])},
                    {"geometry": "ring", "n_sources": 4, "separation": 0.0}))
    for k in sorted({k for k, _, _ in mode["sphere"]}):
        if ks and k not in ks:
            continue
        cells = [(s, r) for kk, s, r in mode["sphere"] if kk == k]
        out.append((f"sphere-k{k}", {"separation": sorted({s for s, _ in cells}),
                                     "snr": sorted({r for _, r in cells})},
                    {"geometry": "sphere", "n_sources": k, "antipodal": -1.0}))
    return out


def _coverage(u: np.ndarray, level: float) -> np.ndarray:
    return np.abs(u - 0.5) < level / 2


def sbc_p(u: np.ndarray) -> float:
    """Bonferroni-combined KS p-value of uniformity over the columns of ``u`` (T, P)."""
    ps = [stats.kstest(c[np.isfinite(c)], "uniform").pvalue for c in u.T
          if np.isfinite(c).sum() >= 3]
    return float(min(1.0, len(ps) * min(ps))) if ps else np.nan


def cell_state(p: float, cov: tuple[float, float], n: int) -> str:
    """"calibrated", "fails" or "undecided" (see the module docstring); "" if n == 0.

    ``p`` NaN (fewer than 3 scenes) never makes a cell calibrated nor failing.
    """
    if n == 0:
        return ""
    dev = [abs(c - q) for c, q in zip(cov, NOMINAL)]
    if p > 0.01 and max(dev) <= BAND:
        return "calibrated"
    se = [np.sqrt(q * (1 - q) / n) for q in NOMINAL]
    if p <= 0.01 or any(d > BAND + 3 * s for d, s in zip(dev, se)):
        return "fails"
    return "undecided"


def _cell_row(c, k: int) -> dict:
    """Statistics of one cell ``c`` (a dataset of one method at one cell) of K sources."""
    ok = c["applies"].values.astype(bool)
    u = c["u"].values[ok]
    u = u[:, np.isfinite(u).any(axis=0)] if len(u) else u
    answered = np.isfinite(u).all(axis=1) if u.size else np.zeros(0, bool)
    ua = u[answered]
    vals = ua[np.isfinite(ua)]
    cov = tuple(float(_coverage(vals, q).mean()) if vals.size else np.nan for q in NOMINAL)
    p = sbc_p(ua) if len(ua) else np.nan
    row = dict(n=int(ok.sum()), no_answer=int(ok.sum() - answered.sum()),
               converged=float(c["converged"].values[ok].mean()) if ok.any() else np.nan,
               cov50=cov[0], cov90=cov[1], sbc_p=p,
               state=cell_state(p, cov, int(answered.sum())),
               gap=float(np.median(c["gap"].values)),
               cpu_s=float(c["seconds"].values[ok].mean()) if ok.any() else np.nan)
    z2 = c["z2"].values
    if (~np.isnan(z2)).any():  # inf: singular Fisher matrix at the truth
        reg = np.all(np.isfinite(z2), axis=1)
        row["ml_eff"] = float(1 / np.max(z2[reg].mean(axis=0))) if reg.any() else np.nan
        row["regular"] = float(reg.mean())
        row["sel_acc"] = float(np.mean(c["k_hat"].values == k))
    conv = c["converged"].values[ok][answered] if u.size else np.zeros(0, bool)
    if conv.any() and not conv.all():
        # runs that raised no ConvergenceWarning: is the cell's miscoverage in them?
        vals = ua[conv][np.isfinite(ua[conv])]
        row["cov90_conv"] = float(_coverage(vals, 0.9).mean())
    rh = c["rhat"].values[ok]
    if np.isfinite(rh).any():
        row["rhat_max"] = float(np.nanmax(rh))
    return row


def summarise(results: dict) -> list[dict]:
    """One row per (group, method, cell) from ``{(tag, method): dataset}``."""
    rows = []
    for (tag, method), ds in results.items():
        k = int(json.loads(ds.attrs["fixed_settings"])["n_sources"])
        xname = "antipodal" if "antipodal" in ds.dims else "separation"
        for x in ds[xname].values:
            for snr in ds["snr"].values:
                row = _cell_row(ds.sel({xname: x, "snr": snr}), k)
                rows.append(dict(group=tag, method=method, x_name=xname, x=float(x),
                                 snr=float(snr), **row))
    return rows


def print_table(rows: list[dict]) -> str:
    head = ["group", "method", "x", "snr", "n", "no_ans", "conv", "gap", "cov50", "cov90",
            "cov90c", "sbc_p", "state", "ml_eff", "regular", "sel_acc", "cpu_s"]
    body = [[r["group"], r["method"], f"{r['x_name'][:3]}={r['x']:g}", f"{r['snr']:g}", r["n"],
             r["no_answer"], r["converged"], r["gap"], r["cov50"], r["cov90"],
             r.get("cov90_conv", ""), r["sbc_p"],
             r["state"] or "-", r.get("ml_eff", ""), r.get("regular", ""),
             r.get("sel_acc", ""), r["cpu_s"]] for r in rows]
    return table(head, body, digits=2)


def _mode_help(name: str) -> str:
    """--help of a mode: its grid's cells x scenes x methods, counted from :data:`MODES`."""
    mode = MODES[name]
    rows = plan(groups(mode), METHODS, list(METHODS), mode["n"])
    cells = max(sum(r["cells"] for r in rows if r["method"] == m) for m in METHODS)
    emcee = sum(r["runs"] for r in rows if r["method"].startswith("emcee"))
    return (f"the {name} grid: {cells} cells x {mode['n']} scenes per cell x {len(METHODS)} "
            f"methods ({emcee} emcee runs, capped at {mode['max_steps']} steps)")


def reference_table(rows: list[dict]) -> str:
    """Per (group, method): cells calibrated / failing / undecided, the worst coverage
    (the 50 % or 90 % coverage furthest from nominal, over cells with an answer) and
    the failing cells as ``x/snr``."""
    out = []
    for key in dict.fromkeys((r["group"], r["method"]) for r in rows):
        cells = [r for r in rows if (r["group"], r["method"]) == key and r["state"]]
        if not cells:
            continue
        count = {s: sum(r["state"] == s for r in cells) for s in
                 ("calibrated", "fails", "undecided")}
        devs = [(abs(r[f"cov{q}"] - q / 100), r[f"cov{q}"], q) for r in cells
                for q in (50, 90) if np.isfinite(r[f"cov{q}"])]
        worst = max(devs) if devs else (np.nan, np.nan, 90)
        failing = " ".join(f"{r['x']:g}/{r['snr']:g}" for r in cells if r["state"] == "fails")
        out.append([*key, len(cells), count["calibrated"], count["fails"],
                    count["undecided"], f"{worst[1]:.2f} ({worst[2]} %)", failing or "-"])
    head = ["group", "method", "cells", "calibrated", "fails", "undecided", "worst cov",
            "failing cells (x/snr)"]
    return table(head, out)


def main(argv: list[str] | None = None) -> int:
    ap = parser("calibration_map", __doc__, full_help=_mode_help("full"))
    ap.add_argument("--medium", action="store_true", help=_mode_help("medium"))
    ap.add_argument("--estimate", action="store_true",
                    help="print the run's plan and expected CPU (from earlier results in "
                    "--out) and stop")
    ap.add_argument("--report", action="store_true",
                    help="run nothing: summarise the (group, method) studies already finished "
                    "in --out (a long run can be read while it goes on)")
    ap.add_argument("--ks", type=int, nargs="*", default=None, help="only these K")
    ap.add_argument("--groups", nargs="*", default=None,
                    help="only these groups, e.g. ring-k4-antipodal sphere-k2")
    ap.add_argument("--methods", nargs="*", default=list(METHODS), choices=list(METHODS))
    ap.add_argument("--trials", type=int, default=None, help="scenes per cell (override)")
    ap.add_argument("--max-steps", type=int, default=None,
                    help="cap on the emcee steps (override; 20000 is the sampler's default)")
    args = ap.parse_args(argv)
    name = "full" if args.full else "medium" if args.medium else "quick"
    mode = MODES[name]
    args.full = name != "quick"  # checkpoints named per mode below
    n = args.trials or mode["n"]
    selected = [g for g in groups(mode, tuple(args.ks or ()))
                if not args.groups or g[0] in args.groups]
    cap = args.max_steps or mode["max_steps"]
    if not args.report:
        print(estimate_text(plan(selected, METHODS, args.methods, n), measured_cpu(args.out),
                            cap, name, n), flush=True)
    if args.estimate:
        return 0
    results = (_finished(args, name, selected) if args.report
               else _run(args, name, mode, selected, n, cap))
    if not results:
        print(f"no finished study of the {name} grid in {args.out}")
        return 0
    rows = summarise(results)
    text = print_table(rows) + "\n\n" + reference_table(rows)
    if args.report:
        total = len(selected) * len(args.methods)
        text = (f"{len(results)} of {total} (group, method) studies finished; the others "
                "are left out\n\n" + text)
    print(text)
    write_text_atomic(args.out / f"calibration_map-{name}.txt", text + "\n")
    keys = list(dict.fromkeys(k for r in rows for k in r))
    csv = ",".join(keys) + "\n" + "\n".join(",".join(str(r.get(k, "")) for k in keys)
                                            for r in rows)
    write_text_atomic(args.out / f"calibration_map-{name}.csv", csv + "\n")
    plot_map(rows, args.out / f"calibration_map-{name}.png", name, n)
    print(f"wrote {args.out / f'calibration_map-{name}.png'}")
    return 0


def _run(args, name: str, mode: dict, selected: list, n: int, cap: int) -> dict:
    """Run (or resume) one study per selected (group, method): ``{(tag, method): dataset}``."""
    results = {}
    # a group's seed depends on its place among all groups of the mode only, so a run
    # restricted with --ks / --groups sees (and resumes) the same scenes
    offsets = {t: 1000 * g for g, (t, _, _) in enumerate(groups(mode))}
    for tag, grid, fixed in selected:
        for method in args.methods:
            fx = {**fixed, "method": method, "max_steps": cap}
            results[(tag, method)] = study(args, f"{name}-{tag}-{method}", calmap_trial, grid,
                                           n, fixed=fx, seed_offset=offsets[tag], chunk_size=1)
    return results


def _finished(args, name: str, selected: list) -> dict:
    """The finished studies (saved datasets) of the selected (group, method) in --out."""
    import xarray as xr

    suffix = "full" if args.full else "quick"  # as _study_cli.study names its files
    results = {}
    for tag, _, _ in selected:
        for method in args.methods:
            path = args.out / f"{name}-{tag}-{method}-{suffix}.nc"
            if path.is_file():
                with xr.open_dataset(path) as ds:
                    results[(tag, method)] = ds.load()
    return results


if __name__ == "__main__":
    raise SystemExit(main())
