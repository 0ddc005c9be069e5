"""Is the K = 4 efficiency threshold of the ML benchmark the near-antipodal geometry?

On an even ring the difference of opposite sub-sensors is one cosine,
s(a) - s(a + pi) = sum_k I_k cos(theta_k - a), so a pair of sources nearly pi
apart leaves a direction the data barely constrain.  This analysis measures

1. how common such pairs are: the share of four-source scenes on a ring of 30
   with a pair within 2 sensor spacings (24 deg) of antipodal, for directions
   i.i.d. uniform and for the scenes of ``k4_threshold.py`` (neighbours at
   least 60 deg apart), and the distance of the benchmark's fixed K = 4 scene
   (``benchmarks/ml_speed_accuracy.py``) from antipodal;
2. the efficiency of the exact global ML (``fit_ml(method="exact")``; CRLB
   variance / mean squared error, min over the 8 parameters; sampling sd
   ~ sqrt(2 / T)) and of LM started at the truth (a local oracle that cannot
   jump to a rival mode) at sigma = 1e-2, against that distance: scenes of
   ``k4_threshold.random_scenes`` drawn until each distance bin holds its
   share, plus the benchmark scene.

The posterior's coverage against the same distance is the antipodal group of
``calibration_map.py``.  Quick: 8 scenes per bin x 150 draws; --full: 30 x 400.
Outputs in --out: antipodal.png, antipodal.csv, antipodal.txt.
"""

from __future__ import annotations

import os
import sys

os.environ.setdefault("MPLBACKEND", "Agg")

import argparse  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from k4_threshold import BENCHMARK_ANGLES, INTENSITIES, scene_stats  # noqa: E402

import olsbayes as ob  # noqa: E402
from olsbayes._io import write_text_atomic  # noqa: E402
from olsbayes.circular import wrap_angle  # noqa: E402

__all__ = ["main", "gap_spacings", "share_near"]

N = 30
H = 2 * np.pi / N
#: Distance-from-antipodal bins (spacings).
BINS = ((0.0, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, 15.0))


def gap_spacings(theta: np.ndarray) -> np.ndarray:
    """Distance of the nearest pair from antipodal (spacings) of scenes ``theta`` (..., K)."""
    d = np.abs(wrap_angle(theta[..., :, None] - theta[..., None, :]))
    iu = np.triu_indices(theta.shape[-1], 1)
    return (np.pi - d[..., iu[0], iu[1]].max(axis=-1)) / H


def _neighbour_gap(theta: np.ndarray) -> np.ndarray:
    a = np.sort(np.mod(theta, 2 * np.pi), axis=-1)
    return np.diff(np.concatenate([a, a[..., :1] + 2 * np.pi], -1), axis=-1).min(axis=-1)


def share_near(n: int, rng: np.random.Generator, min_gap_deg: float = 0.0,
               within: float = 2.0) -> tuple[float, float, int]:
    """Share of random 4-source scenes with a pair within ``within`` spacings of antipodal.

    Directions i.i.d. uniform, kept when neighbours are >= ``min_gap_deg`` apart.
    Returns (share, its binomial se, scenes kept).
    """
    th = rng.uniform(-np.pi, np.pi, (n, 4))
    th = th[_neighbour_gap(th) >= np.radians(min_gap_deg)]
    p = float(np.mean(gap_spacings(th) < within))
    return p, float(np.sqrt(p * (1 - p) / len(th))), len(th)


def stratified_scenes(per_bin: int, min_gap_deg: float, rng: np.random.Generator) -> list:
    """``per_bin`` identifiable scenes (as ``k4_threshold.random_scenes``) in every bin."""
    model = ob.Model(ob.Ring(N), 1.0)
    out: dict[int, list] = {b: [] for b in range(len(BINS))}
    while min(len(v) for v in out.values()) < per_bin:
        th = rng.uniform(0.0, 2 * np.pi, (4096, 4))
        th = th[_neighbour_gap(th) >= np.radians(min_gap_deg)]
        for a, g in zip(th, gap_spacings(th)):
            b = next(i for i, (lo, hi) in enumerate(BINS) if lo <= g < hi)
            if len(out[b]) >= per_bin:
                continue
            scene = ob.Scene(directions=np.sort(a), intensities=rng.permutation(INTENSITIES))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ob.ResolutionWarning)
                if np.all(np.isfinite(ob.crlb(model, scene.sorted()).std)):
                    out[b].append((float(g), scene))
    return [(b, g, s) for b, v in out.items() for g, s in v]


def efficiency_rows(per_bin: int, n_draws: int, sigma: float, min_gap: float,
                    seed: int) -> list[dict]:
    ss = np.random.SeedSequence(seed)
    scene_rng, draw_rng = (np.random.default_rng(s) for s in ss.spawn(2))
    model = ob.Model(ob.Ring(N), sigma)
    rows = []
    bench = ob.Scene(directions=BENCHMARK_ANGLES, intensities=INTENSITIES)
    scenes = [(-1, float(gap_spacings(BENCHMARK_ANGLES)), bench)]
    scenes += stratified_scenes(per_bin, min_gap, scene_rng)
    for b, g, scene in scenes:
        ml, oracle, rival = scene_stats(model, scene, n_draws, draw_rng)
        rows.append(dict(bin=b, gap=g, ml_eff=ml, oracle_eff=oracle, rival=rival))
    return rows


def bin_table(rows: list[dict], n_draws: int) -> list[dict]:
    ok = 0.95 - 2 * np.sqrt(2 / n_draws)
    out = []
    for b, (lo, hi) in enumerate(BINS):
        e = np.array([r["ml_eff"] for r in rows if r["bin"] == b])
        o = np.array([r["oracle_eff"] for r in rows if r["bin"] == b])
        q = np.quantile(e, (0.1, 0.5, 0.9))
        out.append(dict(bin=f"[{lo:g}, {hi:g})", n=len(e), ml_q10=q[0], ml_median=q[1],
                        ml_q90=q[2], ml_ok=float(np.mean(e >= ok)),
                        oracle_median=float(np.median(o)), oracle_ok=float(np.mean(o >= ok))))
    return out


def plot(rows: list[dict], path: Path, sigma: float, n_draws: int) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    r = [x for x in rows if x["bin"] >= 0]
    g = np.array([x["gap"] for x in r])
    ax.scatter(g, [x["ml_eff"] for x in r], s=14, label="exact ML (global)")
    ax.scatter(g, [x["oracle_eff"] for x in r], s=10, marker="x", color="C2",
               label="LM from the truth (local oracle)")
    b = rows[0]
    ax.scatter([b["gap"]], [b["ml_eff"]], s=60, marker="*", color="C3",
               label="benchmark K = 4 scene, exact ML")
    ax.axvline(2.0, color="k", lw=0.6, ls=":")
    ax.axhline(0.95 - 2 * np.sqrt(2 / n_draws), color="k", lw=0.6, ls="--")
    ax.set_xlabel("nearest pair's distance from antipodal (sensor spacings)")
    ax.set_ylabel("efficiency (min over parameters)")
    ax.set_title(f"K = 4 on a 30-ring, sigma = {sigma:g}: ML efficiency vs antipodality",
                 fontsize=9)
    ax.set_ylim(0, 1.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--full", action="store_true", help="30 scenes per bin x 400 draws")
    p.add_argument("--sigma", type=float, default=1e-2)
    p.add_argument("--min-gap", type=float, default=60.0, help="degrees between neighbours")
    p.add_argument("--seed", type=int, default=2027)
    p.add_argument("--out", type=Path, default=Path("out/antipodal"))
    a = p.parse_args(argv)
    per_bin, n_draws = (30, 400) if a.full else (8, 150)
    a.out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(a.seed)
    lines = ["share of random 4-source scenes (ring of 30) with a pair within 2 spacings of pi:"]
    for mg in (0.0, a.min_gap):
        s, se, n = share_near(400_000, rng, mg)
        lines.append(f"  neighbours >= {mg:g} deg: {s:.3f} +- {se:.3f} ({n} scenes)")
    lines.append(f"benchmark K = 4 scene: nearest pair {gap_spacings(BENCHMARK_ANGLES):.2f} "
                 "spacings from antipodal")
    rows = efficiency_rows(per_bin, n_draws, a.sigma, a.min_gap, a.seed)
    b = rows[0]
    lines.append(f"benchmark scene at sigma {a.sigma:g}: exact ML efficiency {b['ml_eff']:.3f}, "
                 f"oracle {b['oracle_eff']:.3f}, rival share {b['rival']:.3f}")
    lines.append(f"\nexact ML efficiency by distance from antipodal (sigma {a.sigma:g}, "
                 f"{n_draws} draws per scene, 'ok' = share >= "
                 f"{0.95 - 2 * np.sqrt(2 / n_draws):.3f}):")
    for r in bin_table(rows, n_draws):
        lines.append("  " + "  ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}"
                                      for k, v in r.items()))
    text = "\n".join(lines)
    print(text)
    write_text_atomic(a.out / "antipodal.txt", text + "\n")
    keys = list(rows[0])
    write_text_atomic(a.out / "antipodal.csv", ",".join(keys) + "\n" + "\n".join(
        ",".join(str(r[k]) for k in keys) for r in rows) + "\n")
    plot(rows, a.out / "antipodal.png", a.sigma, n_draws)
    print(f"wrote {a.out / 'antipodal.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
