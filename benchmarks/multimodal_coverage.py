"""Coverage of 90 % posterior intervals on a near-antipodal four-source ring scene.

The scene: a ring of 30 sub-sensors, sources at -2.6, -1.05, 0.45, 1.95 rad with
intensities 1, 0.8, 1.2, 0.9 (two pairs within 0.7 sensor spacings of antipodal,
:mod:`olsbayes.antipodal`), sigma = 1e-3.  For each of ``--n`` noise draws
(seeds 0, 1, ...) the posterior is sampled twice with default run settings: the
single ensemble (``SamplerOptions(multimodal=False)``, the sampler without a mode
search) and the default automatic choice (which finds the mirrored modes and runs
the multimodal sampler).  A parameter is covered when its true value lies
between the 5 % and 95 % quantiles of its marginal (sources matched to the
posterior mean, angles unwrapped around it).  Printed per path: the share of
(draw, parameter) pairs covered with two standard errors -- the binomial one over
the draws, sqrt(c (1 - c) / n), and one from the spread of the per-draw coverages
(the 8 parameters of a draw are not independent) -- the share of draws whose 8
parameters are all covered, the modes found, and the CPU time per posterior.

Usage::

    python benchmarks/multimodal_coverage.py            # 64 noise draws
    python benchmarks/multimodal_coverage.py --quick    # 6 noise draws
    python benchmarks/multimodal_coverage.py --steps 600  # fixed-length ensembles
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

import olsbayes as ob
from olsbayes.circular import wrap_angle
from olsbayes.exchange import match_sources

TRUTH = np.array([-2.6, 1.0, -1.05, 0.8, 0.45, 1.2, 1.95, 0.9])
SIGMA = 1e-3


def covered(result, model, truth: np.ndarray) -> np.ndarray:
    """Which parameters (P,) have the truth inside their central 90 % interval."""
    x = result.unwrapped_samples().reshape(-1, result.n_params)
    t = match_sources(model, truth, result.estimate)
    periodic = result.periodic
    t[periodic] = result.estimate[periodic] + wrap_angle(t[periodic] - result.estimate[periodic])
    lo, hi = np.quantile(x, [0.05, 0.95], axis=0)
    return (lo <= t) & (t <= hi)


def run(multimodal: bool | None, data: np.ndarray, model, seed: int, steps: int | None
        ) -> tuple[np.ndarray, float, int]:
    """(covered (P,), CPU seconds, modes) of one posterior."""
    opts = (ob.SamplerOptions(multimodal=multimodal) if steps is None else
            ob.SamplerOptions(multimodal=multimodal, n_steps=steps, rhat_max=None))
    t0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = ob.sample_posterior(model, data, 4, rng=1000 + seed, progress=False,
                                  options=opts)
    cpu = time.process_time() - t0
    return covered(res, model, TRUTH), cpu, 1 if res.modes is None else res.modes.n_modes


def report(name: str, cov: np.ndarray, cpu: list[float], modes: list[int]) -> None:
    """One line: coverage with its standard errors, all-covered share, modes, CPU."""
    n = cov.shape[0]
    c = float(cov.mean())
    per_draw = cov.mean(axis=1)
    print(f"{name:<22} coverage {c:.3f} +- {np.sqrt(c * (1 - c) / n):.3f} (binomial, n={n}) "
          f"+- {per_draw.std(ddof=1) / np.sqrt(n):.3f} (per draw); all 8 covered "
          f"{np.mean(cov.all(axis=1)):.3f}; modes {np.mean(modes):.2f}; "
          f"CPU {np.mean(cpu):.1f} s per posterior")


def main() -> None:
    """Run both paths over the noise draws and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=64, help="noise draws (default 64)")
    parser.add_argument("--quick", action="store_true", help="6 noise draws")
    parser.add_argument("--steps", type=int, default=None,
                        help="a fixed number of steps per ensemble (default: run until "
                             "the default convergence criteria hold)")
    args = parser.parse_args()
    n = 6 if args.quick else args.n
    model = ob.Model(ob.Ring(30), sigma=SIGMA)
    out = {False: ([], [], []), None: ([], [], [])}
    for seed in range(n):
        data = model.simulate(TRUTH, rng=seed)
        for path, (cov, cpu, modes) in out.items():
            c, t, m = run(path, data, model, seed, args.steps)
            cov.append(c)
            cpu.append(t)
            modes.append(m)
        print(f"draw {seed}: single {out[False][0][-1].mean():.2f} "
              f"({out[False][1][-1]:.1f} s), automatic {out[None][0][-1].mean():.2f} "
              f"({out[None][1][-1]:.1f} s, {out[None][2][-1]} modes)", flush=True)
    steps = "default run length" if args.steps is None else f"{args.steps} steps per ensemble"
    print(f"90 % intervals, near-antipodal 4-source ring of 30, sigma = {SIGMA:g}, {steps}")
    report("single ensemble", np.array(out[False][0]), out[False][1], out[False][2])
    report("automatic (modes)", np.array(out[None][0]), out[None][1], out[None][2])


if __name__ == "__main__":
    main()
