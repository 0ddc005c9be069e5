"""Fig. 2 with the two-level prior: per-pixel uncertainty by exact block Gibbs.

For each grid convention (``olsbayes.imaging.olss``) and T noise draws of the
"OLSS" scene (sigma = 0.01) it runs the two-level MAP search
(``image(prior="two-level")``) and then
:func:`olsbayes.imaging.binary_gibbs.two_level_gibbs` -- exact heat-bath
updates of all 2^w bit patterns of each window (a source and its w - 1
nearest sources) -- with every chain started at the MAP scene (``--starts map``)
or half of them at the L1 relaxation rounded at random (``--starts mixed``:
do chains from elsewhere find the MAP's mode?).  Reported per convention:

* ``map err sd`` / ``mean err sd``: error sd of the MAP scene and of the
  posterior mean ``i_max * P(bright)``;
* ``cov90``: fraction of pixels whose 90 % credible set ({dark}, {bright} or
  both) contains the truth, pooled over pixels and draws; ``unsure``: fraction
  of pixels with 0.1 < P(bright) < 0.9;
* ``map fails``: draws where the truth has a higher L than the MAP scene;
  ``gibbs > map``: draws where the sampler visited a pattern with a higher L
  than the MAP scene; ``truth > best``: ... where the truth beats every
  pattern visited;
* ``max/med R-hat``: largest split R-hat over the bits of a draw (inf when
  chains sit frozen in different patterns), max / median over draws;
* ``sec``: median wall time of the sampler per image.

``python analyses/fig2_two_level_gibbs.py [--trials 20 --samples 200 --width 9]``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

import olsbayes as ob  # noqa: E402
from olsbayes.imaging import (  # noqa: E402
    ImageOptions,
    TwoLevel,
    design_matrix,
    neighbour_groups,
)
from olsbayes.imaging.binary import sparse_relaxation, two_level_log_posterior  # noqa: E402
from olsbayes.imaging.binary_gibbs import credible_sets, two_level_gibbs  # noqa: E402
from olsbayes.imaging.olss import SIGMA, fig2_sphere, olss_bitmap, olss_directions  # noqa: E402
from olsbayes.imaging.result import split_rhat  # noqa: E402

CONVENTIONS = [("grid", "endpoints"), ("grid", "centres"), ("linspace", "endpoints"),
               ("linspace", "centres")]


def run(sensors, sources, trials, n_samples, width, n_chains, starts, rng):
    model = ob.Model(fig2_sphere(sensors), SIGMA)
    dirs = olss_directions(sources)
    truth = olss_bitmap().ravel()
    a = design_matrix(model, dirs)
    groups = neighbour_groups(model, dirs, width - 1)
    s = {k: [] for k in ("map", "mean", "cov", "unsure", "fail", "better", "truth_best",
                         "rhat", "sec")}
    for _ in tqdm(range(trials), desc=f"{sensors} sensors", unit=" draw", leave=False):
        y = a @ truth + SIGMA * rng.standard_normal(a.shape[0])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ob.NullSpaceWarning)
            res = ob.image(model, y, dirs, TwoLevel(i_max=1.0),
                           options=ImageOptions(reference=truth), progress=False)
        relaxed = sparse_relaxation(a, y, SIGMA, 1.0)
        half = n_chains // 2 if starts == "mixed" else n_chains
        s0 = np.vstack([np.tile(res.mode > 0.5, (half, 1)),
                        rng.random((n_chains - half, a.shape[1])) < relaxed])
        t0 = time.perf_counter()
        g = two_level_gibbs(a, y, SIGMA, 1.0, s0, groups, n_samples, rng=rng,
                            n_burn=n_samples // 2)
        s["sec"].append(time.perf_counter() - t0)
        p = g.p_bright
        dark, bright = credible_sets(p, 0.9)
        s["map"].append(res.mode - truth)
        s["mean"].append(p - truth)
        s["cov"].append(np.mean(np.where(truth > 0.5, bright, dark)))
        s["unsure"].append(np.mean((p > 0.1) & (p < 0.9)))
        s["fail"].append(res.search.reference_better)
        s["better"].append(g.best_log_posterior > res.search.log_posterior + 1e-9)
        lp_truth = two_level_log_posterior(a, y, SIGMA, truth, 1.0, 0.5)
        s["truth_best"].append(lp_truth > g.best_log_posterior + 1e-9)
        s["rhat"].append(float(np.max(split_rhat(g.bits.astype(float)))))
    return {
        "sensors": sensors, "sources": sources, "draws": trials,
        "map_err_sd": float(np.std(s["map"])), "mean_err_sd": float(np.std(s["mean"])),
        "cov90": float(np.mean(s["cov"])), "unsure": float(np.mean(s["unsure"])),
        "map_fails": f"{sum(s['fail'])}/{trials}", "gibbs>map": f"{sum(s['better'])}/{trials}",
        "truth>best": f"{sum(s['truth_best'])}/{trials}",
        "max_rhat": float(np.max(s["rhat"])), "med_rhat": float(np.median(s["rhat"])),
        "sec": float(np.median(s["sec"])),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=20)
    p.add_argument("--samples", type=int, default=200)
    p.add_argument("--width", type=int, default=9, help="window: a source + width-1 nearest")
    p.add_argument("--chains", type=int, default=4)
    p.add_argument("--sensors", choices=["grid", "linspace"], default=None)
    p.add_argument("--starts", choices=["map", "mixed"], default="map")
    p.add_argument("--seed", type=int, default=20261123)
    args = p.parse_args()
    seeds = np.random.SeedSequence(args.seed).spawn(len(CONVENTIONS))
    rows = []
    for (sensors, sources), ss in zip(CONVENTIONS, seeds):
        if args.sensors in (None, sensors):
            rows.append(run(sensors, sources, args.trials, args.samples, args.width,
                            args.chains, args.starts, np.random.default_rng(ss)))
    head = list(rows[0])
    print(f"two-level block Gibbs: window {args.width}, {args.chains} chains x "
          f"{args.samples} sweeps (+{args.samples // 2} burn-in), starts {args.starts}")
    print(" ".join(f"{h:>11}" for h in head))
    for r in rows:
        print(" ".join(f"{r[h]:>11.4g}" if isinstance(r[h], float) else f"{r[h]!s:>11}"
                       for h in head))


if __name__ == "__main__":
    main()
