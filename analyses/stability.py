"""Where each estimator fails: failure rate vs source separation and SNR, and on the kink.

Ring of N = 16 sub-sensors (spacing 2 pi / N), two sources of intensity 1 at a
uniformly random rotation, separated by 0.25 ... 4 sensor spacings (below one
spacing the Fisher matrix is singular on a ring of even N), noise sigma giving
SNR = I / sigma from 3 to 1000.  A second study puts the first source exactly
90 deg from a sub-sensor -- on the kink of the clipped cosine -- at a
separation of 4 spacings.

One failure criterion for every estimator: a trial fails when any of
  * error: some parameter is off by more than 5 CRLB std (CRLB at the truth);
    where the truth is unresolvable (infinite CRLB) the direction RMS error
    exceeds half the separation instead (the sources were not told apart);
  * non-convergence: the optimiser's stopping rule failed (ML), or the chain
    was shorter than 50 autocorrelation times (posterior of fixed length: a
    chain too short to trust counts as a failure, so its map is comparable
    with the others);
  * wrong K: Laplace-evidence selection (:func:`olsbayes.select.select_k`)
    on the same readings picked K != 2
holds.  The maps, the table and the kink panel all show this one rate; the
parts (error, non-convergence, wrong K) are printed separately.
Marked on the maps: the Eq. 4 "random guessing" limit (separation pi / N), the
ResolutionWarning region (some trial's Fisher matrix singular) and the
Laplace-trust threshold of select (2 spacings).

Outputs in --out: stability.png, stability.nc (failure rates), raw study NetCDF
files, stability.txt.
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

N = 16
SPACING = 2 * np.pi / N
SEPS = [0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0]  # in sensor spacings
SIGMAS = [1e-3, 1e-2, 3e-2, 1e-1, 3e-1]
FAST = Estimator("fast")
#: (estimator, trials per cell), in the order of the study seeds (seed offsets j, 100 + j)
QUICK = [(FAST, 20), (Estimator("multistart", n_starts=5), 4),
         (Estimator("posterior", n_steps=300), 3)]
FULL = [(FAST, 200), (Estimator("multistart", n_starts=5), 40),
        (Estimator("multistart", n_starts=20), 20), (Estimator("posterior", n_steps=300), 30),
        (Estimator("posterior", n_steps=2000), 20)]


def failures(ds) -> dict:
    """Failure indicators per trial from the scores of ring_estimate."""
    sep = ds["separation"] if "separation" in ds.coords else ds.attrs["separation"]
    res = ds["resolvable"].astype(bool)
    err = (res & (ds["max_z"] > 5)) | (~res & (ds["dir_err_rms"] > sep / 2))
    conv = ~ds["converged"].astype(bool)
    wrong = (ds["k_hat"] >= 0) & (ds["k_hat"] != 2)
    return {"fail_error": err, "fail_convergence": conv, "fail_k": wrong,
            "fail_any": err | conv | wrong,
            "fail_error_ll_ge_truth": err & (ds["ll_gain"] >= 0)}


def rates(ds):
    import xarray as xr

    f = failures(ds)
    out = xr.Dataset({k: v.mean("trial") for k, v in f.items()})
    out["unresolvable"] = (~ds["resolvable"].astype(bool)).any("trial")
    out["n"] = ds.sizes["trial"]
    return out


def plot(maps, kink, path) -> None:
    import matplotlib.pyplot as plt

    labels = list(maps.estimator.values)
    fig, axes = plt.subplots(1, len(labels) + 1, figsize=(4.3 * (len(labels) + 1), 4.2))
    snr = 1 / np.array(SIGMAS)
    for ax, label in zip(axes, labels):
        m = maps.sel({"estimator": label})
        im = ax.pcolormesh(np.arange(len(SEPS) + 1), np.arange(len(SIGMAS) + 1),
                           m.fail_any.transpose("sigma", "separation").values, vmin=0,
                           vmax=1,
                           cmap="magma_r")
        unres = m.unresolvable.transpose("sigma", "separation").values
        for (i, j) in zip(*np.nonzero(unres)):
            ax.add_patch(plt.Rectangle((j, i), 1, 1, fill=False, hatch="///", ec="0.5", lw=0))
        seps = np.array(SEPS)
        x_eq4 = np.interp(0.5, seps, np.arange(len(SEPS))) + 0.5
        x_lap = np.interp(2.0, seps, np.arange(len(SEPS))) + 0.5
        ax.axvline(x_eq4, color="c", lw=2, label="Eq. 4 limit pi/N")
        ax.axvline(x_lap, color="g", lw=1.5, ls="--", label="select: Laplace trusted from here")
        ax.set_xticks(np.arange(len(SEPS)) + 0.5, [f"{s:g}" for s in SEPS])
        ax.set_yticks(np.arange(len(SIGMAS)) + 0.5, [f"{s:.0f}" for s in snr])
        ax.set_xlabel("separation (sensor spacings 2 pi / N)")
        conv = float(m.fail_convergence.mean())
        ax.set_title(f"{label}: P(fail); non-converged {conv:.0%}", fontsize=10)
        ax.invert_yaxis()  # high SNR on top
    axes[0].set_ylabel("SNR = I / sigma")
    axes[0].legend(fontsize=7, loc="lower right")
    fig.colorbar(im, ax=axes[len(labels) - 1], fraction=0.05,
                 label="failure rate (error > 5 CRLB sd, non-converged or wrong K)")
    ax = axes[-1]
    width = 0.8 / (2 * len(labels))
    for i, label in enumerate(labels):
        for j, kk in enumerate((False, True)):
            y = kink.sel({"estimator": label, "kink": kk}).fail_any.values
            xs = np.arange(len(kink.sigma)) + (2 * i + j) * width
            ax.bar(xs, y, width, color=f"C{i}", alpha=1.0 if kk else 0.45,
                   label=f"{label}{' on kink' if kk else ''}")
            ax.plot(xs, y, "_", color=f"C{i}", ms=8)  # zero rates stay visible
    ax.set_xticks(np.arange(len(kink.sigma)) + 0.4, [f"SNR {1 / s:g}" for s in kink.sigma.values])
    ax.set_ylabel("failure rate")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title("a source on the costn kink\n(solid: KinkWarning) vs off it (pale)", fontsize=10)
    ax.legend(fontsize=7)
    fig.suptitle(f"Stability on a ring of N = {N} (hatched: Fisher matrix singular "
                 "-> ResolutionWarning)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    args = parser("stability", __doc__).parse_args()
    import xarray as xr

    maps, kinks = [], []
    for j, (est, n) in enumerate(FULL if args.full else QUICK):
        fixed = {"n_sensors": N, "n_sources": 2, "intensity": 1.0,
                 "select": True}
        ds = study(args, f"stab-{slug(est.label)}", ring_estimate,
                   {"estimator": [est], "separation": [s * SPACING for s in SEPS],
                    "sigma": SIGMAS}, n, fixed=fixed, seed_offset=j)
        maps.append(rates(ds).assign_coords(separation=SEPS))
        dk = study(args, f"stab-kink-{slug(est.label)}", ring_estimate,
                   {"estimator": [est], "kink": [False, True], "sigma": [1e-3, 1e-2, 1e-1]},
                   n, fixed={**fixed, "separation": 4 * SPACING}, seed_offset=100 + j)
        dk.attrs["separation"] = 4 * SPACING
        kinks.append(rates(dk))
        assert bool(dk["on_kink"].sel(kink=True).all()) and not bool(
            dk["on_kink"].sel(kink=False).any())
    maps = xr.concat(maps, "estimator", data_vars="all")
    kink = xr.concat(kinks, "estimator", data_vars="all")
    rows = []
    for label in maps.estimator.values:
        for sig in SIGMAS:
            r = maps.sel({"estimator": label, "sigma": sig})
            rows.append([str(label), f"{1 / sig:g}"] + [f"{v:.2f}" + ("*" if u else "")
                        for v, u in zip(r.fail_any.values, r.unresolvable.values)])
    text = ("failure rate (error > 5 CRLB std, non-converged or wrong K) vs separation in "
            "sensor spacings; * = Fisher singular in some trial\n"
            + table(["estimator", "SNR"] + [f"{s:g}" for s in SEPS], rows))
    text += "\nnon-convergence over the whole map: " + ", ".join(
        f"{m} {float(maps.sel({'estimator': m}).fail_convergence.mean()):.2f}"
        for m in maps.estimator.values)
    text += "\nwrong K (select_k, Laplace) over the map: " + ", ".join(
        f"{m} {float(maps.sel({'estimator': m}).fail_k.mean()):.2f}" for m in maps.estimator.values)
    rows = []
    for label in kink.estimator.values:
        for sig in kink.sigma.values:
            for kk in (False, True):
                r = kink.sel({"estimator": label, "sigma": sig, "kink": kk})
                rows.append([str(label), f"{1 / sig:g}", str(kk), float(r.fail_error),
                             float(r.fail_error_ll_ge_truth), float(r.fail_convergence),
                             float(r.fail_k), float(r.fail_any), int(r.n)])
    text += "\n\nsource on the costn kink (separation 4 spacings)\n" + table(
        ["estimator", "SNR", "kink", "error", "err&ll>=truth", "non-conv", "wrong K", "fail", "n"],
        rows)
    print(text)
    both = xr.merge([
        maps.rename_vars({k: "map_" + k for k in maps.data_vars}),
        kink.rename({"sigma": "kink_sigma"}).rename_vars({k: "kink_" + k for k in kink.data_vars}),
    ])
    both.attrs.update({"n_sensors": N, "separation_unit": "sensor spacings 2 pi / N",
                       "seed": args.seed})
    both.to_netcdf(args.out / "stability.nc", engine="h5netcdf")
    (args.out / "stability.txt").write_text(text + "\n")
    plot(maps, kink, args.out / "stability.png")


if __name__ == "__main__":
    main()
