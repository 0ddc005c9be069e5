"""Do the imaging samplers mix?  R-hat, ESS and coverage per prior on the Fig. 2 problem.

Targets: rank-normalised split R-hat <= 1.01 and bulk ESS >= 400 for every
intensity on the Fig. 2 problem (``olsbayes.imaging.olss``: 304 sources at
known directions, the 15 x 20 sphere, sigma = 0.01, the "OLSS" scene), and
90 % intervals covering within +- 3 % of nominal when the truth is drawn from
the prior.  Per sensor convention (``grid``: 20 distinct meridians, every
sub-sensor has an antipode, design rank 135 of 304; ``linspace``: 19 distinct
meridians, rank 251):

* ``gaussian``     closed form (exact, independent draws): nothing to mix;
* ``nonnegative``, ``bounded``  ``image`` with its default: the Gibbs sampler with
  block HMC moves of the loose intensities, run until every intensity has
  R-hat <= 1.01 and bulk and tail ESS >= 400 (``--samples`` unset; sampler
  ``gibbs/auto``), or ``--chains`` chains of ``--samples`` kept draws (burn-in
  half that) with the samplers of ``--samplers`` (``gibbs``, ``hmc``, or
  ``gibbs-noblock``: Gibbs without the block moves);
* ``two-level``    :func:`olsbayes.imaging.binary_gibbs.two_level_gibbs` (windows of
  9 neighbouring sources) from the MAP scene in every chain (``map``) and from
  dispersed starts -- independent random bit patterns, P(bright) = 1/2
  (``dispersed``); split R-hat of the bits (inf: chains frozen in different
  patterns) and the share of bits whose chains disagree at the end.

Printed per row: largest R-hat, smallest bulk and tail ESS over the
intensities (arviz, rank-normalised), CPU seconds of the ``image`` call,
and "met"/"not met" for the goals R-hat <= 1.01 and ESS >= 400.  A last table
times the default ``image(model, data, directions)`` call (prior "bounded",
i_max from the readings; the convergence-driven run) and its mode-only path
against the 0.5 s CPU goal, with the draws per chain it kept and its R-hat / ESS
goals.
Then the coverage table: bounded prior (``i_max = 1``), truths drawn from Uniform(0,
1) on the 8-source scene of ``benchmarks/imaging.py`` (sigma = 0.3, where its chains
mix), 90 % HPD intervals pooled over sources and draws, with the binomial standard
error of the pooled share (draws are independent; the 8 sources of one draw are not,
so the error is a lower bound), per sensor convention.

``python benchmarks/imaging_mixing.py`` (quick: the default convergence-driven
run, 10 coverage draws) or ``--full`` (100 coverage draws); ``--samples N``
runs fixed chains of N draws.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402

import olsbayes as ob  # noqa: E402
from olsbayes.imaging import (  # noqa: E402
    Bounded,
    ImageOptions,
    NonNegative,
    TwoLevel,
    design_matrix,
    neighbour_groups,
)
from olsbayes.imaging.binary_gibbs import two_level_gibbs  # noqa: E402
from olsbayes.imaging.olss import SIGMA, fig2_sphere, olss_bitmap, olss_directions  # noqa: E402
from olsbayes.imaging.result import split_rhat  # noqa: E402


def _diagnostics(chains: np.ndarray) -> tuple[float, float, float]:
    """Largest rank-normalised split R-hat, smallest bulk and tail ESS; chains (C, S, K)."""
    import arviz as az

    ds = az.convert_to_dataset(np.asarray(chains, dtype=float))
    rhat = az.rhat(ds, method="rank")["x"].values
    bulk = az.ess(ds, method="bulk")["x"].values
    tail = az.ess(ds, method="tail")["x"].values
    return float(np.nanmax(rhat)), float(np.nanmin(bulk)), float(np.nanmin(tail))


def _fig2(sensors: str, seed: int):
    model = ob.Model(fig2_sphere(sensors), SIGMA)
    dirs = olss_directions("endpoints")
    truth = olss_bitmap().ravel()
    a = design_matrix(model, dirs)
    y = a @ truth + SIGMA * np.random.default_rng(seed).standard_normal(a.shape[0])
    return model, dirs, a, y


def box_row(sensors, prior_name, sampler, n_samples, n_chains, seed):
    model, dirs, _, y = _fig2(sensors, seed)
    prior = Bounded(i_max=1.0) if prior_name == "bounded" else NonNegative()
    if n_samples is None:  # the default: convergence-driven Gibbs with block moves
        opts, sampler = ImageOptions(n_chains=n_chains), "gibbs/auto"
    else:
        extra = {"block": 0.0} if sampler == "gibbs-noblock" else {}
        opts = ImageOptions(n_samples=n_samples, n_burn=n_samples // 2, n_chains=n_chains,
                            sampler=sampler.split("-")[0], **extra)
    c0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = ob.image(model, y, dirs, prior, options=opts, rng=seed, progress=False)
    cpu = time.process_time() - c0
    rhat, bulk, tail = _diagnostics(res.samples)
    return dict(sensors=sensors, prior=prior_name, sampler=sampler, draws=res.samples.shape[1],
                rhat=rhat, ess_bulk=bulk, ess_tail=tail, cpu=cpu,
                rhat_goal=_met(rhat <= 1.01), ess_goal=_met(min(bulk, tail) >= 400))


def _met(ok: bool) -> str:
    return "met" if ok else "not met"


def _draws(res) -> int:
    return 0 if res.samples is None else int(res.samples.shape[1])


def _goals(res, rhat, bulk, tail) -> dict:
    if res.samples is None:  # mode only: nothing to mix
        return dict(rhat_goal="-", ess_goal="-")
    return dict(rhat_goal=_met(rhat <= 1.01), ess_goal=_met(min(bulk, tail) >= 400))


def default_call_rows(seed, repeats=3):
    """CPU of ``image(model, data, directions)`` (all defaults) and of its mode-only path.

    A short fixed run first loads the compiled kernels and the sampler's imports,
    so that no row carries the process's one-off costs.
    """
    rows = []
    model, dirs, _, y = _fig2("grid", seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ob.image(model, y, dirs, options=ImageOptions(n_samples=4), rng=seed, progress=False)
    for sensors in ("grid", "linspace"):
        model, dirs, _, y = _fig2(sensors, seed)
        for label, kw in (("default", {}), ("mode-only", {"options": ImageOptions(n_samples=0)})):
            cpus = []
            for r in range(repeats if label == "mode-only" else 1):
                c0 = time.process_time()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    res = ob.image(model, y, dirs, rng=seed + r, progress=False, **kw)
                cpus.append(time.process_time() - c0)
            cpu = float(np.median(cpus))
            rhat, bulk, tail = (_diagnostics(res.samples) if res.samples is not None
                                else (float("nan"),) * 3)
            rows.append(dict(sensors=sensors, call=label, draws=_draws(res), cpu=cpu,
                             goal_cpu=0.5, cpu_goal=_met(cpu <= 0.5), rhat=rhat,
                             ess_bulk=bulk, ess_tail=tail, **_goals(res, rhat, bulk, tail)))
    return rows


def two_level_row(sensors, starts, n_samples, n_chains, seed):
    model, dirs, a, y = _fig2(sensors, seed)
    rng = np.random.default_rng(seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mapped = ob.image(model, y, dirs, TwoLevel(i_max=1.0)).mean > 0.5
    s0 = (np.repeat(mapped[None], n_chains, axis=0) if starts == "map"
          else rng.random((n_chains, a.shape[1])) < 0.5)
    groups = neighbour_groups(model, dirs, 9)
    t0 = time.perf_counter()
    run = two_level_gibbs(a, y, SIGMA, 1.0, s0, groups, n_samples, rng=rng,
                          n_burn=n_samples // 2)
    sec = time.perf_counter() - t0
    bits = run.bits.astype(float)
    rhat = float(np.nanmax(split_rhat(bits)))
    last = run.bits[:, -1]
    disagree = float(np.mean(np.any(last != last[0], axis=0)))
    return dict(sensors=sensors, prior="two-level", sampler=f"gibbs/{starts}", draws=n_samples,
                rhat=rhat, ess_bulk=float("nan"), ess_tail=float("nan"), sec=sec,
                bits_disagree=disagree)


def coverage_row(sensors, trials, n_samples, seed):
    rng = np.random.default_rng(seed)
    sigma = 0.3
    model = ob.Model(fig2_sphere(sensors), sigma)
    dirs = np.array([[lo, la] for la in (-0.5, 0.5) for lo in np.linspace(-1.2, 1.2, 4)])
    a = design_matrix(model, dirs)
    hits, rhats = [], []
    for _ in range(trials):
        truth = rng.random(8)
        y = a @ truth + sigma * rng.standard_normal(a.shape[0])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = ob.image(model, y, dirs, Bounded(i_max=1.0), rng=rng,
                           options=ImageOptions(n_samples=n_samples, n_burn=n_samples // 4))
        hits.append(res.covers(truth))
        rhats.append(_diagnostics(res.samples)[0])
    hits = np.concatenate(hits)
    p = float(hits.mean())
    return dict(sensors=sensors, truths="uniform prior", draws=trials, coverage90=p,
                binom_se=float(np.sqrt(p * (1 - p) / hits.size)), max_rhat=float(max(rhats)))


def _print(rows):
    head = list(dict.fromkeys(k for r in rows for k in r))
    print(" ".join(f"{h:>13}" for h in head))
    for r in rows:
        cells = [r.get(h, "") for h in head]
        print(" ".join(f"{c:>13.4g}" if isinstance(c, float) else f"{c!s:>13}" for c in cells),
              flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true")
    ap.add_argument("--samples", type=int, default=None, help="kept draws per chain")
    ap.add_argument("--chains", type=int, default=4)
    ap.add_argument("--trials", type=int, default=None, help="coverage draws")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--only", choices=("box", "default", "two-level", "coverage"),
                    default=None)
    ap.add_argument("--samplers", default="gibbs",
                    help="with --samples: box-prior samplers, comma-separated, of gibbs, "
                         "gibbs-noblock, hmc (hmc is slow on 'grid')")
    args = ap.parse_args(argv)
    n = args.samples
    trials = args.trials or (100 if args.full else 10)
    if args.only in (None, "box"):
        samplers = ["auto"] if n is None else args.samplers.split(",")
        _print([box_row(s, p, smp, n, args.chains, args.seed) for s in ("grid", "linspace")
                for p in ("nonnegative", "bounded") for smp in samplers])
    if args.only in (None, "default"):
        _print(default_call_rows(args.seed))
    n = n or 200
    if args.only in (None, "two-level"):
        _print([two_level_row(s, st, n, args.chains, args.seed) for s in ("grid", "linspace")
                for st in ("map", "dispersed")])
    if args.only in (None, "coverage"):
        _print([coverage_row(s, trials, 400, args.seed) for s in ("grid", "linspace")])


if __name__ == "__main__":
    main()
