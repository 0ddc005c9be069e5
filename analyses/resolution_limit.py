"""When are two sources seen as two?  K selection near the resolution limit (Eq. 4).

Two equal sources (I = 1) on a ring of N = 30 sub-sensors at a uniformly random
rotation, separated by dtheta from a quarter of a sensor spacing h = 2 pi / N up
to pi / 2, noise sigma in {1e-2, 1e-4}.  For every trial the number of sources is
chosen by :func:`olsbayes.select_k` (method "laplace": Laplace evidence where it
is trusted, importance sampling over the source locations where it is not --
singular Fisher matrix, split or weak sources; K = 0, 1, 2, uniform intensity
prior U(0, 2), ties broken towards the smaller K) and the K = 2 ML fit is kept.
The ML fits inside select_k are the global optimum (``fit_ml(method="exact")``;
``--fit-method fast`` for the default method, which since it refits close and
lopsided K = 2 pairs exactly gives the same fits; its search alone had missed
the global K = 2 optimum in up to a third of fits below one spacing).
Per separation:

* P(K = 2 selected) and the median Bayes factor log Z2 - log Z1 (nats);
* the RMS angle error of the K = 2 ML fit over all trials, and over the
  resolvable placements (non-singular Fisher matrix at the true scene) next to
  the exact CRLB at the true scene (RMS over the same placements) and Eq. 4
  (theta_sd = 2 sigma / (I sqrt(N dtheta / pi)), "random guessing" for
  N dtheta / pi <= 1, i.e. below HALF a spacing); the fraction of placements
  with a singular Fisher matrix is printed;
* the separation at 50 % detection, in units of h (linear interpolation).

What to expect: with the clipped cosine two sources seen by the same
sub-sensors give exactly one cosine, so a second source shows only when a
sub-sensor's horizon (90 deg from it; on an even ring these points are h apart)
lies between the two sources -- probability min(1, dtheta / h) over random
placements, which crosses 50 % at h / 2, Eq. 4's threshold.  Detection is not
resolution: below ~2 h the Fisher matrix is singular for many placements and
the ML angles are far from the truth even when K = 2 is (rightly) chosen.

Also the false-alarm rate: K = 1 truths (I = 1), how often K = 2 is chosen
(goal <= 5 %).

Outputs in --out (default out/resolution_limit/): resolution_limit.png,
resolution_limit.csv, resolution_limit.txt.

Usage::

    python analyses/resolution_limit.py            # 100 trials per point, 500 K=1 truths
    python analyses/resolution_limit.py --quick    # 30 trials per point, 200 K=1 truths
    python analyses/resolution_limit.py --full     # 300 trials per point, 1000 K=1 truths
"""

from __future__ import annotations

import argparse
import csv
import time
import warnings
from pathlib import Path

import numpy as np
from tqdm import tqdm

from olsbayes import Model, Ring, crlb_eq4
from olsbayes.bounds import bound_covariance
from olsbayes.circular import wrap_angle
from olsbayes.errors import OlsBayesWarning
from olsbayes.select import SelectOptions, select_k

N = 30
H = 2 * np.pi / N
SIGMAS = (1e-2, 1e-4)
SEPS_H = np.array([0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 7.5])
I_MAX = 2.0


def _angle_rms(est: np.ndarray, truth: np.ndarray) -> float:
    """RMS angle error of canonical K = 2 estimates against the truth (best pairing)."""
    e = est.reshape(2, 2)[:, 0]
    t = truth.reshape(2, 2)[:, 0]
    d1 = wrap_angle(e - t)
    d2 = wrap_angle(e - t[::-1])
    return float(min(np.sqrt(np.mean(d1**2)), np.sqrt(np.mean(d2**2))))


def _crlb_theta(model: Model, x: np.ndarray) -> float:
    cov, _, singular = bound_covariance(model.fisher(x))
    return np.inf if singular.any() else float(np.sqrt(np.mean(np.diag(cov)[[0, 2]])))


def run_point(model: Model, sep: float, trials: int, seed: int, fit_method: str = "exact") -> dict:
    rng = np.random.default_rng(seed)
    det, lbf, err, bound = [], [], [], []
    for t in tqdm(range(trials), desc=f"separation {sep / H:g} h", unit=" trial", leave=False):
        th = rng.uniform(-np.pi, np.pi)
        x = model.canonical(np.array([th, 1.0, th + sep, 1.0]))
        d = model.simulate(x, rng=rng)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OlsBayesWarning)
            res = select_k(model, d, k_max=2, method="laplace", rng=rng, i_max=I_MAX,
                           options=SelectOptions(ml_method=fit_method), progress=False)
        det.append(res.best == 2)
        z1, z2 = res[1].log_evidence, res[2].log_evidence
        lbf.append(z2 - z1 if np.isfinite(z2) else -np.inf)
        err.append(_angle_rms(res[2].params, x))
        bound.append(_crlb_theta(model, x))
    bound, err = np.array(bound), np.array(err)
    ok = np.isfinite(bound)  # resolvable placements: the CRLB exists

    def rms(a):
        return float(np.sqrt(np.mean(np.square(a)))) if a.size else float("nan")

    return {
        "p_detect": float(np.mean(det)),
        "median_log_bf": float(np.median(lbf)),
        "rms_error": rms(err),
        "rms_resolvable": rms(err[ok]),
        "crlb_rms": rms(bound[ok]),
        "singular": float(np.mean(~ok)),
        "eq4": float(crlb_eq4(N, model.sigma, 1.0, sep)[0]),
    }


def false_alarms(model: Model, trials: int, seed: int, fit_method: str = "exact") -> float:
    rng = np.random.default_rng(seed)
    hits = 0
    for _ in tqdm(range(trials), desc="false alarms", unit=" trial", leave=False):
        x = np.array([rng.uniform(-np.pi, np.pi), 1.0])
        d = model.simulate(x, rng=rng)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OlsBayesWarning)
            hits += select_k(model, d, k_max=2, method="laplace", rng=rng, i_max=I_MAX,
                             options=SelectOptions(ml_method=fit_method),
                             progress=False).best == 2
    return hits / trials


def crossing(x: np.ndarray, p: np.ndarray, level: float = 0.5) -> float:
    """First x where p rises through ``level`` (linear interpolation), NaN if never."""
    for i in range(1, len(x)):
        if p[i - 1] < level <= p[i]:
            return float(x[i - 1] + (level - p[i - 1]) * (x[i] - x[i - 1]) / (p[i] - p[i - 1]))
    return float(x[0]) if p[0] >= level else float("nan")


def plot(results: dict, fig=None):
    import matplotlib.pyplot as plt

    fig = fig or plt.figure(figsize=(15, 4.6))
    ax1, ax2, ax3 = fig.subplots(1, 3)
    for sigma, rows in results.items():
        p = np.array([r["p_detect"] for r in rows])
        ax1.plot(SEPS_H, p, "o-", label=f"sigma = {sigma:g}")
        lbf = np.array([r["median_log_bf"] for r in rows])
        ax2.plot(SEPS_H, np.where(np.isfinite(lbf), lbf, np.nan), "o-", label=f"sigma = {sigma:g}")
        c = ax3.plot(SEPS_H, [r["rms_resolvable"] for r in rows], "o",
                     label=f"ML RMS, sigma={sigma:g}\n(resolvable placements)")
        col = c[0].get_color()
        ax3.plot(SEPS_H, [r["rms_error"] for r in rows], "o", mfc="none", color=col,
                 label="ML RMS, all placements")
        ax3.plot(SEPS_H, [r["crlb_rms"] for r in rows], "-", color=col,
                 label="exact CRLB (RMS, resolvable)")
        ax3.plot(SEPS_H, [r["eq4"] for r in rows], "--", color=col, label="Eq. 4")
    from matplotlib.ticker import FixedLocator, NullFormatter, ScalarFormatter

    fine = np.geomspace(SEPS_H[0], SEPS_H[-1], 200)
    ax1.plot(fine, np.minimum(1.0, fine), "k--", lw=1,
             label="P(a sub-sensor horizon lies\nbetween the sources) = sep/h")
    for ax in (ax1, ax2, ax3):
        ax.axvline(0.5, color="0.5", ls=":", lw=1)
        ax.axvline(1.0, color="0.3", ls=":", lw=1)
        ax.axvline(2.0, color="0.1", ls=":", lw=1)
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(FixedLocator([0.25, 0.5, 1, 2, 4, 7.5]))
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("separation / sensor spacing h = 2 pi / N")
    ax1.axhline(0.5, color="0.6", lw=0.8)
    ax1.set_ylabel("P(K = 2 selected)")
    ax1.set_title("detection of the second source\n(dotted: Eq. 4 threshold h/2, h, 2h)")
    ax2.set_yscale("symlog", linthresh=10)
    lo = min((r["median_log_bf"] for rows in results.values() for r in rows
              if np.isfinite(r["median_log_bf"])), default=0.0)
    ax2.set_ylim(bottom=min(-30.0, 3 * lo))  # -inf medians (singular K = 2) are not drawn
    ax2.axhline(0, color="0.6", lw=0.8)
    ax2.set_ylabel("median log Bayes factor Z2 : Z1 (nats)")
    ax2.set_title("evidence for two sources")
    ax3.set_yscale("log")
    ax3.set_ylabel("angle error std (rad)")
    ax3.set_title("K = 2 ML fit vs Eq. 4 and the exact CRLB")
    ax1.legend(fontsize=8)
    ax3.set_ylim(top=30.0)  # room for the legend above the data (errors < 1 rad)
    ax3.legend(fontsize=6.5, ncol=2, loc="upper right")
    fig.tight_layout()
    return fig


def read_csv(path: Path) -> dict:
    """Results of an earlier run, as :func:`plot` takes them."""
    out: dict = {}
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            out.setdefault(float(row["sigma"]), []).append(
                {k: float(v) for k, v in row.items() if k not in ("sigma", "sep_h", "sep_rad")})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--full", action="store_true", help="300 trials per point, 1000 K=1 truths")
    ap.add_argument("--quick", action="store_true", help="30 trials per point, 200 K=1 truths")
    ap.add_argument("--trials", type=int, default=None, help="trials per point")
    ap.add_argument("--seed", type=int, default=20260123)
    ap.add_argument("--fit-method", choices=("exact", "fast"), default="exact",
                    help="ML fits inside select_k: the global optimum (default) or the fast search")
    ap.add_argument("--out", type=Path, default=Path("out/resolution_limit"))
    ap.add_argument("--replot", action="store_true",
                    help="only redraw the figure from --out/resolution_limit.csv")
    args = ap.parse_args(argv)
    if args.replot:
        plot(read_csv(args.out / "resolution_limit.csv")).savefig(
            args.out / "resolution_limit.png", dpi=120)
        return 0
    trials = args.trials or (300 if args.full else 30 if args.quick else 100)
    n_fa = 1000 if args.full else 200 if args.quick else 500
    args.out.mkdir(parents=True, exist_ok=True)
    seeds = np.random.SeedSequence(args.seed).spawn(len(SIGMAS) * (len(SEPS_H) + 1))
    results, fa = {}, {}
    t0 = time.perf_counter()
    lines = [f"ring N={N}, two sources I=1, Laplace selection K<=2, i_max={I_MAX}, "
             f"{trials} trials per point, ML fits: {args.fit_method}"]
    for i, sigma in enumerate(SIGMAS):
        model = Model(Ring(N), sigma)
        rows = []
        for j, s in enumerate(SEPS_H):
            rows.append(run_point(model, s * H, trials, seeds[i * (len(SEPS_H) + 1) + j],
                                  args.fit_method))
            print(f"sigma={sigma:g} sep={s:g}h {rows[-1]} ({time.perf_counter() - t0:.0f} s)",
                  flush=True)
        results[sigma] = rows
        fa[sigma] = false_alarms(model, n_fa, seeds[i * (len(SEPS_H) + 1) + len(SEPS_H)],
                                 args.fit_method)
    header = ("sigma", "sep_h", "sep_rad", "p_detect", "median_log_bf", "rms_error",
              "rms_resolvable", "crlb_rms", "singular", "eq4")
    with open(args.out / "resolution_limit.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for sigma, rows in results.items():
            for s, r in zip(SEPS_H, rows):
                w.writerow([sigma, s, s * H] + [r[k] for k in header[3:]])
    lines.append(f"{'sigma':>7} {'sep/h':>6} {'P(K=2)':>7} {'med lnB21':>11} {'RMS all':>9} "
                 f"{'RMS res.':>9} {'CRLB res.':>9} {'singular':>8} {'Eq.4':>9}")
    for sigma, rows in results.items():
        for s, r in zip(SEPS_H, rows):
            lines.append(f"{sigma:7.0e} {s:6.2f} {r['p_detect']:7.2f} {r['median_log_bf']:11.1f} "
                         f"{r['rms_error']:9.3g} {r['rms_resolvable']:9.3g} {r['crlb_rms']:9.3g} "
                         f"{r['singular']:8.2f} {r['eq4']:9.3g}")
    lines.append("(RMS res., CRLB res.: RMS of the ML angle error and of the exact CRLB over the "
                 "placements whose Fisher matrix at the truth is non-singular)")
    for sigma, rows in results.items():
        x50 = crossing(SEPS_H, np.array([r["p_detect"] for r in rows]))
        lines.append(f"sigma={sigma:g}: 50% detection at {x50:.2f} sensor spacings "
                     f"({x50 * H:.4f} rad); Eq. 4 threshold N dtheta/pi = 1 is 0.50 spacings")
    for sigma, rate in fa.items():
        lines.append(f"sigma={sigma:g}: false alarms (K=2 chosen on {n_fa} K=1 truths): "
                     f"{100 * rate:.1f} % (goal <= 5 %)")
    lines.append(f"total time {time.perf_counter() - t0:.0f} s")
    text = "\n".join(lines)
    print(text)
    (args.out / "resolution_limit.txt").write_text(text + "\n")
    fig = plot(results)
    fig.savefig(args.out / "resolution_limit.png", dpi=120)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
