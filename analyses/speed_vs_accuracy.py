"""Speed vs accuracy of every estimator: time per estimate against RMSE / CRLB.

Ring of N sub-sensors (16 quick, 30 --full), K in {1, 2, 3} sources of
intensity 1, 90 deg apart (a quarter-circle grid: three equal sources spread
evenly, 120 deg apart, are nearly unidentifiable under the clipped cosine, whose
harmonics 1, 2, 4 then cancel), at a uniformly random rotation, noise sigma in
{1e-3, 1e-2, 1e-1}.  Estimators (:func:`olsbayes.studies.estimators.ring_estimate`,
each an :class:`~olsbayes.studies.Estimator`): ML fast (one fit per call), ML
fast batched (all trials of a cell in one call), the paper's multistart baseline
with n_starts = 2, 5, 20, the posterior mean of emcee chains of a few fixed
lengths (n_steps), and the posterior mean of dynesty nested sampling under a
likelihood-call cap (max_calls).

y = sqrt(mean over trials of mean over sources of (error / CRLB std)^2) of the
directions (1 = efficient; the CRLB is evaluated at each trial's truth); its
standard error by the delta method.  x = median CPU time per estimate measured
inside the trial (the worker's process time, which other programs sharing the
cores do not inflate; for the batched fit, batch time / batch size); the table
also gives the median wall time.  "fail" = fraction of trials with some
parameter off by more than 5 CRLB std; "of which ll>=truth" = those failures whose
estimate has a log-likelihood at least that of the truth (an ambiguity of the
likelihood, not a search failure).  Hollow markers: most trials not converged (an
emcee chain shorter than 50 autocorrelation times, or nested sampling stopped by
its likelihood-call cap: 10000 quick, 50000 --full).

Outputs in --out: speed_vs_accuracy.png, speed_vs_accuracy.nc (summary), one
NetCDF per estimator (raw trials, resumable checkpoints), speed_vs_accuracy.txt.
"""

from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _study_cli import parser, slug, study, table  # noqa: E402

from olsbayes.studies import Estimator  # noqa: E402
from olsbayes.studies.estimators import ring_estimate  # noqa: E402

__all__ = ["main"]

SIGMAS = [1e-3, 1e-2, 1e-1]
KS = [1, 2, 3]


FAST, BATCHED = Estimator("fast"), Estimator("fast", batched=True)
#: (estimator, trials per cell), in the order of the study seeds (seed offset j)
QUICK = [(FAST, 40), (BATCHED, 40), (Estimator("multistart", n_starts=2), 6),
         (Estimator("multistart", n_starts=5), 4), (Estimator("multistart", n_starts=20), 2),
         (Estimator("posterior", n_steps=200), 3), (Estimator("posterior", n_steps=1000), 2),
         (Estimator("nested", max_calls=10000), 1)]
FULL = [(FAST, 400), (BATCHED, 400), (Estimator("multistart", n_starts=2), 100),
        (Estimator("multistart", n_starts=5), 60), (Estimator("multistart", n_starts=20), 30),
        (Estimator("posterior", n_steps=200), 40), (Estimator("posterior", n_steps=1000), 30),
        (Estimator("posterior", n_steps=5000), 20), (Estimator("nested", max_calls=50000), 20)]


def summarise(ds) -> dict:
    z2 = ds["dir_z2"].where(np.isfinite(ds["dir_z2"]))
    n = z2.count("trial")
    m = z2.mean("trial")
    se = z2.std("trial", ddof=1) / np.sqrt(n)
    ratio = np.sqrt(m)
    return {
        "rmse_ratio": ratio.squeeze("estimator", drop=True),
        "rmse_ratio_se": (se / (2 * ratio)).squeeze("estimator", drop=True),
        "seconds": ds["seconds"].median("trial").squeeze("estimator", drop=True),
        "cpu_seconds": ds["cpu_seconds"].median("trial").squeeze("estimator", drop=True),
        "fail": (ds["max_z"] > 5).mean("trial").squeeze("estimator", drop=True),
        # failures whose estimate fits the data at least as well as the truth: the
        # likelihood itself is ambiguous there, no optimiser could do better
        "fail_ambiguous": ((ds["max_z"] > 5) & (ds["ll_gain"] >= 0)).mean("trial").squeeze(
            "estimator", drop=True),
        "converged": ds["converged"].mean("trial").squeeze("estimator", drop=True),
        "n": n.squeeze("estimator", drop=True),
    }


def plot(summary, path) -> None:
    import matplotlib.pyplot as plt

    labels = list(summary.estimator.values)
    markers = {1: "o", 2: "s", 3: "^"}
    fig, axes = plt.subplots(1, len(SIGMAS), figsize=(5 * len(SIGMAS), 4.6), sharey=True,
                             squeeze=False)
    axes = axes[0]
    for ax, sig in zip(axes, SIGMAS):
        for i, label in enumerate(labels):
            for k in KS:
                c = summary.sel({"estimator": label, "sigma": sig, "n_sources": k})
                hollow = float(c.converged) < 0.5
                ax.errorbar(float(c.cpu_seconds), float(c.rmse_ratio), yerr=float(c.rmse_ratio_se),
                            fmt=markers[k], color=f"C{i}", ms=6, capsize=2,
                            mfc="none" if hollow else f"C{i}",
                            label=label if (k == 1) else None)
        ax.axhline(1.0, color="k", lw=0.8, ls="--")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("CPU time per estimate (s)")
        ax.set_title(f"sigma = {sig:g}", fontsize=10)
    axes[0].set_ylabel("direction RMSE / CRLB")
    axes[-1].legend(fontsize=8, loc="upper right")
    fig.suptitle("Speed vs accuracy of the estimators (dashed: the Cramér-Rao bound)\n"
                 "circle K=1, square K=2, triangle K=3; hollow: most runs not converged "
                 "(chain < 50 tau, or call cap hit)", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    args = parser("speed_vs_accuracy", __doc__).parse_args()
    import xarray as xr

    fixed = {"n_sensors": 30 if args.full else 16, "intensity": 1.0, "slots": 4}
    parts = []
    for j, (est, n) in enumerate(FULL if args.full else QUICK):
        ds = study(args, f"sva-{slug(est.label)}", ring_estimate,
                   {"estimator": [est], "sigma": SIGMAS, "n_sources": KS}, n, fixed=fixed,
                   seed_offset=j, chunk_size=n if est == BATCHED else None)
        parts.append(xr.Dataset(summarise(ds)).expand_dims(estimator=[est.label]))
    summary = xr.concat(parts, "estimator", data_vars="all")
    summary.attrs.update({"n_sensors": fixed["n_sensors"], "seed": args.seed})
    rows = []
    for label in summary.estimator.values:
        for sig in SIGMAS:
            for k in KS:
                c = summary.sel({"estimator": label, "sigma": sig, "n_sources": k})
                rows.append([str(label), sig, k, int(c.n), float(c.rmse_ratio),
                             float(c.rmse_ratio_se), float(c.cpu_seconds), float(c.seconds),
                             float(c.fail), float(c.fail_ambiguous), float(c.converged)])
    text = table(["estimator", "sigma", "K", "n", "RMSE/CRLB", "se", "cpu s/est", "wall s/est",
                  "fail>5sd", "of which ll>=truth", "converged"], rows)
    print(text)
    summary.to_netcdf(args.out / "speed_vs_accuracy.nc", engine="h5netcdf")
    (args.out / "speed_vs_accuracy.txt").write_text(text + "\n")
    plot(summary, args.out / "speed_vs_accuracy.png")


if __name__ == "__main__":
    main()
