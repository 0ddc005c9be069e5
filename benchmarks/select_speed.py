"""Cost and agreement of the K-selection estimators, side by side in one run.

Ring N = 30, sigma = 0.01, intensities U(0, 2) prior (i_max = 2), K_max = 4.

1. Laplace selection (``select_k(method="laplace")``) on well-separated scenes with
   K = 0..4: median wall time per selection (target <= 50 ms), split into the ML
   fits (``fit_ml`` for K = 1..4 plus the cross-K repair) and
   the evidence work proper (Fisher, Laplace, diagnostics).
2. Nested sampling (dynesty rslice, maxcall-capped) vs Laplace for every K of a
   well-separated two-source scene: log Z +- err, |difference| (target <= 0.3
   nats where trusted) and the cost ratio (target Laplace >= 1000x cheaper).
4. The resolution-limit sweep (``analyses/resolution_limit.py``'s scenes: two equal
   sources at a random rotation, 0.25 to 5 sensor spacings apart, sigma 1e-2, 1e-3,
   1e-4, K_max = 2, i_max = 2) with the default method: CPU time per call and the
   chosen K with the escalated K <= 2 computed by quadrature (the default) and by
   nested sampling (``DecisionOptions(quadrature=False)``), the two calls alternating
   on the same data (target <= 2 s CPU per call, the evidences unchanged: the same
   K, or log Z_2 - log Z_1 within two combined stated errors where a scene near the
   decision boundary tips with the nested runs' noise; Laplace values count with
   error 0).
3. Known failure cases of Laplace -- a pair closer than a sensor spacing
   (singular Fisher), a pair at 1.5 spacings, a weak second source, and a K=1
   scene with too many sources fitted (K_max = 2), and four K_max = 4 scenes --
   and what ``auto`` escalates (or why not), with its cost next to nested
   sampling of the escalated K alone and of all K.

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
from olsbayes.select import DecisionOptions, NestedOptions, SelectOptions, select_k
from olsbayes.select.engine import laplace_work, mixture_work, noise_work
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
#: (K_max, scene) of the cases where Laplace is known to fail or to be at risk.
HARD = {
    "pair 0.5 h (singular)": (2, [(0.2, 1.0), (0.2 + 0.5 * H, 1.0)]),
    "pair 1.5 h": (2, [(0.2, 1.0), (0.2 + 1.5 * H, 1.0)]),
    "weak 2nd source I=0.02": (2, [(0.2, 1.0), (2.0, 0.02)]),
    "K=1 truth": (2, [(0.4, 1.0)]),
    "K=2 well separated": (4, SCENES[2]),
    "K=3, pair 1.5 h": (4, [(-2.2, 0.8), (0.2, 1.0), (0.2 + 1.5 * H, 1.0)]),
    "K=3, pair 0.5 h": (4, [(-2.2, 0.8), (0.2, 1.0), (0.2 + 0.5 * H, 1.0)]),
    "K=2, weak 2nd I=0.02": (4, [(0.2, 1.0), (2.0, 0.02)]),
}


def laplace_timing(model, reps: int) -> list[dict]:
    """Whole Laplace selections, and their two parts timed separately on the same data."""
    prior = {k: default_priors(model, k, i_max=2.0) for k in range(5)}
    rows = []
    for k, scene in SCENES.items():
        x = np.array(scene, float).ravel()
        tot, cpu, fits, evid, right = [], [], [], [], 0
        for r in range(reps):
            d = model.simulate(x, rng=np.random.default_rng([k, r]))
            t0, c0 = time.perf_counter(), time.process_time()
            res = select_k(model, d, k_max=4, method="laplace", rng=r, i_max=2.0)
            tot.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            right += res.best == k
            streams = [g.spawn(2)[0] for g in np.random.default_rng(r).spawn(5)]
            t0 = time.perf_counter()
            fitted = fit_all(model, d, 4, rngs=streams)
            fits.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            noise_work(model, d)
            for j in range(1, 5):  # as select_k: importance sampling where Laplace fails
                w = laplace_work(model, j, fitted[j], prior[j], None)
                if w.reasons or not np.isfinite(w.value):
                    lower = [fitted[i][1] for i in (j - 1, j - 2, j - 3) if i >= 1]
                    mixture_work(model, d, w, prior[j], lower, 500,
                                 rng=np.random.default_rng([r, j]))
            evid.append(time.perf_counter() - t0)
        rows.append({"k": k, "total_ms": 1e3 * np.median(tot), "cpu_ms": 1e3 * np.median(cpu),
                     "fits_ms": 1e3 * np.median(fits),
                     "evidence_ms": 1e3 * np.median(evid), "correct": f"{right}/{reps}"})
    return rows


def nested_vs_laplace(model, seed: int, maxcall: int, n_live: int | None) -> list[dict]:
    x = np.array(SCENES[2], float).ravel()
    d = model.simulate(x, rng=np.random.default_rng([2, 0]))
    t0 = time.perf_counter()
    lap = select_k(model, d, k_max=4, method="laplace", rng=seed, i_max=2.0)
    t_lap = time.perf_counter() - t0
    # the evidence step alone (ML fits excluded): Laplace at the same ML points
    fitted = fit_all(model, d, 4,
                     rngs=[g.spawn(2)[0] for g in np.random.default_rng(seed).spawn(5)])
    t_ev = []
    for k in range(1, 5):
        prior = default_priors(model, k, i_max=2.0)
        reps = []
        for _ in range(11):
            t0 = time.perf_counter()
            laplace_work(model, k, fitted[k], prior, None)
            reps.append(time.perf_counter() - t0)
        t_ev.append(float(np.median(reps)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        nested = NestedOptions(maxcall=maxcall, n_live=n_live, dlogz=0.1)
        nes = select_k(model, d, k_max=4, method="nested", rng=seed, i_max=2.0,
                       options=SelectOptions(nested=nested))
        t_nes = time.perf_counter() - t0
    rows = []
    for a, b in zip(lap.evidences, nes.evidences):
        is_z, is_se = np.nan, np.nan
        if a.k and a.trusted:  # one-mode importance sampling: a precise reference
            prior = default_priors(model, a.k, i_max=2.0)
            is_z, is_se = importance_log_evidence(model, d, a.params,
                                                  np.linalg.inv(model.fisher(a.params)), prior,
                                                  n_draws=50_000, rng=seed)
        # nested run alone: minus the (equal) ML-fit share and Laplace work both records hold
        nested_s = b.seconds - a.seconds if a.k else 0.0
        rows.append({"k": a.k, "laplace": a.log_evidence, "nested": b.log_evidence,
                     "err": b.error, "diff": b.log_evidence - a.log_evidence,
                     "is": is_z, "is_se": is_se,
                     "trusted": a.trusted, "calls": b.n_calls, "nested_s": nested_s,
                     "laplace_ev_s": t_ev[a.k - 1] if a.k else 0.0})
    rows.append({"k": "all", "laplace_s": t_lap, "nested_s": t_nes, "ratio": t_nes / t_lap,
                 "p_laplace": lap.probabilities.tolist(), "p_nested": nes.probabilities.tolist()})
    return rows


def hard_cases(model, seed: int, maxcall: int) -> list[dict]:
    rows = []
    for name, (k_max, scene) in HARD.items():
        x = np.array(scene, float).ravel()
        d = model.simulate(x, rng=np.random.default_rng(11))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            opts = SelectOptions(nested=NestedOptions(maxcall=maxcall))
            auto = select_k(model, d, k_max=k_max, method="auto", rng=seed, i_max=2.0,
                            options=opts)
            t_auto = time.perf_counter() - t0
            t0 = time.perf_counter()
            nes = select_k(model, d, k_max=k_max, method="nested", rng=seed, i_max=2.0,
                           options=opts)
            t_nes = time.perf_counter() - t0
        # nested sampling of just the K auto escalated (same seeds: the same runs); likelihood
        # calls are the load-independent cost (ML-fit evaluations + nested-sampling calls)
        doubt_s = sum(nes[k].seconds for k in auto.escalated)
        doubt_calls = sum(nes[k].n_calls for k in auto.escalated)
        rows.append({"case": name, "k_max": k_max, "auto_best": auto.best,
                     "nested_best": nes.best, "escalated": dict(auto.escalated),
                     "notes": list(auto.notes), "auto_s": t_auto, "nested_s": t_nes,
                     "doubt_nested_s": doubt_s, "doubt_calls": doubt_calls,
                     "auto_calls": sum(ev.n_calls for ev in auto.evidences),
                     "nested_calls": sum(ev.n_calls for ev in nes.evidences),
                     "capped": [ev.k for ev in nes.evidences
                                if any("stopped at maxcall" in r for r in ev.reasons)],
                     "p_auto": auto.probabilities.round(3).tolist(),
                     "p_nested": nes.probabilities.round(3).tolist()})
    return rows


#: Separations (sensor spacings) and noise levels of the resolution-limit sweep.
SWEEP_SEPS = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 4.0, 5.0)
SWEEP_SIGMAS = (1e-2, 1e-3, 1e-4)


def _timed_select(model, d, seed, quadrature: bool):
    """One default select_k call (K_max = 2, i_max = 2): CPU s, the result."""
    opts = SelectOptions(decision=DecisionOptions(quadrature=quadrature))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c0 = time.process_time()
        res = select_k(model, d, k_max=2, rng=seed, i_max=2.0, options=opts, progress=False)
        return time.process_time() - c0, res


def _escalated(res) -> str:
    """The escalated K with their method and log Z +- error."""
    return ", ".join(f"K={k} {res[k].method} {res[k].log_evidence:.3f}+-{res[k].error:.3f}"
                     for k in sorted(res.escalated)) or "-"


def _odds(res) -> tuple[float, float]:
    """log Z_2 - log Z_1 and its standard error (the methods' stated errors combined)."""
    err = np.nan_to_num(res.error[1:3], nan=0.0)
    return float(res.log_evidence[2] - res.log_evidence[1]), float(np.hypot(*err))


def _explained(r: dict) -> bool:
    """A different K whose two log odds agree within 2 combined errors (the nested noise)."""
    (a, ea), (b, eb) = r["odds_before"], r["odds_after"]
    return abs(a - b) < 2 * np.hypot(ea, eb)


def sweep(trials: int, seed: int, say) -> list[dict]:
    """Every scene of the sweep, the rule with and without quadrature, on the same data and seed.

    The two calls alternate (A/B per scene) so that both see the same machine load.
    """
    rows = []
    for sigma in SWEEP_SIGMAS:
        model = Model(Ring(30), sigma)
        rng = np.random.default_rng([seed, int(round(-np.log10(sigma)))])
        for sep in SWEEP_SEPS:
            for t in range(trials):
                th = rng.uniform(-np.pi, np.pi)
                d = model.simulate(model.canonical(np.array([th, 1.0, th + sep * H, 1.0])),
                                   rng=rng)
                s = int(rng.integers(2**31))
                order = (True, False) if (len(rows) % 2) else (False, True)
                out = {q: _timed_select(model, d, s, q) for q in order}
                (c_after, after), (c_before, before) = out[True], out[False]
                r = {"sigma": sigma, "sep": sep, "trial": t, "cpu_before": c_before,
                     "cpu_after": c_after, "k_before": before.best, "k_after": after.best,
                     "odds_before": _odds(before), "odds_after": _odds(after),
                     "esc_before": _escalated(before), "esc_after": _escalated(after),
                     "p2_before": float(before.probabilities[2]),
                     "p2_after": float(after.probabilities[2])}
                rows.append(r)
                say(f"  sigma={sigma:g} sep={sep:4.2f}h #{t}: CPU {c_before:6.2f} -> "
                    f"{c_after:6.2f} s, K {before.best} -> {after.best}, p(K=2) "
                    f"{r['p2_before']:.3f} -> {r['p2_after']:.3f}; escalated: "
                    f"{r['esc_before']} -> {r['esc_after']}")
    return rows


def part4(args, say) -> list[dict]:
    say(f"4. resolution-limit sweep, default method, K_max = 2: per scene CPU s and chosen K, "
        f"quadrature off -> on ({args.sweep_trials} scenes per separation and sigma)")
    rows = sweep(args.sweep_trials, 4, say)
    after = np.array([r["cpu_after"] for r in rows])
    before = np.array([r["cpu_before"] for r in rows])
    same = [r["k_before"] == r["k_after"] for r in rows]
    within = [eq or _explained(r) for r, eq in zip(rows, same)]
    say(f"CPU per call: quadrature off median {np.median(before):.2f} s, max "
        f"{before.max():.2f} s, <= 2 s in {np.mean(before <= 2.0):.1%}; on median "
        f"{np.median(after):.3f} s, max {after.max():.2f} s, <= 2 s in "
        f"{np.mean(after <= 2.0):.1%} of {len(rows)} scenes; chosen K equal in "
        f"{sum(same)} of {len(rows)}, the others' log odds within 2 combined errors in "
        f"{sum(within) - sum(same)} of {len(rows) - sum(same)}")
    say(f"goal (<= 2 s CPU per call on every scene, the evidences unchanged within their "
        f"errors): {'met' if after.max() <= 2.0 and all(within) else 'not met'}")
    for r, eq in zip(rows, same):
        if not eq:
            (a, ea), (b, eb) = r["odds_before"], r["odds_after"]
            say(f"  K differs: sigma={r['sigma']:g} sep={r['sep']:g}h #{r['trial']}: "
                f"{r['esc_before']} -> {r['esc_after']}; log Z_2 - log Z_1 {a:.3f} +- "
                f"{ea:.3f} -> {b:.3f} +- {eb:.3f} (tie: log 3 = 1.099)")
    for sigma in SWEEP_SIGMAS:
        sel = [r for r in rows if r["sigma"] == sigma]
        line = " ".join(
            f"{sep:g}:{np.mean([r['k_before'] == 2 for r in sel if r['sep'] == sep]):.2f}/"
            f"{np.mean([r['k_after'] == 2 for r in sel if r['sep'] == sep]):.2f}"
            for sep in SWEEP_SEPS)
        say(f"  sigma={sigma:g} P(K=2) off/on per separation (h): {line}")
    say()
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--full", action="store_true", help="more repeats")
    ap.add_argument("--out", type=Path, default=Path("out/select_speed"))
    ap.add_argument("--parts", default="1234", help="which parts to run, e.g. 24")
    ap.add_argument("--sweep-trials", type=int, default=None,
                    help="scenes per separation and sigma in part 4 (3; --full 10)")
    ap.add_argument("--n-live", type=int, default=None,
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

    lap, nvl, hard, swp = [], [], [], []
    args.sweep_trials = args.sweep_trials or (10 if args.full else 3)
    if "1" in args.parts:
        lap = part1(model, reps, say)
    if "2" in args.parts:
        nvl = part2(model, args, say)
    if "3" in args.parts:
        hard = part3(model, args, say)
    if "4" in args.parts:
        swp = part4(args, say)
    (args.out / "select_speed.txt").write_text("\n".join(lines) + "\n")
    (args.out / "select_speed.json").write_text(json.dumps(
        {"laplace": lap, "nested_vs_laplace": nvl, "hard": hard, "sweep": swp}, default=float,
        indent=1))
    return 0


def part1(model, reps, say) -> list[dict]:
    say("1. Laplace selection, K_max = 4, N = 30 (median ms per selection; target <= 50 ms)")
    lap = laplace_timing(model, reps)
    say(f"{'true K':>6} {'total':>8} {'CPU':>8} {'ML fits':>8} {'evidence':>9} {'correct':>8}")
    say("(total: wall time of select_k; CPU: its process CPU time, less sensitive to a loaded "
        "machine; ML fits: fit_ml for K=1..4 + cross-K repair; evidence: K=0 closed form, "
        "Fisher, Laplace, trust diagnostics for K=1..4, and importance sampling over the "
        "locations for each K whose Laplace value is untrusted -- the over-complete ones)")
    for r in lap:
        say(f"{r['k']:>6} {r['total_ms']:8.1f} {r['cpu_ms']:8.1f} {r['fits_ms']:8.1f} "
            f"{r['evidence_ms']:9.1f} {r['correct']:>8}")
    say()
    return lap


def part2(model, args, say) -> list[dict]:
    say(f"2. Nested (dynesty rslice, n_live={args.n_live or 'default'}, dlogz=0.1, "
        f"maxcall={args.maxcall}) vs Laplace, well-separated K=2 scene")
    nvl = nested_vs_laplace(model, 0, args.maxcall, args.n_live)
    say(f"{'K':>2} {'Laplace':>12} {'nested':>12} {'+-':>6} {'diff':>7} {'IS - Lapl.':>11} "
        f"{'+-':>6} {'trusted':>7} {'calls':>7} {'nested s':>8} {'Lapl. ms':>8} {'ratio':>7}")
    for r in nvl[:-1]:
        ratio = r["nested_s"] / r["laplace_ev_s"] if r["k"] else np.nan
        say(f"{r['k']:>2} {r['laplace']:12.3f} {r['nested']:12.3f} {r['err']:6.2f} "
            f"{r['diff']:7.2f} {r['is'] - r['laplace']:11.4f} {r['is_se']:6.4f} "
            f"{r['trusted']!s:>7} {r['calls']:7d} {r['nested_s']:8.2f} "
            f"{1e3 * r['laplace_ev_s']:8.2f} {ratio:7.0f}")
    say("(Laplace: select_k(method='laplace'), i.e. mixture importance sampling over the "
        "locations where trusted is False; IS: Student-t importance sampling around the ML "
        "mode, 50000 draws, x K! -- the "
        "precise reference for the Laplace value where the modes are apart; nested s: the "
        "dynesty run alone; Lapl. ms: Fisher + Laplace + diagnostics at the same ML point, "
        "ML fit excluded; ratio: per-K evidence step, nested / Laplace)")
    tot = nvl[-1]
    ev_l = sum(r["laplace_ev_s"] for r in nvl[:-1])
    ev_n = sum(r["nested_s"] for r in nvl[:-1])
    say(f"whole selection, the ML fits on both sides: Laplace {tot['laplace_s'] * 1e3:.1f} ms, "
        f"nested {tot['nested_s']:.1f} s, ratio {tot['ratio']:.0f}x")
    say(f"(the evidence step alone, ML fits excluded, K=1..4: Laplace {ev_l * 1e3:.1f} ms, "
        f"nested {ev_n:.1f} s, ratio {ev_n / ev_l:.0f}x; target >= 1000x)")
    say(f"p(K) Laplace {np.round(tot['p_laplace'], 3)}  nested {np.round(tot['p_nested'], 3)}")
    say()
    return nvl


def part3(model, args, say) -> list[dict]:
    say("3. Hard cases: what auto escalates (or why not), its cost vs nested sampling of the "
        "escalated K alone and of all K")
    rows = hard_cases(model, 0, args.maxcall)
    for r in rows:
        ratio = r["nested_s"] / r["auto_s"]
        say(f"- {r['case']} (K_max={r['k_max']}): auto K={r['auto_best']} in {r['auto_s']:.1f} s"
            f" (nested of its {len(r['escalated'])} escalated K alone {r['doubt_nested_s']:.1f} s)"
            f", nested all K: K={r['nested_best']} in {r['nested_s']:.1f} s (ratio {ratio:.1f}x)")
        say(f"    likelihood calls: auto {r['auto_calls']}, escalated K alone (nested) "
            f"{r['doubt_calls']}, nested all K {r['nested_calls']}")
        say(f"    p auto {r['p_auto']}  p nested {r['p_nested']}"
            + (f"  (nested runs capped at maxcall: K={r['capped']})" if r["capped"] else ""))
        for k, why in r["escalated"].items():
            say(f"    escalated K={k}: {why}")
        for note in r["notes"]:
            say(f"    note: {note}")
    return rows


if __name__ == "__main__":
    raise SystemExit(main())
