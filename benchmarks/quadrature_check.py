"""The ring quadrature evidence against nested sampling and the grid reference.

For K = 1 and 2 on a well-separated and a close two-source scene (ring N = 30,
sigma = 0.01, intensities Uniform(0, 2)), on the escalated scenes of the
resolution-limit sweep and on a pair half a spacing apart at sigma = 1e-4 (whose
K = 2 needs cells aligned per direction): log Z by :func:`olsbayes.select.ring_log_evidence`
(three seeds: mean, stated error, scatter of the seeds, CPU per call) and by
nested sampling as ``select_k`` runs it (``NestedOptions()``: three dynesty
runs combined, their stated error, CPU).  Both integrate the labelled scene
prior on the whole torus, so they must agree within the nested error.

Usage::

    python benchmarks/quadrature_check.py [--long]   # --long: also 9 nested runs
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from olsbayes import Model, Ring
from olsbayes.priors import default_priors
from olsbayes.select import NestedOptions, ring_log_evidence
from olsbayes.select.engine import laplace_work, nested_work
from olsbayes.select.fits import fit_all

H = 2 * np.pi / 30


def _scenes():
    model = Model(Ring(30), 0.01)
    yield "separated (-0.6, 1.0), (1.5, 0.6)", model, model.simulate(
        np.array([-0.6, 1.0, 1.5, 0.6]), rng=np.random.default_rng(0))
    yield "close pair 0.75 h", model, model.simulate(
        np.array([0.2, 1.0, 0.2 + 0.75 * H, 1.0]), rng=np.random.default_rng(0))
    rng = np.random.default_rng([4, 2])  # the sweep of select_speed.py part 4, sigma 1e-2
    for sep in (0.25, 0.5, 0.75):
        for t in range(3):
            th = rng.uniform(-np.pi, np.pi)
            d = model.simulate(model.canonical(np.array([th, 1.0, th + sep * H, 1.0])), rng=rng)
            rng.integers(2**31)
            if t == 0 and sep in (0.25, 0.75):
                yield f"sweep sep {sep} h #0", model, d
    model = Model(Ring(30), 1e-4)  # square cells exceed the budget: cells aligned per direction
    yield "close pair 0.5 h, sigma 1e-4", model, model.simulate(
        np.array([0.3, 1.0, 0.3 + 0.5 * H, 1.0]), rng=np.random.default_rng(0))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--long", action="store_true", help="also nested with 9 runs")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    print(f"{'scene':<36} K {'quadrature':>20} {'seed sd':>8} {'CPU s':>6} "
          f"{'nested (3 runs)':>20} {'CPU s':>6} {'diff/err':>8}")
    for name, model, d in _scenes():
        fitted = fit_all(model, d, 2, method="fast", options=None,
                         rngs=[np.random.default_rng(i) for i in range(3)])
        for k in (1, 2):
            prior = default_priors(model, k, i_max=2.0)
            fits = [fitted[j][1] for j in range(1, k + 1)]
            c0 = time.process_time()
            q = [ring_log_evidence(model, d, prior, fits, rng=np.random.default_rng(s))
                 for s in range(3)]
            cq = (time.process_time() - c0) / 3
            v = np.array([x.log_evidence for x in q])
            work = laplace_work(model, k, fitted[k], prior, None)
            runs = [NestedOptions()] + ([NestedOptions(n_runs=9)] if args.long else [])
            for opts in runs:
                c0 = time.process_time()
                nw = nested_work(model, d, work, prior, opts, rng=np.random.default_rng(7))
                cn = time.process_time() - c0
                print(f"{name:<36} {k} {v.mean():11.3f} +- {q[0].error:6.3f} "
                      f"{v.std(ddof=1):8.3f} {cq:6.2f} {nw.value:11.3f} +- {nw.error:6.3f} "
                      f"{cn:6.1f} {(v.mean() - nw.value) / nw.error:8.2f}"
                      + (f"  ({opts.n_runs} runs)" if opts.n_runs != 3 else ""), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
