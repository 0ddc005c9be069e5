"""Part 3 of benchmarks/ml_scaling.py: K = 1..8 sources on a 64-ring and the Fig. 2 sphere.

Per K: the CPU time per single fit of the default fast fit ("after") and of the
fast fit without the sliding search (``FastOptions(slide=0)``, "before"), the two
alternating in blocks of data vectors; and for K >= 5 the share of fits reaching
the best optimum of every fit run on the data vector: both fast fits, an LM run
from the truth, a long compiled search (``ref_scatter`` scattered starts refined
by LM and the sliding search from the ``ref_slide`` best distinct optima,
``FastOptions(scatter=..., slide=...)``) on every scene and the paper's L-BFGS-B
multistart (``ms_starts`` pseudo-random starts) on the first ``ms_trials``
scenes.  Shares are printed with their binomial standard error and the one-sided
95 % lower confidence bound (Clopper-Pearson), at 1e-6 nats of the best
log-likelihood; the default fit's also at 1e-3 and 0.1 nats, with the largest
shortfall.  The best optimum is the best of the methods run, so every share is an
upper bound of the share of fits at the global optimum.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.stats import beta

import olsbayes as ob
from olsbayes.ml import FastOptions, MultistartOptions, fit_ml
from olsbayes.ml.lm import refine_batch

__all__ = ["part_many"]

#: Reached: within this many nats of the best log-likelihood found; and a looser
#: tolerance that counts LM runs stopping a little short of one optimum (on a kink)
#: as reaching it.
REACH = 1e-6
REACH_LOOSE = 1e-3
#: Shortfall far below the likelihood's resolution (a likelihood ratio of 1.1).
REACH_NEAR = 0.1
BEFORE = FastOptions(slide=0)


def _timed(model, data, k, block) -> dict:
    """Log-likelihoods and CPU s per fit of the default fit and of ``BEFORE``, interleaved."""
    cpu = {"after": [], "before": []}
    ll = {"after": np.empty(len(data)), "before": np.empty(len(data))}
    for lo in range(0, len(data), block):
        for name, opts in (("after", None), ("before", BEFORE)):
            for i in range(lo, min(lo + block, len(data))):
                c0 = time.process_time()
                ll[name][i] = fit_ml(model, data[i], k, options=opts, warn=False).log_likelihood
                cpu[name].append(time.process_time() - c0)
    return {"ll": ll, "cpu": cpu}


def _share(ok: np.ndarray) -> tuple[float, float, float]:
    """Share, its binomial standard error and its one-sided 95 % lower bound."""
    n, s = ok.size, int(ok.sum())
    p = s / n
    low = 0.0 if s == 0 else float(beta.ppf(0.05, s, n - s + 1))
    return p, float(np.sqrt(p * (1 - p) / n)), low


def _point(kind, model, k, sep, args, scenes) -> dict:
    rng = np.random.default_rng([args.seed, 8, k])
    n = args.many_trials if k >= 5 else max(10, args.many_trials // 5)
    truth = scenes(kind, k, n, rng, sep)
    data = model.simulate(truth, rng=rng)
    fit_ml(model, data[0], k, warn=False)  # set-up of the model and plans
    fit_ml(model, data[0], k, options=BEFORE, warn=False)
    t = _timed(model, data, k, args.block)
    r = {"kind": kind, "k": k, "n": n,
         "after_ms": 1e3 * float(np.median(t["cpu"]["after"])),
         "before_ms": 1e3 * float(np.median(t["cpu"]["before"]))}
    if k < 5:
        return r
    ref = refine_batch(model, data, model.canonical(truth), kinks=True).x
    lls = [t["ll"]["after"], t["ll"]["before"], model.log_likelihood(ref, data)]
    c0 = time.process_time()
    long_opts = FastOptions(scatter=args.ref_scatter[kind], slide=args.ref_slide[kind])
    lls.append(fit_ml(model, data, k, options=long_opts, warn=False).log_likelihood)
    r["long_ms"] = 1e3 * (time.process_time() - c0) / n
    m = min(args.ms_trials, n)
    ms = np.full(n, -np.inf)
    if m:
        ms[:m] = fit_ml(model, data[:m], k, method="multistart", rng=k, warn=False,
                        options=MultistartOptions(args.ms_starts)).log_likelihood
    best = np.max(lls + [ms], axis=0)
    for name, ll in (("after", lls[0]), ("before", lls[1]), ("truth", lls[2]), ("long", lls[3])):
        r[name] = _share(best - ll <= REACH)
    r["after_loose"] = _share(best - lls[0] <= REACH_LOOSE)
    r["after_near"] = _share(best - lls[0] <= REACH_NEAR)
    r["worst_gap"] = float(np.max(best - lls[0]))
    r["ms"] = _share(best[:m] - ms[:m] <= REACH) if m else (np.nan,) * 3
    return r


def _say_point(say, model, r) -> None:
    head = (f"  {r['kind']:6s} N={model.n_sensors} K={r['k']}: {r['after_ms']:8.2f} ms "
            f"(before {r['before_ms']:8.2f})")
    if r["k"] < 5:
        say(head)
        return
    p, se, low = r["after"]
    say(f"{head}; share {p:.3f} +- {se:.3f} (95 % lower bound {low:.3f}, {r['n']} scenes): "
        f"{'met' if p >= 0.99 else 'NOT met'} (within {REACH_LOOSE:g} nats: "
        f"{r['after_loose'][0]:.3f}, {REACH_NEAR:g} nats: {r['after_near'][0]:.3f}, largest "
        f"shortfall {r['worst_gap']:.3f} nats); before {r['before'][0]:.3f}, LM from truth "
        f"{r['truth'][0]:.3f}, long search {r['long'][0]:.3f} ({r['long_ms']:.0f} ms), "
        f"L-BFGS-B multistart {r['ms'][0]:.3f}")


def part_many(args, say, scenes, exponent) -> list[dict]:
    """Run part 3; ``scenes`` and ``exponent`` are ml_scaling's helpers."""
    say(f"\n3. many sources: median CPU ms per single fit after | before the sliding search "
        f"(interleaved), share reaching the best of both, LM from the truth, a long compiled "
        f"search ({args.ref_scatter} LM starts, sliding search from {args.ref_slide} optima) "
        f"and L-BFGS-B multistart ({args.ms_starts} starts, first {args.ms_trials} scenes) "
        f"(goal: >= 0.99 for K = 5..8)")
    rows = []
    cases = (("ring", ob.Model(ob.Ring(64), 1e-2), 20.0),
             ("sphere", ob.Model(ob.Sphere.grid(15, 20), 1e-2), 30.0))
    for kind, model, sep in cases:
        if kind not in args.many_kinds:
            continue
        for k in args.many_ks:
            r = _point(kind, model, k, sep, args, scenes)
            rows.append(r)
            _say_point(say, model, r)
        sel = [r for r in rows if r["kind"] == kind]
        ks = [r["k"] for r in sel]
        e_a, e_b = (exponent(ks, [r[f"{w}_ms"] for r in sel]) for w in ("after", "before"))
        big = [r for r in sel if r["k"] >= 5]
        e_5 = exponent([r["k"] for r in big], [r["after_ms"] for r in big]) if len(big) > 1 \
            else np.nan
        worst = min((r["after"][0] for r in big), default=np.nan)
        say(f"  {kind}: cost ~ K^{e_a:.2f} after, K^{e_b:.2f} before over K = {min(ks)}..{max(ks)}"
            f" (K = 5..8 after: K^{e_5:.2f}); worst share K = 5..8 {worst:.3f}: "
            f"{'met' if worst >= 0.99 else 'NOT met'}")
    return rows
