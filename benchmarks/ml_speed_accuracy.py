"""Speed and accuracy of the ML estimators, side by side on the same simulated data.

Settings (ring of N = 30 clipped-cosine sub-sensors):

* Fig. 3: two sources pi apart, intensities 1.0 and 0.2, sigma in {1e-3, 1e-2, 1e-1};
* K = 1..4 well-separated sources, sigma = 1e-2 and 1e-3, intensities 1.0 .. 0.6; angles
  0.37 + 2 pi k / K + 0.13 k for K <= 3, and 0.37 + (0, 60, 150, 260) deg for K = 4.
  The formula's K = 4 scene (spacing ~97 deg) is not identifiable on this array:
  each source's kink (90 deg away) falls ~7 deg from its neighbour, so most
  sub-sensors see the same pair of sources, the per-arc sinusoids
  I_j cos(a_j - t) + I_{j+1} cos(a_{j+1} - t) determine the phasors only up to
  an alternating shift, and an exact alternative scene ~30 CRLB std away
  reproduces all 30 noiseless readings to 1e-16 (evenly spaced K = 4 scenes
  are mostly Fisher-singular).  Each setting's identifiability is checked and
  printed: noiseless data fitted by fast and by multistart with 200 starts; an
  exact fit (max residual < 1e-9) far from the truth means an ambiguous scene.

These fixed scenes are single points of a distribution: ``--scenes N`` adds N
random well-separated scenes per K = 2, 3, 4 (angles uniform, neighbours >= 30
deg apart, I ~ U(0.5, 1), identifiable), at sigma = 1e-2 and 1e-3: the share of
fast and multistart fits reaching the best optimum found, and the distribution
over scenes of the efficiency of the fast fits (the global ML) next to that of
an LM run started at the truth (a local ML that cannot jump to a rival mode).
The benchmark's K = 4 scene, rotated by 3-6 deg, stopped half of the fast fits
in a rival mode with the old 3-subset search (now 24 subsets from K = 4 on).

Methods: ``fast`` (one ``fit_ml`` call per data vector), ``batch`` (one ``fit_ml``
call on all T data vectors, time divided by T), ``paper`` (the paper's method as the
paper ran it, :mod:`_paper_baseline`: pseudo-random starts each refined by BFGS, with
the number of starts M99 that reaches the global optimum in 99 % of the data vectors
of this setting -- measured first on ``--pilot`` data vectors with 40 starts each,
against the exact ML and the fast fit), ``multistart`` (``fit_ml(method="multistart")``: 20
pseudo-random starts + L-BFGS-B), both on the first T_ms data vectors, and ``exact``
(``fit_ml(method="exact")``, one batched call: the global optimum, by enumerating the
ring's linear cells).  The exact row is the reference for the global-optimum share,
and its efficiency is that of the ML estimator itself: where it is below 1 (K = 4 at
sigma = 1e-2, where another cell's optimum beats the one near the truth in ~13 % of
draws), no search can do better.  Every row is timed interleaved: the single fits
(fast, paper, multistart) alternate in blocks of ``--block`` data vectors (10), so
all see the same machine load with warm caches, as in a user's loop of fits, and the
whole-batch calls (batch, exact) run ``--batch-reps`` times (3) spread between the
blocks (median); every method runs once on other data first (compiled code, tuple
plans and the exact enumeration's tables are loaded before any timing).

A last row per setting, ``oracle``, is an LM run started at the truth: a local
ML that cannot jump to another cell's optimum, untimed (it is not an estimator).
Where the exact ML's efficiency falls short of the oracle's, the ML estimator
itself jumps between optima, whatever finds them.

Per method and setting: efficiency per parameter (CRLB variance / mean squared
error), failure rate (some parameter off by more than 5 CRLB std), the share of
fits reaching the best optimum any method (the exact one, or the oracle) found
-- to within 1e-6 and 1e-3 in log-likelihood -- and the median time per fit, as
CPU time of this process (``time.process_time``) and wall-clock time.  Then the
speed ratios against the paper's method and against the 20-start variant, and the
ML estimator's targets judged on this run.  CPU time is the primary measure: the
machine is shared, and wall-clock times include waiting for a core, which depends
on other processes' load.  Run ``python
benchmarks/ml_speed_accuracy.py`` (quick: some 20 minutes) or ``--full`` (T = T_ms
= 1000).  BLAS threads are pinned to 1 so that timings on a shared machine
measure the algorithms, not thread contention.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MPLBACKEND", "Agg")

import argparse  # noqa: E402
import csv  # noqa: E402
import io  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from _ml_scenes import efficiency_only, scene_study  # noqa: E402
from _paper_baseline import bfgs_starts, paper_fit, starts_for_success  # noqa: E402

import olsbayes as ob  # noqa: E402
from olsbayes._io import write_text_atomic  # noqa: E402
from olsbayes.exchange import estimation_errors  # noqa: E402
from olsbayes.ml import MultistartOptions, fit_ml  # noqa: E402
from olsbayes.ml.atoms import cached_default_grid  # noqa: E402
from olsbayes.ml.lm import refine_batch  # noqa: E402


def settings() -> list[tuple[str, float, ob.Scene]]:
    out = []
    for sigma in (1e-3, 1e-2, 1e-1):
        out.append((f"fig3 s={sigma:g}", sigma,
                    ob.Scene(directions=[0.5, 0.5 + np.pi], intensities=[1.0, 0.2])))
    for sigma in (1e-2, 1e-3):
        for k in (1, 2, 3, 4):
            ang = 0.37 + 2 * np.pi * np.arange(k) / k + 0.13 * np.arange(k)  # no symmetry
            if k == 4:  # the formula's K = 4 scene is ambiguous (see the module docstring)
                ang = 0.37 + np.radians([0.0, 60.0, 150.0, 260.0])
            out.append((f"K={k} s={sigma:g}", sigma,
                        ob.Scene(directions=ang, intensities=np.linspace(1.0, 0.6, k))))
    return out


def identifiability(model: ob.Model, scene: ob.Scene, std: np.ndarray) -> str:
    """Fit noiseless data (fast; multistart with 200 starts): exact fits far from truth?"""
    truth = model.canonical(model.pack(scene))
    mu = model.response(truth)
    parts = []
    for meth, opts in (("fast", {}), ("multistart", dict(rng=0, options=MultistartOptions(200)))):
        r = fit_ml(model, mu, scene.n_sources, method=meth, **opts)
        resid = float(np.max(np.abs(model.response(r.params) - mu)))
        dist = float(np.max(np.abs(estimation_errors(model, r.params, truth)) / std))
        parts.append(f"{meth}: max residual {resid:.1e}, max |error|/CRLB std {dist:.1e}")
    return "; ".join(parts)


def _timed_rows(singles: dict, batches: dict, data: np.ndarray, n_ms: int, block: int,
                reps: int) -> dict:
    """Every method timed interleaved: per method (results, CPU s per fit, wall s per fit).

    ``singles``: name -> (fit of one data vector, how many data vectors); they alternate
    in blocks of ``block`` data vectors.  ``batches``: name -> fit of all data vectors,
    run ``reps`` times spread between the blocks (time divided by T; median over reps).
    """
    res = {name: [] for name in singles}
    cpu = {name: [] for name in (*singles, *batches)}
    wall = {name: [] for name in (*singles, *batches)}
    t = data.shape[0]
    starts = list(range(0, t, block))
    at = {starts[int(j)] for j in np.linspace(0, len(starts) - 1, reps).round()}
    for lo in starts:
        for name, (fn, n) in singles.items():
            for s in data[lo : min(lo + block, n)]:
                c0, t0 = time.process_time(), time.perf_counter()
                res[name].append(fn(s))
                wall[name].append(time.perf_counter() - t0)
                cpu[name].append(time.process_time() - c0)
        if lo in at:
            for name, fn in batches.items():
                c0, t0 = time.process_time(), time.perf_counter()
                res[name] = fn(data)
                wall[name].append((time.perf_counter() - t0) / t)
                cpu[name].append((time.process_time() - c0) / t)
    return {name: (res[name], float(np.median(cpu[name])), float(np.median(wall[name])))
            for name in cpu}


#: Rows per setting: the estimators, then the LM run started at the truth (an oracle,
#: not an estimator: a local ML that cannot jump to another cell's optimum).
METHODS = ("fast", "batch", "paper", "multistart", "exact", "oracle")
#: BFGS starts per pilot data vector (the paper's method), and the most the timed
#: paper row runs (a larger M99 is printed with the timed row marked).
PILOT_STARTS, PAPER_MAX = 40, 200


def paper_starts(model, data: np.ndarray, k: int, grid: np.ndarray, rng
                 ) -> tuple[int, float, int]:
    """M99 of the paper's method on these data vectors, its per-start success rate, and
    the number of data vectors no start reached (M99 is unbounded if they exceed 1 %).

    A start succeeds when its BFGS optimum is within 1e-3 of the best log-likelihood of
    the exact ML, the fast fit and all starts (BFGS stops on a gradient tolerance).
    """
    ref = np.maximum(fit_ml(model, data, k, method="exact").log_likelihood,
                     fit_ml(model, data, k).log_likelihood)
    lls = np.array([bfgs_starts(model, s, k, PILOT_STARTS, grid, rng)[1] for s in data])
    ref = np.maximum(ref, lls.max(axis=1))
    hits = ref[:, None] - lls <= 1e-3
    return starts_for_success(hits), float(hits.mean()), int(np.sum(~hits.any(axis=1)))


def run_setting(name, sigma, scene, n_trials, n_ms, rng, block=10, n_pilot=40, reps=3):
    model = ob.Model(ob.Ring(30), sigma)
    k = scene.n_sources
    truth = model.canonical(model.pack(scene))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ob.KinkWarning)
        std = ob.crlb(model, scene.sorted()).std
    data = model.simulate(scene, rng=rng, size=n_trials)
    pilot = model.simulate(scene, rng=rng, size=n_pilot)
    grid = cached_default_grid(model)
    ms_rng = np.random.default_rng(rng.integers(2**63))
    paper_rng = np.random.default_rng(rng.integers(2**63))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", (ob.ConvergenceWarning, ob.MultimodalWarning))
        for d in (pilot[:2], pilot[0]):  # every method once before any timing
            for meth in ("fast", "exact", "multistart"):
                fit_ml(model, d, k, method=meth, rng=0)
        m99, p_start, missed = paper_starts(model, pilot, k, grid, paper_rng)
        m_run = min(m99, PAPER_MAX)
        out = _timed_rows(
            {"fast": (lambda s: fit_ml(model, s, k), n_trials),
             "paper": (lambda s: paper_fit(model, s, k, m_run, grid, paper_rng), n_ms),
             "multistart": (lambda s: fit_ml(model, s, k, method="multistart", rng=ms_rng),
                            n_ms)},
            {"batch": lambda d: fit_ml(model, d, k),
             "exact": lambda d: fit_ml(model, d, k, method="exact")},
            data, n_ms, block, reps)
        ident = identifiability(model, scene, std)
    res = {}
    for meth in ("fast", "multistart"):
        r, c, w = out[meth]
        res[meth] = (np.array([x.params for x in r]),
                     np.array([float(x.log_likelihood) for x in r]), c, w,
                     np.array([x.n_evaluations for x in r]))
    r, c, w = out["paper"]
    res["paper"] = (np.array([x[0] for x in r]), np.array([x[1] for x in r]), c, w,
                    np.full(len(r), np.nan))
    for meth in ("batch", "exact"):
        r, c, w = out[meth]
        res[meth] = (r.params, r.log_likelihood, c, w, r.n_evaluations)
    ref = refine_batch(model, data, np.repeat(truth[None], n_trials, axis=0))
    res["oracle"] = (model.canonical(ref.x), model.log_likelihood(ref.x, data), np.nan, np.nan,
                     ref.n_evaluations)
    best = np.max([res[m][1] for m in ("oracle", "fast", "batch", "exact")], axis=0)
    best[:n_ms] = np.max([best[:n_ms], res["multistart"][1], res["paper"][1]], axis=0)
    rows = []
    for meth in METHODS:
        params, ll, tcpu, twall, nev = res[meth]
        t = params.shape[0]
        err = estimation_errors(model, params, truth)
        eff = std**2 / np.mean(err**2, axis=0)
        fail = np.mean(np.any(np.abs(err) > 5 * std, axis=1))
        gap = best[:t] - ll
        rows.append(dict(setting=name, k=k, sigma=sigma, method=meth, trials=t,
                         eff_min=float(eff.min()), eff=" ".join(f"{e:.3f}" for e in eff),
                         fail=float(fail), glob6=float(np.mean(gap <= 1e-6)),
                         glob3=float(np.mean(gap <= 1e-3)), cpu_ms=1e3 * tcpu,
                         wall_ms=1e3 * twall, evals=float(np.nanmedian(nev))
                         if np.isfinite(nev).any() else np.nan, ident=ident,
                         m99=m99, m_run=m_run, p_start=p_start, missed=missed,
                         pilot=n_pilot))
    return rows


def print_table(rows: list[dict]) -> None:
    head = f"{'setting':14s} {'method':10s} {'T':>5s} {'eff per parameter':40s} " \
           f"{'fail':>6s} {'glob1e-6':>8s} {'glob1e-3':>8s} {'cpu ms':>8s} {'wall ms':>8s} " \
           f"{'evals':>6s}"
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['setting']:14s} {r['method']:10s} {r['trials']:5d} {r['eff']:40s} "
              f"{r['fail']:6.3f} {r['glob6']:8.4f} {r['glob3']:8.4f} {r['cpu_ms']:8.4f} "
              f"{r['wall_ms']:8.3f} {r['evals']:6.0f}")
    print("eff = CRLB variance / mean squared error; its sampling sd is ~sqrt(2/T) "
          "(0.063 at T=500, 0.032 at T=2000); evals = median forward-model evaluations "
          "(responses + Jacobians) per fit, over all starts/candidates (paper: not counted); "
          "oracle = LM started at the truth (not an estimator, untimed)")
    print("\npaper's method (pseudo-random starts + BFGS): starts for 99 % global optimum "
          f"(M99, measured on {PILOT_STARTS} starts per pilot data vector), per-start success:")
    for setting in dict.fromkeys(r["setting"] for r in rows):
        r = next(r for r in rows if r["setting"] == setting)
        m99 = (str(r["m99"]) if r["m99"] <= 10_000 else
               f"unbounded ({r['missed']} of {r['pilot']} pilot data vectors: no start reached)")
        timed = "" if r["m99"] <= PAPER_MAX else f", timed with {r['m_run']} starts"
        print(f"  {setting:14s} M99 = {m99}{timed}, per start {r['p_start']:.3f}")
    print("\nidentifiability (noiseless data):")
    for setting in dict.fromkeys(r["setting"] for r in rows):
        print(f"  {setting:14s} " + next(r["ident"] for r in rows if r["setting"] == setting))
    print("\nspeed ratios (baseline CPU time per fit / method CPU time per fit) against the "
          "paper's method with M99 starts [and against 20 starts + L-BFGS-B]:")
    for setting in dict.fromkeys(r["setting"] for r in rows):
        c = {r["method"]: r["cpu_ms"] for r in rows if r["setting"] == setting}
        print(f"  {setting:14s} " + "   ".join(
            f"{m} {c['paper'] / c[m]:8.1f}x [{c['multistart'] / c[m]:8.1f}x]"
            for m in ("fast", "batch", "exact")))


def _verdict(ok: bool) -> str:
    return "met    " if ok else "NOT met"


def print_targets(rows: list[dict]) -> None:
    """The ML estimator's targets, judged on this run's rows (speed ratios in CPU time).

    Efficiency counts as met at >= 0.95 - 2 sd (sd = sqrt(2 / T), the sampling sd
    of a variance ratio); a miss is shown next to the exact ML's and the oracle's
    efficiency, which tell an estimator's shortfall from the ML estimator's own.
    """
    by = {(r["setting"], r["method"]): r for r in rows}
    print("\ntargets (this run; speed against the paper's method with M99 starts, "
          "[20 starts + L-BFGS-B] for comparison):")
    for setting in dict.fromkeys(r["setting"] for r in rows):
        fast, batch, paper, ms, exact, orc = (by[setting, m] for m in METHODS)
        k, sigma = fast["k"], fast["sigma"]
        parts = []
        if sigma <= 1e-2:
            ok = 0.95 - 2 * np.sqrt(2 / batch["trials"])
            parts.append(f"eff >= 0.95 (-2 sd = {ok:.3f}): {_verdict(batch['eff_min'] >= ok)} "
                         f"{batch['eff_min']:.3f} [exact ML {exact['eff_min']:.3f}, "
                         f"oracle {orc['eff_min']:.3f}]")
        if k <= 3:
            share = min(fast["glob6"], batch["glob6"])
            parts.append(f"optimum >= 99.5 %: {_verdict(share >= 0.995)} {share:.4f}")
        need = 50 if k <= 2 else 20 if k == 3 else None
        if need:
            ratio = paper["cpu_ms"] / fast["cpu_ms"]
            ok = ratio >= need and fast["glob3"] >= paper["glob3"]
            parts.append(f"fast >= {need}x at equal success: {_verdict(ok)} {ratio:.0f}x "
                         f"[{ms['cpu_ms'] / fast['cpu_ms']:.0f}x]")
        ratio = paper["cpu_ms"] / batch["cpu_ms"]
        parts.append(f"batch >= 500x: {_verdict(ratio >= 500)} {ratio:.0f}x "
                     f"[{ms['cpu_ms'] / batch['cpu_ms']:.0f}x]")
        print(f"  {setting:14s} " + "; ".join(parts))


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r["setting"] for r in rows))
    meths = ["fast", "batch", "paper", "multistart", "exact"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    x = np.arange(len(names))
    for j, m in enumerate(meths):
        sel = [next(r for r in rows if r["setting"] == n and r["method"] == m) for n in names]
        axes[0].bar(x + (j - 2) * 0.16, [r["cpu_ms"] for r in sel], 0.16, label=m)
        axes[1].bar(x + (j - 2) * 0.16, [r["eff_min"] for r in sel], 0.16, label=m)
    axes[0].set_yscale("log")
    axes[0].set_ylabel("median CPU time per fit (ms)")
    axes[1].axhline(0.95, color="k", lw=0.8, ls="--")
    axes[1].set_ylabel("min efficiency over parameters")
    for ax in axes:
        ax.set_xticks(x, names, rotation=45, ha="right")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--full", action="store_true", help="T = T_ms = 1000 trials")
    p.add_argument("--trials", type=int, default=None, help="trials for fast/batch (500)")
    p.add_argument("--ms-trials", type=int, default=None,
                   help="trials of the paper's method and of multistart (60)")
    p.add_argument("--pilot", type=int, default=40,
                   help="pilot data vectors per setting for the paper's M99 (40 starts each)")
    p.add_argument("--batch-reps", type=int, default=3,
                   help="timed whole-batch calls (batch, exact) per setting, spread between "
                        "the blocks of single fits")
    p.add_argument("--seed", type=int, default=2024)
    p.add_argument("--block", type=int, default=10,
                   help="single fits alternate between the methods in blocks of this many "
                        "data vectors (1: every fit, cold caches)")
    p.add_argument("--eff-trials", type=int, default=0,
                   help="extra batch-only efficiency pass with this many trials (0: none)")
    p.add_argument("--scenes", type=int, default=0,
                   help="extra pass over this many random well-separated scenes per K = 2, 3, 4")
    p.add_argument("--out", type=Path, default=Path("out/ml_speed_accuracy"))
    a = p.parse_args(argv)
    n = a.trials or (1000 if a.full else 500)
    n_ms = min(n, a.ms_trials or (1000 if a.full else 60))
    a.out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(a.seed)
    rows = []
    for name, sigma, scene in settings():
        rows += run_setting(name, sigma, scene, n, n_ms, rng, a.block, a.pilot, a.batch_reps)
        print(f"done {name}", flush=True)
    print_table(rows)
    print_targets(rows)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]))
    w.writeheader()
    w.writerows(rows)
    write_text_atomic(a.out / "table.csv", buf.getvalue())
    plot(rows, a.out / "ml_speed_accuracy.png")
    print(f"\nwrote {a.out / 'table.csv'} and {a.out / 'ml_speed_accuracy.png'}")
    if a.eff_trials:
        efficiency_only(settings(), a.eff_trials, a.seed + 1)
    if a.scenes:
        print("\nrandom scenes (ring 30, separation >= 30 deg, I ~ U(0.5, 1)):")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", (ob.ConvergenceWarning, ob.MultimodalWarning))
            warnings.simplefilter("ignore", ob.KinkWarning)
            for sigma in (1e-2, 1e-3):
                for k in (2, 3, 4):
                    print(scene_study(k, sigma, a.scenes, 20 if a.full else 10,
                                      10 if a.full else 4, 1000 if a.full else 300,
                                      a.seed + k), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
