"""Where the ML estimate of four sources on a ring stops reaching the CRLB.

Ring of N = 30 clipped-cosine sub-sensors, K = 4 sources with neighbours at least
``--min-gap`` degrees apart (60 by default: well separated; 90 is the most a ring
allows), intensities a random order of 1.0, 0.867, 0.733, 0.6 (as in
``benchmarks/ml_speed_accuracy.py``), scenes with a singular Fisher matrix drawn
again; plus that benchmark's fixed K = 4 scene.  Per scene and noise sigma, T
data vectors are fitted by the *exact* global ML (``fit_ml(method="exact")``,
so no search failure enters) and, as a local oracle that cannot jump to a rival
mode, by LM started at the truth.  Printed and saved per sigma:

* the efficiency (CRLB variance / mean squared error, min over the 8
  parameters) of the ML, quantiles over scenes; its sampling sd is ~sqrt(2/T);
* the share of scenes whose ML efficiency is >= 0.95 - 2 sqrt(2/T) (consistent
  with an efficiency of 0.95);
* the same for the local oracle: the gap between the two is the ML's jumps to
  another linear cell of the likelihood (a rival mode), not noise around the
  truth's mode.  The oracle is also the control of the statistic: the minimum of
  8 noisy efficiencies falls below 0.95 - 2 sd for a share of the scenes even
  where the estimator is efficient;
* the share of fits off by more than 5 CRLB std whose log-likelihood is at least
  that of the truth: the data cannot tell that rival from the truth.

Why: with the clipped cosine a sub-sensor seeing two neighbouring sources reads
one sinusoid, I_j cos(a_j - t) + I_(j+1) cos(a_(j+1) - t), so the readings of an
arc fix only the sum of the two phasors; with four sources each sub-sensor
mostly sees two, the arc sums determine the four phasors only up to an
alternating shift, and that shift is fixed by the few sub-sensors near the
horizons.  Evenly spread (well-separated) scenes are the worst case.  The
threshold sigma below which the ML is efficient is therefore far lower for K = 4
than for K <= 3 on the same ring.

Run ``python analyses/k4_threshold.py`` (quick: 12 scenes x 200 draws) or
``--full`` (60 scenes x 500 draws).  Outputs in --out:
k4_threshold.png, k4_threshold.csv.
"""

from __future__ import annotations

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import argparse  # noqa: E402
import csv  # noqa: E402
import io  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

import olsbayes as ob  # noqa: E402
from olsbayes._io import write_text_atomic  # noqa: E402
from olsbayes.exchange import estimation_errors  # noqa: E402
from olsbayes.ml import fit_ml, refine_batch  # noqa: E402

SIGMAS = (1e-2, 3e-3, 1e-3, 3e-4, 1e-4)
INTENSITIES = np.linspace(1.0, 0.6, 4)
#: The fixed K = 4 scene of benchmarks/ml_speed_accuracy.py.
BENCHMARK_ANGLES = 0.37 + np.radians([0.0, 60.0, 150.0, 260.0])


def random_scenes(model: ob.Model, n: int, min_gap_deg: float,
                  rng: np.random.Generator) -> list[ob.Scene]:
    """``n`` identifiable K = 4 scenes, neighbours >= min_gap_deg apart."""
    out = []
    while len(out) < n:
        a = np.sort(rng.uniform(0.0, 2 * np.pi, 4))
        if np.diff(np.r_[a, a[0] + 2 * np.pi]).min() < np.radians(min_gap_deg):
            continue
        scene = ob.Scene(directions=a, intensities=rng.permutation(INTENSITIES))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ob.ResolutionWarning)
            if np.all(np.isfinite(ob.crlb(model, scene.sorted()).std)):
                out.append(scene)
    return out


def scene_stats(model: ob.Model, scene: ob.Scene, n_draws: int,
                rng: np.random.Generator) -> tuple[float, float, float]:
    """(ML efficiency, oracle efficiency, share of far fits at least as likely as the
    truth) of one scene: efficiencies are min over parameters."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ob.KinkWarning)
        std = ob.crlb(model, scene.sorted()).std
    truth = model.canonical(model.pack(scene))
    data = model.simulate(scene, rng=rng, size=n_draws)
    ml = fit_ml(model, data, 4, method="exact", warn=False)
    oracle = refine_batch(model, data, np.repeat(truth[None], n_draws, axis=0))
    err_ml = estimation_errors(model, ml.params, truth)
    effs = [float(np.min(std**2 / np.mean(e**2, axis=0)))
            for e in (err_ml, estimation_errors(model, oracle.x, truth))]
    far = np.any(np.abs(err_ml) > 5 * std, axis=1)
    ll_truth = model.log_likelihood(np.repeat(truth[None], n_draws, axis=0), data)
    rival = float(np.mean(far & (ml.log_likelihood >= ll_truth)))
    return effs[0], effs[1], rival


def run(n_scenes: int, n_draws: int, min_gap: float, seed: int) -> list[dict]:
    ss = np.random.SeedSequence(seed)
    scene_ss, *draw_ss = ss.spawn(1 + len(SIGMAS))
    scenes = random_scenes(ob.Model(ob.Ring(30), 1.0), n_scenes, min_gap,
                           np.random.default_rng(scene_ss))
    bench = ob.Scene(directions=BENCHMARK_ANGLES, intensities=INTENSITIES)
    ok = 0.95 - 2 * np.sqrt(2 / n_draws)
    rows = []
    for sigma, dss in zip(SIGMAS, draw_ss):
        model = ob.Model(ob.Ring(30), sigma)
        rng = np.random.default_rng(dss)
        stats = np.array([scene_stats(model, s, n_draws, rng)
                          for s in tqdm(scenes, desc=f"sigma {sigma:g}", unit=" scene",
                                        leave=False)])
        b_ml, b_or, b_riv = scene_stats(model, bench, n_draws, rng)
        q = np.quantile(stats[:, 0], (0.1, 0.25, 0.5, 0.75, 0.9))
        rows.append(dict(
            sigma=sigma, ml_q10=q[0], ml_q25=q[1], ml_median=q[2], ml_q75=q[3], ml_q90=q[4],
            ml_ok=float(np.mean(stats[:, 0] >= ok)),
            oracle_median=float(np.median(stats[:, 1])),
            oracle_ok=float(np.mean(stats[:, 1] >= ok)),
            rival_share=float(np.mean(stats[:, 2])),
            bench_ml=b_ml, bench_oracle=b_or, bench_rival=b_riv))
        print(f"done sigma = {sigma:g}", flush=True)
    return rows


def print_table(rows: list[dict], n_scenes: int, n_draws: int, min_gap: float) -> None:
    ok = 0.95 - 2 * np.sqrt(2 / n_draws)
    print(f"\nK = 4 on a 30-ring: {n_scenes} random scenes (neighbours >= {min_gap:g} deg) "
          f"x {n_draws} draws; exact global ML vs LM from the truth (local oracle)")
    print(f"efficiency = min over parameters of CRLB var / MSE (sampling sd "
          f"{np.sqrt(2 / n_draws):.3f}); 'ok' = share of scenes >= {ok:.3f}")
    head = (f"{'sigma':>7s}  {'ML eff q10/q25/median/q75/q90':32s} {'ML ok':>6s} "
            f"{'oracle med':>10s} {'oracle ok':>9s} {'rival':>6s} | bench ML / oracle / rival")
    print(head)
    print("-" * len(head))
    for r in rows:
        qs = "/".join(f"{r[k]:.2f}" for k in ("ml_q10", "ml_q25", "ml_median", "ml_q75",
                                               "ml_q90"))
        print(f"{r['sigma']:7.0e}  {qs:32s} {r['ml_ok']:6.2f} {r['oracle_median']:10.3f} "
              f"{r['oracle_ok']:9.2f} {r['rival_share']:6.3f} | {r['bench_ml']:.3f} / "
              f"{r['bench_oracle']:.3f} / {r['bench_rival']:.3f}")
    print("rival = share of fits off by > 5 CRLB std with log-likelihood >= the truth's")


def plot(rows: list[dict], path: Path, n_draws: int):
    import matplotlib.pyplot as plt

    s = np.array([r["sigma"] for r in rows])
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    ax.fill_between(s, [r["ml_q10"] for r in rows], [r["ml_q90"] for r in rows],
                    alpha=0.2, color="C0", label="exact ML, scenes 10-90 %")
    ax.fill_between(s, [r["ml_q25"] for r in rows], [r["ml_q75"] for r in rows],
                    alpha=0.35, color="C0", label="exact ML, scenes 25-75 %")
    ax.plot(s, [r["ml_median"] for r in rows], "o-", color="C0", label="exact ML, median")
    ax.plot(s, [r["oracle_median"] for r in rows], "s--", color="C2",
            label="LM from truth (oracle), median")
    ax.plot(s, [r["bench_ml"] for r in rows], "^-", color="C3",
            label="benchmark scene, exact ML")
    ax.axhline(0.95, color="k", lw=0.8, ls=":")
    ax.axhline(0.95 - 2 * np.sqrt(2 / n_draws), color="k", lw=0.6, ls="--")
    ax.set_xscale("log")
    ax.set_ylim(0, 1.25)
    ax.set_xlabel("noise sigma (intensities 0.6 - 1)")
    ax.set_ylabel("efficiency (min over parameters)")
    ax.set_title("K = 4 sources on a 30-ring: ML efficiency vs noise")
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return fig


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--full", action="store_true", help="60 scenes x 500 draws")
    p.add_argument("--scenes", type=int, default=None)
    p.add_argument("--draws", type=int, default=None)
    p.add_argument("--min-gap", type=float, default=60.0, help="degrees between neighbours")
    p.add_argument("--seed", type=int, default=2026)
    p.add_argument("--out", type=Path, default=Path("out/k4_threshold"))
    a = p.parse_args(argv)
    n_scenes = a.scenes or (60 if a.full else 12)
    n_draws = a.draws or (500 if a.full else 200)
    a.out.mkdir(parents=True, exist_ok=True)
    rows = run(n_scenes, n_draws, a.min_gap, a.seed)
    print_table(rows, n_scenes, n_draws, a.min_gap)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]))
    w.writeheader()
    w.writerows(rows)
    write_text_atomic(a.out / "k4_threshold.csv", buf.getvalue())
    plot(rows, a.out / "k4_threshold.png", n_draws)
    print(f"\nwrote {a.out / 'k4_threshold.csv'} and {a.out / 'k4_threshold.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
