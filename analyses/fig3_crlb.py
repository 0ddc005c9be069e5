"""Fig. 3 of the paper: ML error std vs the Cramér–Rao bound on a ring.

Two sources pi apart (intensities a1 = 1.0 and a2 = 0.2) on a ring of clipped-
cosine sub-sensors.  (a, b) angle and intensity error std vs noise sigma at
N = 30; (c, d) the same vs N at sigma = 0.01.  Measured points (batched
``fit_ml``, T trials per point) over the exact CRLB (inverse Fisher matrix) and
the paper's closed form Eq. 3, for both sources.  The error std is the root mean
square error about the true value (bias included), after matching estimated
to true sources (:func:`olsbayes.exchange.estimation_errors`).

``python analyses/fig3_crlb.py`` (T = 500, a minute or two) or ``--full``
(T = 4000).  Writes ``fig3_crlb.png`` and ``fig3_crlb.csv`` to ``--out``
(default ``out/fig3_crlb``) and prints the table.
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

THETA = (0.5, 0.5 + np.pi)
INTENSITY = (1.0, 0.2)
SIGMAS = (1e-3, 2e-3, 5e-3, 1e-2, 2e-2, 5e-2, 1e-1)
NS = (10, 14, 20, 30, 40, 60, 100)


def measure(n: int, sigma: float, trials: int, rng: np.random.Generator) -> list[dict]:
    """One setting: observed RMS errors, exact CRLB and Eq. 3 for both sources."""
    model = ob.Model(ob.Ring(n), sigma)
    scene = ob.Scene(directions=THETA, intensities=INTENSITY)
    truth = model.canonical(model.pack(scene))  # sorted by wrapped angle
    data = model.simulate(scene, rng=rng, size=trials)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", (ob.ConvergenceWarning, ob.MultimodalWarning))
        res = fit_ml(model, data, 2)
    err = estimation_errors(model, res.params, truth)
    rms = np.sqrt(np.mean(err**2, axis=0)).reshape(2, 2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ob.KinkWarning)
        bound = ob.crlb(model, scene.sorted()).std.reshape(2, 2)
    rows = []
    for j in range(2):
        inten = truth[2 * j + 1]
        eq3_th, eq3_i = ob.crlb_eq3(n, sigma, inten)
        rows.append(dict(
            n=n, sigma=sigma, source=f"a={inten:g}", trials=trials,
            theta_std=rms[j, 0], theta_crlb=bound[j, 0], theta_eq3=float(eq3_th),
            i_std=rms[j, 1], i_crlb=bound[j, 1], i_eq3=float(eq3_i),
            not_converged=int(np.sum(~res.converged)),
        ))
    return rows


def print_table(rows: list[dict]) -> None:
    head = (f"{'N':>4s} {'sigma':>7s} {'source':>7s} | {'th std':>9s} {'th CRLB':>9s} "
            f"{'th Eq3':>9s} {'ratio':>6s} | {'I std':>9s} {'I CRLB':>9s} {'I Eq3':>9s} "
            f"{'ratio':>6s}")
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['n']:4d} {r['sigma']:7.0e} {r['source']:>7s} | {r['theta_std']:9.2e} "
              f"{r['theta_crlb']:9.2e} {r['theta_eq3']:9.2e} "
              f"{r['theta_std'] / r['theta_crlb']:6.3f} | {r['i_std']:9.2e} "
              f"{r['i_crlb']:9.2e} {r['i_eq3']:9.2e} {r['i_std'] / r['i_crlb']:6.3f}")
    print("ratio = observed RMS error / exact CRLB (1 = efficient; sampling sd of the "
          "ratio ~ 1/sqrt(2T))")


def plot(rows: list[dict], path: Path):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(10, 8))
    panels = [("sigma", 30, "sigma"), ("n", 0.01, "N")]
    for col, (xkey, fixed, label) in enumerate(panels):
        other = "n" if xkey == "sigma" else "sigma"
        sel = [r for r in rows if r[other] == fixed]
        for row, (par, unit) in enumerate((("theta", "rad"), ("i", ""))):
            ax = axes[row, col]
            for src, colour in zip(("a=1", "a=0.2"), ("C0", "C3")):
                pts = sorted((r for r in sel if r["source"] == src), key=lambda r: r[xkey])
                x = np.array([r[xkey] for r in pts], dtype=float)
                ax.plot(x, [r[f"{par}_crlb"] for r in pts], "-", color=colour,
                        label=f"exact CRLB {src}")
                ax.plot(x, [r[f"{par}_eq3"] for r in pts], ":", color=colour, lw=2,
                        label=f"Eq. 3 {src}")
                ax.plot(x, [r[f"{par}_std"] for r in pts], "o", color=colour, mfc="none",
                        label=f"ML {src}")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel(label)
            name = "angle" if par == "theta" else "intensity"
            ax.set_ylabel(f"{name} error std {unit}".strip())
            fixed_txt = "N = 30" if xkey == "sigma" else "sigma = 0.01"
            ax.set_title(f"({'abcd'[2 * col + row]}) {name} vs {label}, {fixed_txt}")
            ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return fig


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--full", action="store_true", help="T = 4000 trials per point")
    p.add_argument("--trials", type=int, default=None)
    p.add_argument("--seed", type=int, default=3)
    p.add_argument("--out", type=Path, default=Path("out/fig3_crlb"))
    a = p.parse_args(argv)
    trials = a.trials or (4000 if a.full else 500)
    a.out.mkdir(parents=True, exist_ok=True)
    seeds = np.random.SeedSequence(a.seed).spawn(len(SIGMAS) + len(NS))
    settings = [(30, s) for s in SIGMAS] + [(n, 0.01) for n in NS]
    rows = []
    for (n, sigma), ss in tqdm(list(zip(settings, seeds)), desc="Fig. 3 settings",
                               unit=" setting", leave=False):
        rows += measure(n, sigma, trials, np.random.default_rng(ss))
    print_table(rows)
    with open(a.out / "fig3_crlb.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    plot(rows, a.out / "fig3_crlb.png")
    print(f"wrote {a.out / 'fig3_crlb.png'} and {a.out / 'fig3_crlb.csv'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
