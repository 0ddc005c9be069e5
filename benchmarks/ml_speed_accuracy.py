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
call on all T data vectors, time divided by T), ``multistart`` (the paper's
baseline: 20 pseudo-random starts + L-BFGS-B, on the first T_ms data vectors)
and ``exact`` (``fit_ml(method="exact")``, one batched call: the global
optimum, by enumerating the ring's linear cells).  The exact row is the
reference for the global-optimum share, and its efficiency is that of the ML
estimator itself: where it is below 1 (K = 4 at sigma = 1e-2, where another
cell's optimum beats the one near the truth in ~13 % of draws), no search can do
better.  The single fits of ``fast`` and ``multistart`` alternate in blocks of
``--block`` data vectors (10), so both see the same machine load with warm
caches, as in a user's loop of fits; ``--block 1`` alternates every fit (each
fast fit then starts with the caches a multistart fit left, ~2x its warm time).

A fifth row per setting, ``oracle``, is an LM run started at the truth: a local
ML that cannot jump to another cell's optimum, untimed (it is not an estimator).
Where the exact ML's efficiency falls short of the oracle's, the ML estimator
itself jumps between optima, whatever finds them.

Per method and setting: efficiency per parameter (CRLB variance / mean squared
error), failure rate (some parameter off by more than 5 CRLB std), the share of
fits reaching the best optimum any method (the exact one, or the oracle) found
-- to within 1e-6 and 1e-3 in log-likelihood -- and the median time per fit, as
CPU time of this process (``time.process_time``) and wall-clock time.  Then the
speed ratios, and the ML estimator's targets judged on this run.  CPU time is the primary
measure: the machine is shared, and wall-clock times include waiting for a core,
which depends on other processes' load.  Run ``python
benchmarks/ml_speed_accuracy.py`` (quick, a few minutes) or ``--full`` (T = T_ms
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

import olsbayes as ob  # noqa: E402
from olsbayes._io import write_text_atomic  # noqa: E402
from olsbayes.exchange import estimation_errors  # noqa: E402
from olsbayes.ml import MultistartOptions, fit_ml  # noqa: E402
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


def _timed_pair(fast, multi, data: np.ndarray, n_ms: int, block: int = 10):
    """Single fits, fast and multistart alternating in blocks of ``block`` data vectors.

    Alternating makes the two medians see the same machine load (the box is
    shared), so their ratio is fair even when absolute times drift; blocks keep
    each method's code and data in cache as in a user's loop of fits
    (``block=1`` alternates every fit: each short fast fit then starts cold after
    a multistart fit, which costs it ~2x).  Returns per method (params,
    log-likelihoods, median CPU s per fit, median wall s per fit, forward-model
    evaluations per fit).
    """
    res = {"fast": [], "multistart": []}
    cpu = {"fast": [], "multistart": []}
    wall = {"fast": [], "multistart": []}
    for lo in range(0, data.shape[0], block):
        for name, fn in (("fast", fast), ("multistart", multi)):
            for s in data[lo : min(lo + block, n_ms if name == "multistart" else data.shape[0])]:
                c0, t0 = time.process_time(), time.perf_counter()
                res[name].append(fn(s))
                wall[name].append(time.perf_counter() - t0)
                cpu[name].append(time.process_time() - c0)
    return {
        name: (np.array([r.params for r in res[name]]),
               np.array([float(r.log_likelihood) for r in res[name]]),
               float(np.median(cpu[name])), float(np.median(wall[name])),
               np.array([r.n_evaluations for r in res[name]]))
        for name in res
    }


#: Rows per setting: the estimators, then the LM run started at the truth (an oracle,
#: not an estimator: a local ML that cannot jump to another cell's optimum).
METHODS = ("fast", "batch", "multistart", "exact", "oracle")


def run_setting(name, sigma, scene, n_trials, n_ms, rng, block=10):
    model = ob.Model(ob.Ring(30), sigma)
    k = scene.n_sources
    truth = model.canonical(model.pack(scene))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ob.KinkWarning)
        std = ob.crlb(model, scene.sorted()).std
    data = model.simulate(scene, rng=rng, size=n_trials)
    fit_ml(model, data[:2], k)  # warm the tuple-search plan cache for every method alike
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", (ob.ConvergenceWarning, ob.MultimodalWarning))
        ms_rng = np.random.default_rng(rng.integers(2**63))
        out.update(_timed_pair(
            lambda s: fit_ml(model, s, k),
            lambda s: fit_ml(model, s, k, method="multistart", rng=ms_rng), data, n_ms,
            block))
        c0, t0 = time.process_time(), time.perf_counter()
        b = fit_ml(model, data, k)
        out["batch"] = (b.params, b.log_likelihood, (time.process_time() - c0) / n_trials,
                        (time.perf_counter() - t0) / n_trials, b.n_evaluations)
        c0, t0 = time.process_time(), time.perf_counter()
        e = fit_ml(model, data, k, method="exact")
        out["exact"] = (e.params, e.log_likelihood, (time.process_time() - c0) / n_trials,
                        (time.perf_counter() - t0) / n_trials, e.n_evaluations)
        ident = identifiability(model, scene, std)
    ref = refine_batch(model, data, np.repeat(truth[None], n_trials, axis=0))
    out["oracle"] = (model.canonical(ref.x), model.log_likelihood(ref.x, data), np.nan, np.nan,
                     ref.n_evaluations)
    best = np.max([out[m][1] for m in ("oracle", "fast", "batch", "exact")], axis=0)
    best[:n_ms] = np.maximum(best[:n_ms], out["multistart"][1])
    rows = []
    for meth in METHODS:
        params, ll, tcpu, twall, nev = out[meth]
        t = params.shape[0]
        err = estimation_errors(model, params, truth)
        eff = std**2 / np.mean(err**2, axis=0)
        fail = np.mean(np.any(np.abs(err) > 5 * std, axis=1))
        gap = best[:t] - ll
        rows.append(dict(setting=name, k=k, sigma=sigma, method=meth, trials=t,
                         eff_min=float(eff.min()), eff=" ".join(f"{e:.3f}" for e in eff),
                         fail=float(fail), glob6=float(np.mean(gap <= 1e-6)),
                         glob3=float(np.mean(gap <= 1e-3)), cpu_ms=1e3 * tcpu,
                         wall_ms=1e3 * twall, evals=float(np.median(nev)), ident=ident))
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
          "(responses + Jacobians) per fit, over all starts/candidates; oracle = LM "
          "started at the truth (not an estimator, untimed)")
    print("\nidentifiability (noiseless data):")
    for setting in dict.fromkeys(r["setting"] for r in rows):
        print(f"  {setting:14s} " + next(r["ident"] for r in rows if r["setting"] == setting))
    print("\nspeed ratios (multistart time per fit / method time per fit), CPU [wall]:")
    for setting in dict.fromkeys(r["setting"] for r in rows):
        c = {r["method"]: r["cpu_ms"] for r in rows if r["setting"] == setting}
        w = {r["method"]: r["wall_ms"] for r in rows if r["setting"] == setting}
        print(f"  {setting:14s} fast {c['multistart'] / c['fast']:7.1f}x "
              f"[{w['multistart'] / w['fast']:7.1f}x]   batch "
              f"{c['multistart'] / c['batch']:8.1f}x [{w['multistart'] / w['batch']:8.1f}x]   "
              f"exact {c['multistart'] / c['exact']:6.1f}x")


def _verdict(ok: bool) -> str:
    return "met    " if ok else "NOT met"


def print_targets(rows: list[dict]) -> None:
    """The ML estimator's targets, judged on this run's rows (speed ratios in CPU time).

    Efficiency counts as met at >= 0.95 - 2 sd (sd = sqrt(2 / T), the sampling sd
    of a variance ratio); a miss is shown next to the exact ML's and the oracle's
    efficiency, which tell an estimator's shortfall from the ML estimator's own.
    """
    by = {(r["setting"], r["method"]): r for r in rows}
    print("\ntargets (this run):")
    for setting in dict.fromkeys(r["setting"] for r in rows):
        fast, batch, ms, exact, orc = (by[setting, m] for m in METHODS)
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
            ratio = ms["cpu_ms"] / fast["cpu_ms"]
            ok = ratio >= need and fast["glob6"] >= ms["glob6"]
            parts.append(f"fast >= {need}x at equal success: {_verdict(ok)} {ratio:.0f}x")
        ratio = ms["cpu_ms"] / batch["cpu_ms"]
        parts.append(f"batch >= 500x: {_verdict(ratio >= 500)} {ratio:.0f}x")
        print(f"  {setting:14s} " + "; ".join(parts))


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r["setting"] for r in rows))
    meths = ["fast", "batch", "multistart", "exact"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    x = np.arange(len(names))
    for j, m in enumerate(meths):
        sel = [next(r for r in rows if r["setting"] == n and r["method"] == m) for n in names]
        axes[0].bar(x + (j - 1.5) * 0.2, [r["cpu_ms"] for r in sel], 0.2, label=m)
        axes[1].bar(x + (j - 1.5) * 0.2, [r["eff_min"] for r in sel], 0.2, label=m)
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


def efficiency_only(n_trials: int, seed: int) -> None:
    """Batched fast fits only, many trials: efficiency with sampling sd sqrt(2/T)."""
    rng = np.random.default_rng(seed)
    print(f"\nbatch-only efficiency, T = {n_trials} (sampling sd {np.sqrt(2 / n_trials):.3f}):")
    for name, sigma, scene in settings():
        model = ob.Model(ob.Ring(30), sigma)
        truth = model.canonical(model.pack(scene))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ob.KinkWarning)
            std = ob.crlb(model, scene.sorted()).std
        data = model.simulate(scene, rng=rng, size=n_trials)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", (ob.ConvergenceWarning, ob.MultimodalWarning))
            res = fit_ml(model, data, scene.n_sources)
        err = estimation_errors(model, res.params, truth)
        eff = std**2 / np.mean(err**2, axis=0)
        fail = np.mean(np.any(np.abs(err) > 5 * std, axis=1))
        print(f"  {name:14s} eff {' '.join(f'{e:.3f}' for e in eff):48s} fail {fail:.4f}")


def random_scenes(model: ob.Model, k: int, n: int, rng: np.random.Generator,
                  min_sep_deg: float = 30.0) -> list[ob.Scene]:
    """``n`` identifiable scenes of K sources: angles uniform with neighbours at least
    ``min_sep_deg`` apart, I ~ U(0.5, 1); scenes with a singular Fisher matrix
    (e.g. a source pair on one kink configuration) are drawn again."""
    out = []
    while len(out) < n:
        a = np.sort(rng.uniform(-np.pi, np.pi, k))
        if np.diff(np.r_[a, a[0] + 2 * np.pi]).min() < np.radians(min_sep_deg):
            continue
        scene = ob.Scene(directions=a, intensities=rng.uniform(0.5, 1.0, k))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ob.ResolutionWarning)
            if np.all(np.isfinite(ob.crlb(model, scene.sorted()).std)):
                out.append(scene)
    return out


def _deciles(v: list[float]) -> str:
    return " ".join(f"{x:.3f}" for x in np.quantile(v, (0.1, 0.25, 0.5, 0.75, 0.9)))


def scene_study(k: int, sigma: float, n_scenes: int, n_trials: int, n_ms: int, n_eff: int,
                seed: int) -> str:
    """Random well-separated scenes: search reliability and per-scene efficiency.

    Per scene: ``n_trials`` fast fits and ``n_ms`` multistart fits (20 starts) of
    the same data; "reached" = within 1e-6 of the best log-likelihood any method
    or an LM run from the truth found.  Then ``n_eff`` batched fast fits per scene
    give its efficiency (min over parameters), next to that of the LM run from the
    truth -- a local ML that cannot jump to a rival mode (an oracle, not an
    estimator): the gap between the two is the ML estimator's own mode jumps.
    """
    rng = np.random.default_rng(seed)
    model = ob.Model(ob.Ring(30), sigma)
    reach_f, reach_m, t_f, t_m, eff_f, eff_o = [], [], 0.0, 0.0, [], []
    ms_rng = np.random.default_rng(rng.integers(2**63))
    scenes = random_scenes(model, k, n_scenes, rng)
    warm = model.simulate(scenes[0], rng=rng, size=2)  # plans and compiled code, for both alike
    fit_ml(model, warm, k)
    fit_ml(model, warm[0], k, method="multistart", rng=0)
    for scene in scenes:
        truth = model.canonical(model.pack(scene))
        data = model.simulate(scene, rng=rng, size=max(n_trials, n_eff))
        ref = refine_batch(model, data, np.repeat(truth[None], data.shape[0], axis=0))
        c0 = time.process_time()
        fast = fit_ml(model, data[:n_trials], k)
        t_f += time.process_time() - c0
        c0 = time.process_time()
        ms = np.array([fit_ml(model, s, k, method="multistart", rng=ms_rng).log_likelihood
                       for s in data[:n_ms]])
        t_m += time.process_time() - c0
        best = np.maximum(model.log_likelihood(ref.x[:n_trials], data[:n_trials]),
                          fast.log_likelihood)
        best[:n_ms] = np.maximum(best[:n_ms], ms)
        reach_f.append(best - fast.log_likelihood <= 1e-6)
        reach_m.append(best[:n_ms] - ms <= 1e-6)
        if n_eff:
            std = ob.crlb(model, scene.sorted()).std
            for x, acc in ((fit_ml(model, data[:n_eff], k).params, eff_f), (ref.x[:n_eff], eff_o)):
                err = estimation_errors(model, x, truth)
                acc.append(float(np.min(std**2 / np.mean(err**2, axis=0))))
    rf, rm = np.concatenate(reach_f), np.concatenate(reach_m)
    line = (f"  K={k} s={sigma:g}  {n_scenes} scenes: optimum reached fast {rf.mean():.4f} "
            f"({rf.size} fits, {1e3 * t_f / rf.size:.3f} ms/fit in batches of {n_trials}), "
            f"multistart-20 {rm.mean():.4f} "
            f"({rm.size} fits, {1e3 * t_m / max(rm.size, 1):.2f} ms/fit)")
    if n_eff:
        ok = 0.95 - 2 * np.sqrt(2 / n_eff)
        line += (f"\n        min efficiency over scenes (quantiles 10/25/50/75/90 %, T={n_eff}): "
                 f"fast {_deciles(eff_f)} | LM from truth {_deciles(eff_o)}; "
                 f"scenes >= 0.95 - 2 sd: "
                 f"fast {np.mean(np.array(eff_f) >= ok):.2f}, LM from truth "
                 f"{np.mean(np.array(eff_o) >= ok):.2f}")
    return line


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--full", action="store_true", help="T = T_ms = 1000 trials")
    p.add_argument("--trials", type=int, default=None, help="trials for fast/batch (500)")
    p.add_argument("--ms-trials", type=int, default=None, help="multistart trials (60)")
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
        rows += run_setting(name, sigma, scene, n, n_ms, rng, a.block)
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
        efficiency_only(a.eff_trials, a.seed + 1)
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
