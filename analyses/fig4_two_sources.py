"""Fig. 4 of the paper: two equal sources, error std vs their separation.

Ring of N = 30 clipped-cosine sub-sensors, two sources of intensity 1.0 centred
at a generic angle (0.1 rad), sigma = 1e-4, separation swept from a quarter of
the ring's sensor spacing (2 pi / N) to pi/2.  For each separation: observed RMS
error (averaged over the two sources, after matching estimates to sources) of
angle and amplitude from batched ``fit_ml``, the exact CRLB (inverse Fisher
matrix at that placement) and the paper's Eq. 4.  Estimation "breaks down"
where the Fisher matrix is singular or the observed error exceeds 1.5x the
exact CRLB.  The same data are also fitted by ``method="exact"`` (the global
optimum, by enumerating the likelihood's linear cells): the share of fast fits
that reach it ("glob") and the global ML's own RMS errors tell a search failure
from the ML estimator's breakdown.

Eq. 4's threshold N * dtheta / pi = 1 is dtheta = pi / N: half of this ring's
sensor spacing 2 pi / N.  It is the "angular separation between neighbouring
sub-sensors" only if the N sub-sensors span pi (a half circle, or counting the
spacing as pi/N on a full ring).  The measured breakdown on the full ring lies
near 1.5-2 ring spacings instead (printed below).

One placement hides how much the breakdown depends on where the pair sits
relative to the sub-sensors' horizons, so the same sweep is also run over the
distribution of placements: ``--placements`` centres uniform on the circle,
each with its own draws (fast fits).  Plotted: the median and the 10-90 %
band over placements of the RMS errors and of the CRLB (regular placements),
and, in a third panel, the share of placements whose Fisher matrix is
singular (with its 90 % binomial interval) next to that of the fixed one.

``python analyses/fig4_two_sources.py`` (T = 300 per point; 16 placements x 60
draws) or ``--full`` (T = 2000; 64 placements x 200 draws).  Writes
``fig4_two_sources.png``, ``.csv`` and ``_placements.csv`` to ``--out``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # small batched BLAS calls: threads only contend
os.environ.setdefault("MPLBACKEND", "Agg")

import argparse  # noqa: E402
import csv  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

import olsbayes as ob  # noqa: E402
from olsbayes.exchange import estimation_errors  # noqa: E402
from olsbayes.ml import fit_ml  # noqa: E402

N, SIGMA, CENTRE = 30, 1e-4, 0.1
BREAK_RATIO = 1.5


def measure(sep: float, trials: int, rng: np.random.Generator) -> dict:
    """Observed RMS errors, exact CRLB and Eq. 4 at one separation (rad)."""
    model = ob.Model(ob.Ring(N), SIGMA)
    scene = ob.Scene(directions=[CENTRE - sep / 2, CENTRE + sep / 2], intensities=[1.0, 1.0])
    truth = model.canonical(model.pack(scene))
    data = model.simulate(scene, rng=rng, size=trials)
    with warnings.catch_warnings():
        # the figure charts where these fits break down; their per-fit warnings (a
        # singular Fisher matrix, the resolution limit) would repeat it at every separation
        warnings.simplefilter("ignore", (ob.ConvergenceWarning, ob.MultimodalWarning,
                                         ob.ResolutionWarning))
        res = fit_ml(model, data, 2)
        ex = fit_ml(model, data, 2, method="exact")
    err = estimation_errors(model, res.params, truth)
    rms = np.sqrt(np.mean(err**2, axis=0)).reshape(2, 2)
    rms_ex = np.sqrt(np.mean(estimation_errors(model, ex.params, truth)**2, axis=0)).reshape(2, 2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", (ob.ResolutionWarning, ob.KinkWarning))
        bound = ob.crlb(model, scene.sorted())
    b = bound.std.reshape(2, 2)
    eq4_th, eq4_i = ob.crlb_eq4(N, SIGMA, 1.0, sep)
    row = dict(
        sep=sep, sep_spacings=sep / (2 * np.pi / N), n_dtheta_over_pi=N * sep / np.pi,
        theta_std=float(np.sqrt(np.mean(rms[:, 0] ** 2))),
        theta_crlb=float(np.sqrt(np.mean(b[:, 0] ** 2))), theta_eq4=float(eq4_th),
        i_std=float(np.sqrt(np.mean(rms[:, 1] ** 2))),
        i_crlb=float(np.sqrt(np.mean(b[:, 1] ** 2))), i_eq4=float(eq4_i),
        trials=trials, not_converged=int(np.sum(~res.converged)),
        glob=float(np.mean(res.log_likelihood >= ex.log_likelihood - 1e-6)),
        theta_std_exact=float(np.sqrt(np.mean(rms_ex[:, 0] ** 2))),
        i_std_exact=float(np.sqrt(np.mean(rms_ex[:, 1] ** 2))),
    )
    singular = not (np.isfinite(row["theta_crlb"]) and np.isfinite(row["i_crlb"]))
    ratio = np.inf if singular else max(row["theta_std"] / row["theta_crlb"],
                                        row["i_std"] / row["i_crlb"])
    row["status"] = "ok" if ratio <= BREAK_RATIO else (
        "singular Fisher" if singular else "breakdown")
    return row


def measure_placements(sep: float, n_place: int, draws: int, rng: np.random.Generator) -> dict:
    """Median and 10-90 % band over random placements (uniform centre) at separation ``sep``.

    Per placement: RMS angle / amplitude errors of ``draws`` fast fits, the exact
    CRLB (RMS over the two sources) and whether the Fisher matrix is singular.
    """
    model = ob.Model(ob.Ring(N), SIGMA)
    th_err, i_err, th_b, i_b = (np.empty(n_place) for _ in range(4))
    for j, c in enumerate(rng.uniform(-np.pi, np.pi, n_place)):
        scene = ob.Scene(directions=[c - sep / 2, c + sep / 2], intensities=[1.0, 1.0])
        truth = model.canonical(model.pack(scene))
        data = model.simulate(scene, rng=rng, size=draws)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ob.OlsBayesWarning)
            res = fit_ml(model, data, 2, warn=False)
            b = ob.crlb(model, scene.sorted()).std.reshape(2, 2)
        rms = np.sqrt(np.mean(estimation_errors(model, res.params, truth) ** 2, 0)).reshape(2, 2)
        th_err[j], i_err[j] = np.sqrt(np.mean(rms ** 2, axis=0))
        th_b[j], i_b[j] = np.sqrt(np.mean(b ** 2, axis=0))
    sing = ~(np.isfinite(th_b) & np.isfinite(i_b))
    out = dict(sep=sep, sep_spacings=sep / (2 * np.pi / N), placements=n_place, draws=draws,
               singular_share=float(sing.mean()))
    from scipy import stats

    k = int(sing.sum())
    out["singular_q05"] = float(stats.beta.ppf(0.05, k, n_place - k + 1)) if k else 0.0
    out["singular_q95"] = float(stats.beta.ppf(0.95, k + 1, n_place - k)) if k < n_place else 1.0
    for name, v in (("theta_std", th_err), ("i_std", i_err), ("theta_crlb", th_b[~sing]),
                    ("i_crlb", i_b[~sing])):
        q = np.quantile(v, (0.1, 0.5, 0.9)) if len(v) else np.full(3, np.nan)
        out.update({f"{name}_q10": q[0], f"{name}_median": q[1], f"{name}_q90": q[2]})
    return out


def breakdown_edge(rows: list[dict]) -> tuple[float | None, float | None]:
    """(largest separation that broke down, smallest efficient one above it), rad."""
    bad = [r["sep"] for r in rows if r["status"] != "ok"]
    if not bad:
        return None, None
    above = [r["sep"] for r in rows if r["status"] == "ok" and r["sep"] > max(bad)]
    return max(bad), (min(above) if above else None)


def print_table(rows: list[dict]) -> None:
    head = (f"{'sep rad':>8s} {'/spacing':>8s} {'N*d/pi':>7s} | {'th std':>9s} {'th CRLB':>9s} "
            f"{'th Eq4':>9s} | {'I std':>9s} {'I CRLB':>9s} {'I Eq4':>9s} | {'glob':>6s} "
            f"{'th exact':>9s} {'I exact':>9s} | status")
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['sep']:8.4f} {r['sep_spacings']:8.3f} {r['n_dtheta_over_pi']:7.3f} | "
              f"{r['theta_std']:9.2e} {r['theta_crlb']:9.2e} {r['theta_eq4']:9.2e} | "
              f"{r['i_std']:9.2e} {r['i_crlb']:9.2e} {r['i_eq4']:9.2e} | {r['glob']:6.3f} "
              f"{r['theta_std_exact']:9.2e} {r['i_std_exact']:9.2e} | {r['status']}")
    last_bad, edge = breakdown_edge(rows)
    spacing = 2 * np.pi / N
    if last_bad is not None:
        print(f"\nlargest breakdown separation: {last_bad:.4f} rad = "
              f"{last_bad / spacing:.2f} ring spacings (2 pi/N); "
              f"N*d/pi = {N * last_bad / np.pi:.2f}")
    if edge is not None:
        print(f"efficient from {edge:.4f} rad = {edge / spacing:.2f} ring spacings up "
              f"(observed <= {BREAK_RATIO}x exact CRLB); N*d/pi = {N * edge / np.pi:.2f}")
    print("Eq. 4 threshold N*d/pi = 1  <=>  d = pi/N = 0.5 ring spacings (2 pi/N); it is "
          "one sensor spacing only if the N sub-sensors span pi (a half ring)")
    print("glob = share of fast fits reaching the global optimum (method='exact'); "
          "'th/I exact' = RMS errors of the global ML itself")


def _placements_panel(ax, rows: list[dict], spread: list[dict]) -> None:
    import matplotlib.pyplot as plt

    xs = np.array([r["sep_spacings"] for r in spread])
    ax.fill_between(xs, [r["singular_q05"] for r in spread], [r["singular_q95"] for r in spread],
                    color="C4", alpha=0.25, label="random placements, 90 % interval")
    ax.plot(xs, [r["singular_share"] for r in spread], "o-", color="C4", ms=3,
            label="random placements")
    fixed = [0.0 if r["status"] != "singular Fisher" else 1.0 for r in rows]
    ax.plot([r["sep_spacings"] for r in rows], fixed, "s", color="k", ms=3, mfc="none",
            label=f"the one placement (centre {CENTRE} rad)")
    ax.set_xscale("log")
    ticks = [0.25, 0.5, 1, 2, 4, 7.5]
    ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
    ax.xaxis.set_minor_formatter(plt.NullFormatter())
    ax.set_xlabel("separation d / ring sensor spacing (2 pi / N)")
    ax.set_ylabel("share with a singular Fisher matrix")
    ax.set_ylim(-0.03, 1.03)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)


def print_spread(spread: list[dict]) -> None:
    """Median and 10-90 % band over random placements, and the singular share."""
    print(f"\nover {spread[0]['placements']} random placements x {spread[0]['draws']} draws:")
    print(f"{'/spacing':>8s} | {'th std q10/med/q90':>28s} | {'th CRLB med':>11s} | "
          f"{'singular share (90 % int)':>26s}")
    for r in spread:
        print(f"{r['sep_spacings']:8.3f} | {r['theta_std_q10']:8.2e} {r['theta_std_median']:9.2e} "
              f"{r['theta_std_q90']:9.2e} | {r['theta_crlb_median']:11.2e} | "
              f"{r['singular_share']:5.2f} ({r['singular_q05']:.2f}-{r['singular_q95']:.2f})")


def plot(rows: list[dict], spread: list[dict], path: Path):
    import matplotlib.pyplot as plt

    x = np.array([r["sep_spacings"] for r in rows])
    xs = np.array([r["sep_spacings"] for r in spread])
    last_bad, edge = breakdown_edge(rows)
    spacing = 2 * np.pi / N
    fig, axes = plt.subplots(1, 3, figsize=(17, 4.8))
    _placements_panel(axes[2], rows, spread)
    for ax, par, label in ((axes[0], "i", "amplitude"), (axes[1], "theta", "angle (rad)")):
        ax.fill_between(xs, [r[f"{par}_std_q10"] for r in spread],
                        [r[f"{par}_std_q90"] for r in spread], color="0.6", alpha=0.3,
                        label="ML, random placements 10-90 %")
        ax.plot(xs, [r[f"{par}_std_median"] for r in spread], "-", color="0.35", lw=1,
                label="ML, random placements median")
        ax.plot(xs, [r[f"{par}_crlb_median"] for r in spread], ":", color="C0", lw=1,
                label="CRLB, regular random placements median")
        crlb = np.array([r[f"{par}_crlb"] for r in rows])
        ax.plot(x, np.where(np.isfinite(crlb), crlb, np.nan), "-", color="C0",
                label="exact CRLB")
        ax.plot(x, [r[f"{par}_eq4"] for r in rows], "--", color="C1", label="Eq. 4")
        ok = np.array([r["status"] == "ok" for r in rows])
        obs = np.array([r[f"{par}_std"] for r in rows])
        ax.plot(x[ok], obs[ok], "o", color="k", mfc="none", label="ML (efficient)")
        ax.plot(x[~ok], obs[~ok], "x", color="C3", label="ML (breakdown / singular Fisher)")
        ax.plot(x, [r[f"{par}_std_exact"] for r in rows], ".", color="C2", ms=4,
                label="global ML (method='exact')")
        ax.axvline(0.5, color="C1", lw=0.8, ls=":",
                   label="Eq. 4 threshold N d/pi = 1 (d = pi/N)")
        if last_bad is not None:
            right = (edge if edge is not None else last_bad) / spacing
            ax.axvspan(x.min() * 0.9, np.sqrt(last_bad / spacing * right), color="C3",
                       alpha=0.08, label="measured breakdown")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ticks = [0.25, 0.5, 1, 2, 4, 7.5]
        ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
        ax.xaxis.set_minor_formatter(plt.NullFormatter())
        ax.set_xlabel("separation d / ring sensor spacing (2 pi / N)")
        top = ax.secondary_xaxis("top", functions=(lambda v: 2 * v, lambda v: v / 2))
        top.set_xlabel("N d / pi (Eq. 4's variable)")
        ax.set_ylabel(f"{label} error std")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="lower left", bbox_to_anchor=(0.0, 0.28))
    note = ("Eq. 4's threshold N d/pi = 1 is d = pi/N = half this ring's spacing 2 pi/N; it is "
            "'one sensor spacing' only if the N sub-sensors span pi (a half ring).")
    if edge is not None:
        note += (f"\nMeasured: breakdown up to {last_bad / spacing:.2f} spacings "
                 f"(N d/pi = {N * last_bad / np.pi:.1f}); ML at the exact CRLB from "
                 f"{edge / spacing:.2f} spacings (N d/pi = {N * edge / np.pi:.1f}) up.")
    fig.suptitle(f"Two sources I = 1, N = {N}, sigma = {SIGMA:g}: one placement (markers) "
                 "and random placements (bands)", y=0.99)
    fig.text(0.5, 0.005, note, ha="center", va="bottom", fontsize=8)
    fig.tight_layout(rect=(0, 0.07, 1, 0.97))
    fig.savefig(path, dpi=120)
    return fig


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--full", action="store_true", help="T = 2000 trials per separation")
    p.add_argument("--trials", type=int, default=None)
    p.add_argument("--points", type=int, default=24, help="number of separations")
    p.add_argument("--placements", type=int, default=None, help="random placements per point")
    p.add_argument("--seed", type=int, default=4)
    p.add_argument("--out", type=Path, default=Path("out/fig4_two_sources"))
    a = p.parse_args(argv)
    trials = a.trials or (2000 if a.full else 300)
    a.out.mkdir(parents=True, exist_ok=True)
    seps = np.geomspace(0.25 * 2 * np.pi / N, np.pi / 2, a.points)
    seeds = np.random.SeedSequence(a.seed).spawn(len(seps))
    rows = [measure(s, trials, np.random.default_rng(ss))
            for s, ss in tqdm(list(zip(seps, seeds)), desc="Fig. 4 separations",
                              unit=" separation", leave=False)]
    print_table(rows)
    n_place, n_draws = (a.placements or (64 if a.full else 16)), (200 if a.full else 60)
    pseeds = np.random.SeedSequence([a.seed, 1]).spawn(len(seps))
    spread = [measure_placements(s, n_place, n_draws, np.random.default_rng(ss))
              for s, ss in zip(seps, pseeds)]
    print_spread(spread)
    with open(a.out / "fig4_two_sources_placements.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(spread[0]))
        w.writeheader()
        w.writerows(spread)
    with open(a.out / "fig4_two_sources.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    plot(rows, spread, a.out / "fig4_two_sources.png")
    print(f"wrote {a.out / 'fig4_two_sources.png'} and {a.out / 'fig4_two_sources.csv'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
