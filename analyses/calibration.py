"""Simulation-based calibration (SBC) of the posterior sampler and of the posterior over K.

For each replicate: a scene drawn from the prior (ring of 16 sub-sensors, sigma
0.05, directions uniform, intensities Uniform(0, 2)), simulated readings, an
emcee posterior (:func:`olsbayes.posterior.sample` with the same prior), and the
ranks of the true (canonically ordered) parameters among 99 thinned draws.
Rank histograms per parameter, chi-square and KS uniformity tests, and the
coverage of the central 50 % and 90 % intervals (from the ranks, so exactly 0.5
and 0.9 for a calibrated posterior).  The posterior over K from
:func:`olsbayes.select.select_k` (Laplace evidences, importance sampling for the K
where Laplace is untrusted; K uniform on 0..2) is calibrated with the randomised PIT.

The same scenes (same study seed) are also given to the exact reference posterior
of :mod:`olsbayes.studies.sbc_exact` (grid over the directions, intensities
integrated analytically; no Markov chain).  Its coverage on the same scenes tells
the scenes' own fluctuation (binomial, se 0.021 at 200 replicates) apart from a
defect of the sampler: the paired difference sampler - exact has a much smaller se.

Quick (default): K = 1 and K = 2 (sorted directions), 200 replicates each, chains
run to 20 autocorrelation times; K-selection 300 replicates (some K = 2
replicates have a dim or close second source whose chain needs thousands of
steps).  --full: 500 replicates each, 50 autocorrelation times; K-selection 1000
replicates.

Outputs in --out: calibration.png, calibration.nc (summary), the raw study
NetCDF files, calibration.txt (the printed table).
"""

from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _study_cli import parser, study, table  # noqa: E402

from olsbayes.studies.sbc import N_DRAWS, rank_test, sbc_k, sbc_posterior  # noqa: E402
from olsbayes.studies.sbc_exact import sbc_exact  # noqa: E402

__all__ = ["main"]

N_BINS = 10  # 100 possible ranks -> 10 equal bins


def run_posterior_sbc(args, k: int, n: int):
    fixed = {"n_sensors": 16, "sigma": 0.05, "n_sources": k, "i_max": 2.0,
             "tau_multiple": 50.0 if args.full else 20.0, "max_steps": 20000}
    # small chunks: a few replicates (a dim or close second source) run much longer
    return study(args, f"sbc-k{k}", sbc_posterior, {}, n, fixed=fixed, seed_offset=k,
                 chunk_size=4)


def run_exact_sbc(args, k: int, n: int):
    """The exact posterior on the scenes of :func:`run_posterior_sbc` (same seed offset)."""
    fixed = {"n_sensors": 16, "sigma": 0.05, "n_sources": k, "i_max": 2.0}
    return study(args, f"sbc-exact-k{k}", sbc_exact, {}, n, fixed=fixed, seed_offset=k,
                 chunk_size=10)


def paired_rows(ds, dx, k: int) -> list:
    """Coverage of the sampler (from its ranks) and of the exact posterior (from its CDF
    at the truth) on the same scenes, their difference and its paired standard error."""
    names = [f"{nm}[{j}]" for j in range(k) for nm in ("theta", "I")]
    rows = []
    for p, name in enumerate(names):
        r, c = ds["rank"].values[:, p], dx["cdf"].values[:, p]
        row = [f"K={k} {name}", len(r)]
        for level in (0.5, 0.9):
            lo = int(round((N_DRAWS + 1) * (1 - level) / 2))
            a = (r >= lo) & (r < N_DRAWS + 1 - lo)  # as in _coverage
            b = (c > (1 - level) / 2) & (c < (1 + level) / 2)
            d = a.astype(float) - b
            row += [float(a.mean()), float(b.mean()), float(d.mean()),
                    float(d.std() / np.sqrt(len(d)))]
        rows.append(row)
    return rows


def _coverage(ranks: np.ndarray, level: float) -> float:
    """Fraction of replicates whose truth lies in the central ``level`` interval of the
    draws, read off the ranks (0..N_DRAWS): e.g. 90 % = ranks 5..94 of 0..99, so a
    calibrated posterior gives exactly ``level`` in expectation.  (Interpolated sample
    quantiles of 99 draws would give 0.882 for 90 % and 0.49 for 50 %.)"""
    n = N_DRAWS + 1
    lo = int(round(n * (1 - level) / 2))
    return float(np.mean((ranks >= lo) & (ranks < n - lo)))


def summarise(ds, k: int, rng) -> tuple[list, dict]:
    names = [f"{nm}[{j}]" for j in range(k) for nm in ("theta", "I")]
    rows, hists = [], {}
    n = ds.sizes["trial"]
    for p, name in enumerate(names):
        r = ds["rank"].values[:, p]
        rt = rank_test(r, N_DRAWS, N_BINS, rng=rng)
        c50, c90 = _coverage(r, 0.5), _coverage(r, 0.9)
        rows.append([f"K={k} {name}", n, rt.chi2, rt.p_value, rt.ks_p_value, c50,
                     np.sqrt(0.25 / n), c90, np.sqrt(0.09 / n)])
        hists[f"K={k} {name}"] = rt.counts
    return rows, hists


def plot(hists: dict, n_per: dict, pit: np.ndarray, path) -> None:
    import matplotlib.pyplot as plt

    m = len(hists) + 1
    cols = min(4, m)
    fig, axes = plt.subplots(-(-m // cols), cols, figsize=(3.2 * cols, 2.6 * -(-m // cols)),
                             squeeze=False)
    for ax, (name, counts) in zip(axes.flat, hists.items()):
        n = n_per[name]
        ax.bar(np.arange(N_BINS), counts, width=1.0, color="C0", edgecolor="white")
        e = n / N_BINS
        band = 1.96 * np.sqrt(e * (1 - 1 / N_BINS))
        ax.axhspan(e - band, e + band, color="0.85", zorder=0)
        ax.axhline(e, color="k", lw=0.8)
        ax.set_title(f"ranks of {name}", fontsize=9)
        ax.set_xticks([])
    ax = axes.flat[len(hists)]
    ax.hist(pit, bins=N_BINS, range=(0, 1), color="C2", edgecolor="white")
    e = len(pit) / N_BINS
    band = 1.96 * np.sqrt(e * (1 - 1 / N_BINS))
    ax.axhspan(e - band, e + band, color="0.85", zorder=0)
    ax.axhline(e, color="k", lw=0.8)
    ax.set_title("randomised PIT of K (select_k)", fontsize=9)
    for ax in list(axes.flat)[m:]:
        ax.set_visible(False)
    fig.suptitle("SBC: uniform histograms (grey: 95 % band per bin) mean a calibrated posterior",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    args = parser("calibration", __doc__).parse_args()
    import xarray as xr

    ks = (1, 2)
    n = 500 if args.full else 200
    rng = np.random.default_rng(args.seed)
    rows, hists, n_per, paired = [], {}, {}, []
    for k in ks:
        ds = run_posterior_sbc(args, k, n)
        paired += paired_rows(ds, run_exact_sbc(args, k, n), k)
        r, h = summarise(ds, k, rng)
        rows += r
        hists.update(h)
        n_per.update({name: n for name in h})
        conv = float(ds["converged"].mean())
        print(f"K={k}: {n} replicates, converged fraction {conv:.3f}, "
              f"median {float(ds['seconds'].median()):.2f} s per posterior")
    nk = 1000 if args.full else 300
    dk = study(args, "sbc-select", sbc_k, {}, nk, fixed={"n_sensors": 16, "sigma": 0.05,
                                                         "i_max": 2.0, "k_max": 2})
    pit = dk["pit"].values
    counts = np.histogram(pit, bins=N_BINS, range=(0, 1))[0]
    from scipy import stats

    chi2, p = stats.chisquare(counts)
    rows.append(["K (select_k PIT)", nk, float(chi2), float(p),
                 float(stats.kstest(pit, "uniform").pvalue), float(np.mean(np.abs(pit - .5) < .25)),
                 np.sqrt(0.25 / nk), float(np.mean(np.abs(pit - .5) < .45)), np.sqrt(0.09 / nk)])
    header = ["parameter", "n", "chi2(9 dof)", "p chi2", "p KS", "cover50", "se", "cover90",
              "se"]
    text = table(header, rows)
    acc = float(np.mean(dk["k_best"].values == dk["k_true"].values))
    text += f"\nK selection: accuracy of k_best {acc:.3f} over {nk} prior draws of K in 0..2"
    text += ("\n\nSampler vs exact posterior on the same scenes (paired; se of the difference)\n"
             + table(["parameter", "n", "samp50", "exact50", "diff", "se", "samp90", "exact90",
                      "diff", "se"], paired))
    print(text)
    plot(hists, n_per, pit, args.out / "calibration.png")
    cols = {"n": 1, "chi2": 2, "p_chi2": 3, "p_ks": 4, "cover50": 5, "cover90": 7}
    summary = xr.Dataset({k: ("parameter", [r[i] for r in rows]) for k, i in cols.items()},
                         coords={"parameter": [r[0] for r in rows]},
                         attrs={"seed": args.seed, "n_draws": N_DRAWS})
    summary.to_netcdf(args.out / "calibration.nc", engine="h5netcdf")
    (args.out / "calibration.txt").write_text(text + "\n")


if __name__ == "__main__":
    main()
