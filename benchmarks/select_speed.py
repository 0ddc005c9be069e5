"""Cost and agreement of the K-selection estimators, side by side in one run.

Ring N = 30, sigma = 0.01, intensities U(0, 2) prior (i_max = 2), K_max = 4.

1. Laplace selection (``select_k(method="laplace")``) on well-separated scenes with
   K = 0..4: median wall time per selection (target <= 50 ms), split into the ML
   fits (the ML engineer's ``fit_ml`` for K = 1..4 plus the cross-K repair) and
   the evidence work proper (Fisher, Laplace, diagnostics).
2. Nested sampling (dynesty rslice, maxcall-capped) vs Laplace for every K of a
   well-separated two-source scene: log Z +- err, |difference| (target <= 0.3
   nats where trusted) and the cost ratio (target Laplace >= 1000x cheaper).
3. Known failure cases of Laplace (K_max = 2) -- a pair closer than a sensor spacing
   (singular Fisher), a pair at 1.5 spacings, a weak second source, and a K=1
   scene with too many sources fitted -- and what ``auto`` escalates, with its
   cost next to nested sampling of all K.

Usage::

    python benchmarks/select_speed.py            # quick (a few minutes)
    python benchmarks/select_speed.py --full     # more repeats
    python benchmarks/select_speed.py --out out/select_speed
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np

from olsbayes import Model, Ring
from olsbayes.priors import default_priors
from olsbayes.select import select_k
from olsbayes.select.engine import laplace_work, noise_work
from olsbayes.select.fits import fit_all
from olsbayes.select.importance import importance_log_evidence

H = 2 * np.pi / 30
SCENES = {
    0: [],
    1: [(0.4, 1.0)],
    2: [(-0.6, 1.0), (1.5, 0.6)],
    3: [(-2.2, 0.8), (-0.5, 1.0), (1.3, 0.6)],
    4: [(-1.5, 1.0), (-0.3, 0.6), (0.9, 0.8), (2.1, 0.7)],
}
HARD = {
    "pair 0.5 h (singular)": [(0.2, 1.0), (0.2 + 0.5 * H, 1.0)],
    "pair 1.5 h": [(0.2, 1.0), (0.2 + 1.5 * H, 1.0)],
    "weak 2nd source I=0.02": [(0.2, 1.0), (2.0, 0.02)],
    "K=1 truth": [(0.4, 1.0)],
}


def laplace_timing(model, reps: int) -> list[dict]:
    """Whole Laplace selections, and their two parts timed separately on the same data."""
    prior = {k: default_priors(model, k, i_max=2.0) for k in range(5)}
    rows = []
    for k, scene in SCENES.items():
        x = np.array(scene, float).ravel()
        tot, fits, evid, right = [], [], [], 0
        for r in range(reps):
            d = model.simulate(x, np.random.default_rng([k, r]))
            t0 = time.perf_counter()
            res = select_k(model, d, k_max=4, method="laplace", rng=r, i_max=2.0)
            tot.append(time.perf_counter() - t0)
            right += res.best == k
            streams = [g.spawn(2)[0] for g in np.random.default_rng(r).spawn(5)]
            t0 = time.perf_counter()
            fitted = fit_all(model, d, 4, streams)
            fits.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            noise_work(model, d)
            for j in range(1, 5):
                laplace_work(model, j, fitted[j], prior[j], None)
            evid.append(time.perf_counter() - t0)
        rows.append({"k": k, "total_ms": 1e3 * np.median(tot), "fits_ms": 1e3 * np.median(fits),
                     "evidence_ms": 1e3 * np.median(evid), "correct": f"{right}/{reps}"})
    return rows


def nested_vs_laplace(model, seed: int, maxcall: int, nlive: int | None) -> list[dict]:
    x = np.array(SCENES[2], float).ravel()
    d = model.simulate(x, np.random.default_rng([2, 0]))
    t0 = time.perf_counter()
    lap = select_k(model, d, k_max=4, method="laplace", rng=seed, i_max=2.0)
    t_lap = time.perf_counter() - t0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        nes = select_k(model, d, k_max=4, method="nested", rng=seed, i_max=2.0, maxcall=maxcall,
                       nlive=nlive, dlogz=0.1)
        t_nes = time.perf_counter() - t0
    rows = []
    for a, b in zip(lap.evidences, nes.evidences):
        is_z, is_se = np.nan, np.nan
        if a.k and a.trusted:  # one-mode importance sampling: a precise reference
            prior = default_priors(model, a.k, i_max=2.0)
            is_z, is_se = importance_log_evidence(model, d, a.params,
                                                  np.linalg.inv(model.fisher(a.params)), prior,
                                                  n_draws=50_000, rng=seed)
        rows.append({"k": a.k, "laplace": a.log_evidence, "nested": b.log_evidence,
                     "err": b.error, "diff": b.log_evidence - a.log_evidence,
                     "is": is_z, "is_se": is_se,
                     "trusted": a.trusted, "calls": b.n_calls, "nested_s": b.seconds})
    rows.append({"k": "all", "laplace_s": t_lap, "nested_s": t_nes, "ratio": t_nes / t_lap,
                 "p_laplace": lap.probabilities.tolist(), "p_nested": nes.probabilities.tolist()})
    return rows


def hard_cases(model, seed: int, maxcall: int) -> list[dict]:
    rows = []
    for name, scene in HARD.items():
        x = np.array(scene, float).ravel()
        d = model.simulate(x, np.random.default_rng(11))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            auto = select_k(model, d, k_max=2, method="auto", rng=seed, i_max=2.0,
                            maxcall=maxcall)
            t_auto = time.perf_counter() - t0
            t0 = time.perf_counter()
            nes = select_k(model, d, k_max=2, method="nested", rng=seed, i_max=2.0,
                           maxcall=maxcall)
            t_nes = time.perf_counter() - t0
        rows.append({"case": name, "auto_best": auto.best, "nested_best": nes.best,
                     "escalated": dict(auto.escalated), "auto_s": t_auto, "nested_s": t_nes,
                     "p_auto": auto.probabilities.round(3).tolist(),
                     "p_nested": nes.probabilities.round(3).tolist()})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--full", action="store_true", help="more repeats")
    ap.add_argument("--out", type=Path, default=Path("out/select_speed"))
    ap.add_argument("--parts", default="123", help="which parts to run, e.g. 2")
    ap.add_argument("--nlive", type=int, default=None,
                    help="dynesty live points in part 2 (default max(100, 25 P))")
    ap.add_argument("--maxcall", type=int, default=150_000,
                    help="likelihood-call cap per nested run (over-complete K often hit it)")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    model = Model(Ring(30), 0.01)
    reps = 20 if args.full else 5
    lines = []

    def say(s=""):
        print(s, flush=True)
        lines.append(s)

    lap, nvl = [], []
    if "1" in args.parts:
        lap = part1(model, reps, say)
    if "2" in args.parts:
        nvl = part2(model, args, say)
    if "3" in args.parts:
        part3(model, args, say)
    (args.out / "select_speed.txt").write_text("\n".join(lines) + "\n")
    (args.out / "select_speed.json").write_text(json.dumps(
        {"laplace": lap, "nested_vs_laplace": nvl}, default=float, indent=1))
    return 0


def part1(model, reps, say) -> list[dict]:
    say("1. Laplace selection, K_max = 4, N = 30 (median ms per selection; target <= 50 ms)")
    lap = laplace_timing(model, reps)
    say(f"{'true K':>6} {'total':>8} {'ML fits':>8} {'evidence':>9} {'correct':>8}")
    say("(ML fits: fit_ml for K=1..4 + cross-K repair; evidence: K=0 closed form, Fisher,"
        " Laplace, trust diagnostics for K=1..4)")
    for r in lap:
        say(f"{r['k']:>6} {r['total_ms']:8.1f} {r['fits_ms']:8.1f} {r['evidence_ms']:9.1f} "
            f"{r['correct']:>8}")
    say()
    return lap


def part2(model, args, say) -> list[dict]:
    say(f"2. Nested (dynesty rslice, nlive={args.nlive or 'default'}, dlogz=0.1, "
        f"maxcall={args.maxcall}) vs Laplace, well-separated K=2 scene")
    nvl = nested_vs_laplace(model, 0, args.maxcall, args.nlive)
    say(f"{'K':>2} {'Laplace':>12} {'nested':>12} {'+-':>6} {'diff':>7} {'IS - Lapl.':>11} "
        f"{'+-':>6} {'trusted':>7} {'calls':>7} {'s':>6}")
    for r in nvl[:-1]:
        say(f"{r['k']:>2} {r['laplace']:12.3f} {r['nested']:12.3f} {r['err']:6.2f} "
            f"{r['diff']:7.2f} {r['is'] - r['laplace']:11.4f} {r['is_se']:6.4f} "
            f"{r['trusted']!s:>7} {r['calls']:7d} {r['nested_s']:6.1f}")
    say("(IS: Student-t importance sampling around the ML mode, 50000 draws, x K! -- the "
        "precise reference for the Laplace value where the modes are apart)")
    tot = nvl[-1]
    say(f"whole selection: Laplace {tot['laplace_s'] * 1e3:.1f} ms, nested {tot['nested_s']:.1f} s,"
        f" ratio {tot['ratio']:.0f}x (target >= 1000x)")
    say(f"p(K) Laplace {np.round(tot['p_laplace'], 3)}  nested {np.round(tot['p_nested'], 3)}")
    say()
    return nvl


def part3(model, args, say) -> None:
    say("3. Hard cases (K_max = 2): what auto escalates, and its cost vs nested for all K")
    for r in hard_cases(model, 0, args.maxcall):
        ratio = r["nested_s"] / r["auto_s"]
        say(f"- {r['case']}: auto K={r['auto_best']} in {r['auto_s']:.1f} s, nested K="
            f"{r['nested_best']} in {r['nested_s']:.1f} s (ratio {ratio:.1f}x)")
        say(f"    p auto {r['p_auto']}  p nested {r['p_nested']}")
        for k, why in r["escalated"].items():
            say(f"    escalated K={k}: {why}")


if __name__ == "__main__":
    raise SystemExit(main())
