"""Cost of the fast ML fit against the number of sub-sensors N and of sources K.

Side by side in one run, CPU time of this process (``time.process_time``; BLAS
pinned to one thread), fits of one data vector at a time:

1. **Size.**  Rings and spheres (Fibonacci lattices) of N = 16 ... 10,000 sub-sensors, K
   = 1..4 well-separated sources (neighbours >= 30 deg apart, I ~ U(0.5, 1), sigma =
   0.01): the median time of ``fit_ml(warn=False)`` next to that of a plain-numpy fitter
   (:mod:`_numpy_baseline`: the same grid of candidate directions, K steps of orthogonal
   matching pursuit, damped Gauss-Newton) and of ``fit_ml``'s default call, which also
   runs the checks behind its warnings (goodness of fit, resolution, mirrored optima;
   none is shown), the three alternating in blocks of data vectors so that all see the
   same machine load. The goal's ratio is the default call's.  Printed: the exponent of
   cost against N (least squares on log-log, over the whole range and over N >= 1000),
   the ratio baseline / fit at N = 1000, the first fit's one-off set-up on a new model
   (atoms, Gram matrix, tuple plans; the baseline's atoms alike), and the share of data
   vectors on which each reaches the best optimum found (its own, the other's, or an LM
   run from the truth).
2. **Grid.**  The default grids are capped (rings 1024 angles, spheres 2048
   directions): optimum shares with the capped grid and with the former one
   (``max(128, 4N)`` angles, ``4N`` directions up to 8192) on the same data, at
   N = 300 and 1000 (ring; the exact ML among the references for K <= 3 at N = 300,
   K <= 2 at N = 1000) and 1000, 3000 (sphere).
3. **Many sources.**  K = 1..8 on a ring of 64 and on the Fig. 2 sphere (300):
   the median time per fit with and without the sliding search (interleaved), the
   exponent of cost against K, and the share of fits reaching the best optimum of
   both fits, an LM run from the truth, a long compiled search and the
   paper's multistart (``--ms-starts`` pseudo-random starts + L-BFGS-B), with
   standard errors (:mod:`_many_sources`).

Run ``python benchmarks/ml_scaling.py`` (quick: ~15 min) or ``--full``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from _many_sources import part_many  # noqa: E402
from _numpy_baseline import NumpyGridFitter  # noqa: E402

import olsbayes as ob  # noqa: E402
from olsbayes.circular import wrap_angle  # noqa: E402
from olsbayes.geometry import lonlat_to_unit  # noqa: E402
from olsbayes.ml import fit_ml  # noqa: E402
from olsbayes.ml.atoms import cached_default_grid  # noqa: E402
from olsbayes.ml.lm import refine_batch  # noqa: E402

SIZES = (16, 32, 64, 128, 256, 512, 1000, 2000, 5000, 10000)
#: Reached: within this many nats of the best log-likelihood found.
REACH = 1e-6


def make_model(kind: str, n: int, sigma: float = 1e-2) -> ob.Model:
    return ob.Model(ob.Ring(n) if kind == "ring" else ob.Sphere.fibonacci(n), sigma)


def scenes(kind: str, k: int, n: int, rng: np.random.Generator,
           min_sep_deg: float = 30.0) -> np.ndarray:
    """``n`` random scenes (n, P): neighbours >= min_sep_deg apart, I ~ U(0.5, 1)."""
    out = []
    while len(out) < n:
        if kind == "ring":
            a = rng.uniform(-np.pi, np.pi, k)
            d = np.abs(wrap_angle(a[:, None] - a[None, :]))
            loc = a[:, None]
        else:
            lon, lat = rng.uniform(-np.pi, np.pi, k), np.arcsin(rng.uniform(-1, 1, k))
            u = lonlat_to_unit(lon, lat)
            d = np.arccos(np.clip(u @ u.T, -1.0, 1.0))
            loc = np.column_stack([lon, lat])
        np.fill_diagonal(d, np.pi)
        if d.min() >= np.radians(min_sep_deg):
            out.append(np.column_stack([loc, rng.uniform(0.5, 1.0, k)]).ravel())
    return np.array(out)


def _best_ll(model, data, truth, *lls):
    """Best log-likelihood per data vector of the given fits and an LM run from the truth."""
    ref = refine_batch(model, data, truth)
    return np.max([model.log_likelihood(ref.x, data), *lls], axis=0)


def size_point(kind: str, n: int, k: int, trials: int, block: int, seed: int) -> dict:
    """One (kind, N, K): interleaved single fits of fit_ml and of the numpy baseline."""
    rng = np.random.default_rng([seed, n, k])
    model = make_model(kind, n)
    truth = scenes(kind, k, trials, rng)
    data = model.simulate(truth, rng=rng)
    c0 = time.process_time()
    fit_ml(model, data[0], k, warn=False)
    setup = time.process_time() - c0
    c0 = time.process_time()
    base = NumpyGridFitter(model.array.normals, cached_default_grid(model))
    base_setup = time.process_time() - c0
    cpu = {"fast": [], "default": [], "numpy": [], "pass": []}
    ll = {"fast": np.empty(trials), "numpy": np.empty(trials)}
    with warnings.catch_warnings():  # the default call checks and warns; none is shown
        warnings.simplefilter("ignore")
        fit_ml(model, data[0], k)  # the checks' first use (scipy's import) off the clock
        for lo in range(0, trials, block):
            for name in ("fast", "default", "numpy"):
                for i in range(lo, min(lo + block, trials)):
                    c0 = time.process_time()
                    if name == "fast":
                        x = fit_ml(model, data[i], k, warn=False).params
                    elif name == "default":
                        fit_ml(model, data[i], k)
                    else:
                        x = base.fit(data[i], k)[0]
                    cpu[name].append(time.process_time() - c0)
                    if name != "default":
                        ll[name][i] = model.log_likelihood(x, data[i])
                    if name == "numpy":  # one pass over the grid's atoms, a search's floor
                        c0 = time.process_time()
                        for _ in range(10):
                            base.atoms @ data[i]
                        cpu["pass"].append((time.process_time() - c0) / 10)
    best = _best_ll(model, data, model.canonical(truth), ll["fast"], ll["numpy"])
    fast_ms, numpy_ms = 1e3 * np.median(cpu["fast"]), 1e3 * np.median(cpu["numpy"])
    return {"kind": kind, "n": n, "k": k, "fast_ms": fast_ms, "numpy_ms": numpy_ms,
            "default_ms": 1e3 * np.median(cpu["default"]),
            "pass_ms": 1e3 * np.median(cpu["pass"]),
            "setup_ms": 1e3 * setup - fast_ms, "numpy_setup_ms": 1e3 * base_setup,
            "fast_reach": float(np.mean(best - ll["fast"] <= REACH)),
            "numpy_reach": float(np.mean(best - ll["numpy"] <= REACH))}


def exponent(x, y) -> float:
    """Slope of log y against log x (least squares)."""
    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


def verdict(ok: bool) -> str:
    return "met" if ok else "NOT met"


def part_size(args, say) -> list[dict]:
    say("1. size: median CPU ms per single fit (fit_ml(warn=False) | numpy grid + pursuit + "
        "Gauss-Newton on the same grid; and fit_ml's default call, which also runs the "
        "warnings' checks), one-off set-up of a new model, share reaching the best optimum")
    rows = []
    for kind in ("ring", "sphere"):
        for k in (1, 2, 3, 4):
            for n in args.sizes:
                r = size_point(kind, n, k, args.trials, args.block, args.seed)
                rows.append(r)
                say(f"  {kind:6s} K={k} N={n:6d}  fit {r['fast_ms']:8.2f}  numpy "
                    f"{r['numpy_ms']:8.2f}  ratio {r['numpy_ms'] / r['fast_ms']:5.2f}  "
                    f"default {r['default_ms']:8.2f}  set-up {r['setup_ms']:8.1f} | "
                    f"{r['numpy_setup_ms']:7.1f}  reach {r['fast_reach']:.2f} | "
                    f"{r['numpy_reach']:.2f}")
    say("\n  exponent of cost vs N (fit | numpy), whole range and N >= 1000; ratio numpy / fit "
        "at N = 1000, of warn=False and of the default call (goals: exponent <= 1 for both "
        "calls, default ratio >= 3) and the time numpy / 3 in passes of a data vector over "
        "the grid's atoms (A @ y, the least a search of the grid costs)")
    for kind in ("ring", "sphere"):
        for k in (1, 2, 3, 4):
            sel = [r for r in rows if r["kind"] == kind and r["k"] == k]
            ns = np.array([r["n"] for r in sel])
            f, b = np.array([r["fast_ms"] for r in sel]), np.array([r["numpy_ms"] for r in sel])
            dflt = np.array([r["default_ms"] for r in sel])
            hi = ns >= 1000
            e_all, e_hi = exponent(ns, f), exponent(ns[hi], f[hi]) if hi.sum() > 1 else np.nan
            e_def = max(exponent(ns, dflt), exponent(ns[hi], dflt[hi]) if hi.sum() > 1 else 0.0)
            at = [r for r in sel if r["n"] == 1000]
            ratio = at[0]["numpy_ms"] / at[0]["fast_ms"] if at else np.nan
            r_def = at[0]["numpy_ms"] / at[0]["default_ms"] if at else np.nan
            passes = at[0]["numpy_ms"] / 3 / at[0]["pass_ms"] if at else np.nan
            top = ns >= 5000  # past the step where the atoms outgrow the last-level cache
            e_top = exponent(ns[top], f[top]) if top.sum() > 1 else np.nan
            say(f"  {kind:6s} K={k}: exponent {e_all:5.2f} | {exponent(ns, b):5.2f}, N>=1000 "
                f"{e_hi:5.2f} | {exponent(ns[hi], b[hi]) if hi.sum() > 1 else np.nan:5.2f}, "
                f"N>=5000 {e_top:5.2f}, default call {e_def:5.2f}: "
                f"{verdict(max(e_all, e_hi, e_def) <= 1.0)};  ratio at N=1000 {ratio:5.2f}, "
                f"default call {r_def:5.2f}: {verdict(r_def >= 3.0)} "
                f"(numpy / 3 = {passes:.1f} grid passes)")
    return rows


def former_grid(model: ob.Model) -> np.ndarray:
    """The default grid before the caps: max(128, 4N) angles, 4N directions in [1024, 8192]."""
    n = model.n_sensors
    if model.kind == "angle":
        m = int(max(128, 4 * n))
        return np.angle(np.exp(2j * np.pi * (np.arange(m) + 0.5) / m))[:, None]
    m = int(np.clip(4 * n, 1024, 8192))
    j = np.arange(m) + 0.5
    lon = np.angle(np.exp(1j * np.pi * (1.0 + 5.0**0.5) * j))
    return np.column_stack([lon, np.arcsin(1.0 - 2.0 * j / m)])


def part_grid(args, say) -> list[dict]:
    say("\n2. grid: share of fits reaching the best optimum, capped default grid | former grid "
        "(same data; ring: the exact ML among the references where affordable)")
    rows = []
    for kind, ns in (("ring", (300, 1000)), ("sphere", (1000, 3000))):
        for n in ns:
            model = make_model(kind, n)
            old = former_grid(model)
            for k in (1, 2, 3, 4):
                rng = np.random.default_rng([args.seed, 7, n, k])
                truth = scenes(kind, k, args.grid_trials, rng)
                data = model.simulate(truth, rng=rng)
                new_ll = fit_ml(model, data, k, warn=False).log_likelihood
                old_ll = fit_ml(model, data, k, grid=old, warn=False).log_likelihood
                refs = [new_ll, old_ll]
                if kind == "ring" and k <= (3 if n <= 300 else 2):  # exact: affordable K
                    refs.append(fit_ml(model, data, k, method="exact", warn=False).log_likelihood)
                best = _best_ll(model, data, model.canonical(truth), *refs)
                r = {"kind": kind, "n": n, "k": k, "grid": old.shape[0],
                     "capped": cached_default_grid(model).shape[0],
                     "new_reach": float(np.mean(best - new_ll <= REACH)),
                     "old_reach": float(np.mean(best - old_ll <= REACH))}
                rows.append(r)
                say(f"  {kind:6s} N={n:5d} K={k} ({r['capped']} | {r['grid']} atoms, "
                    f"{args.grid_trials} fits): {r['new_reach']:.3f} | {r['old_reach']:.3f}")
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--full", action="store_true", help="more data vectors per point")
    p.add_argument("--parts", default="123", help="which parts to run, e.g. 13")
    p.add_argument("--seed", type=int, default=2025)
    p.add_argument("--block", type=int, default=5, help="fits per block of the interleaving")
    p.add_argument("--ms-starts", type=int, default=300, help="starts of the long multistart")
    p.add_argument("--many-ks", default="12345678", help="part 3: the numbers of sources")
    p.add_argument("--many-kinds", default="ring,sphere", help="part 3: ring and/or sphere")
    p.add_argument("--ms-trials", type=int, help="part 3: scenes with the L-BFGS-B multistart")
    p.add_argument("--out", type=Path, default=Path("out/ml_scaling"))
    a = p.parse_args(argv)
    a.sizes = SIZES
    a.trials, a.grid_trials = (60, 300) if a.full else (20, 100)
    a.many_trials, ms_trials = (200, 40) if a.full else (50, 10)
    a.ms_trials = ms_trials if a.ms_trials is None else a.ms_trials
    a.many_ks = [int(c) for c in a.many_ks]
    a.ref_scatter = {"ring": 3000, "sphere": 1000}
    a.ref_slide = {"ring": 64, "sphere": 16}
    a.out.mkdir(parents=True, exist_ok=True)
    lines: list[str] = []

    def say(s: str = "") -> None:
        print(s, flush=True)
        lines.append(s)

    warnings.simplefilter("ignore", (ob.ConvergenceWarning, ob.MultimodalWarning))
    for kind in ("ring", "sphere"):  # compiled code of every kind and K, before any timing
        model = make_model(kind, 40)
        for k in range(1, 9):
            x = scenes(kind, k, 1, np.random.default_rng(k), 20.0)
            fit_ml(model, model.simulate(x, rng=k), k, warn=False)
    out = {}
    if "1" in a.parts:
        out["size"] = part_size(a, say)
    if "2" in a.parts:
        out["grid"] = part_grid(a, say)
    if "3" in a.parts:
        out["many"] = part_many(a, say, scenes, exponent)
    (a.out / "ml_scaling.txt").write_text("\n".join(lines) + "\n")
    (a.out / "ml_scaling.json").write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
