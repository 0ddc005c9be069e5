"""Speed at equal accuracy: fit_ml against the plain-numpy fitter given the starts it needs.

The plain-numpy fitter of :mod:`_numpy_baseline` (grid, greedy pursuit, damped
Gauss-Newton) reaches the best optimum found less often than ``fit_ml`` from K = 2
on (``ml_scaling.py`` prints both shares), so their time ratio compares fits of
unequal accuracy.  Here the numpy fitter runs R pursuits (the r-th forced to take
the r-th best-correlated distinct atom first), each refined, the best kept, for R =
1, 2, 4, ...; printed per R: the median CPU ms per fit and the share of scenes
reaching the best optimum (within ``--reach`` nats, default 0.01, of the best of
every fit and an LM run from the truth: the same optimum, if less tightly
converged), with its binomial standard error, beside ``fit_ml``'s default call,
all interleaved in blocks of scenes in one process (CPU time, BLAS on one thread).
The last lines per row: the fewest starts R whose share is at least ``fit_ml``'s, and
the time ratio numpy(R) / fit_ml there ("not reached" if no R of the list does); the
same for a share of at least 0.99 (one miss in 100 scenes).

Run ``python benchmarks/ml_equal_accuracy.py`` (~7 min; ``--trials`` scenes per row;
100 took ~12 min).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402
from _numpy_baseline import NumpyGridFitter  # noqa: E402
from ml_scaling import _best_ll, make_model, scenes  # noqa: E402

from olsbayes.ml import fit_ml  # noqa: E402
from olsbayes.ml.atoms import cached_default_grid  # noqa: E402


def row(kind: str, n: int, k: int, starts: tuple[int, ...], trials: int, block: int,
        seed: int, reach: float) -> dict:
    """Interleaved fits of one (kind, N, K): CPU ms (median) and log-likelihoods per variant."""
    rng = np.random.default_rng([seed, n, k])
    model = make_model(kind, n)
    truth = scenes(kind, k, trials, rng)
    data = model.simulate(truth, rng=rng)
    base = NumpyGridFitter(model.array.normals, cached_default_grid(model))
    names = ("fit_ml",) + tuple(f"numpy R={r}" for r in starts)
    cpu = {name: [] for name in names}
    ll = {name: np.empty(trials) for name in names}
    with warnings.catch_warnings():  # the default call checks and warns; none is shown
        warnings.simplefilter("ignore")
        fit_ml(model, data[0], k)  # set-up outside the clock: atoms, plans; the
        base.fit(data[0], k, 2)  # numpy fitter's table of close atoms
        for lo in range(0, trials, block):
            for name, r in zip(names, (0,) + starts):
                for i in range(lo, min(lo + block, trials)):
                    c0 = time.process_time()
                    x = fit_ml(model, data[i], k).params if r == 0 else base.fit(data[i], k, r)[0]
                    cpu[name].append(time.process_time() - c0)
                    ll[name][i] = model.log_likelihood(x, data[i])
    best = _best_ll(model, data, model.canonical(truth), *ll.values())
    return {name: (1e3 * np.median(cpu[name]), float(np.mean(best - ll[name] <= reach)))
            for name in names}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=60)
    p.add_argument("--block", type=int, default=10)
    p.add_argument("--n", type=int, default=1000)
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--reach", type=float, default=0.01,
                   help="nats below the best log-likelihood that still count as reaching it")
    a = p.parse_args(argv)
    starts = (1, 2, 4, 8, 16)
    print(f"N = {a.n}, {a.trials} well-separated scenes per row; CPU ms per fit (median) and "
          f"share within {a.reach:g} nats of the best optimum (+- binomial se)")
    for kind in ("ring", "sphere"):
        for k in (1, 2, 3, 4):
            out = row(kind, a.n, k, starts, a.trials, a.block, a.seed, a.reach)
            ms0, share0 = out.pop("fit_ml")
            se = np.sqrt(max(share0 * (1 - share0), 1 / a.trials) / a.trials)
            cells = "  ".join(f"{name.split()[1]} {ms:6.2f} ms {sh:4.2f}"
                              for name, (ms, sh) in out.items())
            print(f"  {kind:6s} K={k}  fit_ml {ms0:6.2f} ms {share0:4.2f} (se {se:.2f})  | "
                  f"numpy {cells}")
            equal = [(name, ms) for name, (ms, sh) in out.items() if sh >= share0]
            if equal:
                name, ms = equal[0]
                print(f"         equal accuracy: numpy {name.split()[1]}, {ms:.2f} ms: "
                      f"numpy / fit_ml = {ms / ms0:.2f}")
            else:
                print(f"         equal accuracy: not reached with R <= {max(starts)} starts")
            near = [(name, ms) for name, (ms, sh) in out.items() if sh >= 0.99]
            if near:
                print(f"         share >= 0.99: numpy {near[0][0].split()[1]}, {near[0][1]:.2f} "
                      f"ms: numpy / fit_ml = {near[0][1] / ms0:.2f}")


if __name__ == "__main__":
    main()
