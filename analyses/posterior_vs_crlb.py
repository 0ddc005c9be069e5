"""Posterior width against the CRLB as the noise grows (Fig. 3 scene, ring N = 30).

For each noise level sigma the Fig. 3 scene (two sources pi apart, intensities
1.0 and 0.2) is simulated, the posterior sampled with the default ML-seeded
emcee ensemble, and every parameter's posterior sd divided by its CRLB at the
posterior mean.  At high SNR the ratio is 1 within Monte Carlo error; as sigma
grows the faint source's ratio departs from 1 and ``crlb_check`` names why
(low SNR, prior boundary, kink).  Prints a table and writes
``posterior_vs_crlb.csv`` and ``posterior_vs_crlb.png``.

Usage::

    python analyses/posterior_vs_crlb.py            # quick: 5 noise levels, 1 data set
    python analyses/posterior_vs_crlb.py --full     # 9 noise levels, 4 data sets each
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np
from tqdm import tqdm

from olsbayes import Model, OlsBayesWarning, Ring
from olsbayes.posterior import SamplerOptions, sample
from olsbayes.priors import default_priors

TRUTH = np.array([0.3, 1.0, 0.3 + np.pi, 0.2])


def one_run(sigma: float, rep: int) -> list[dict]:
    model = Model(Ring(30), sigma=sigma)
    data = model.simulate(TRUTH, rng=np.random.SeedSequence([rep, int(sigma * 1e6)]))
    prior = default_priors(model, 2, i_max=3.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", OlsBayesWarning)
        res = sample(model, data, 2, priors=prior, options=SamplerOptions(max_steps=8000),
                     rng=rep, progress=False)
    check = res.crlb_check()
    rhat = float(np.nanmax(res.summary()["r_hat"].to_numpy()))
    note = "; ".join(sorted({type(w.message).__name__ for w in caught}))
    return [{"sigma": sigma, "rep": rep, "param": n, "ratio": check.ratio[j],
             "mc_error": check.mc_error[j], "flagged": bool(check.flagged[j]),
             "reason": check.reasons[j], "converged": res.converged, "rhat": rhat,
             "warnings": note}
            for j, n in enumerate(check.names)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true")
    parser.add_argument("--out", default="out/posterior_vs_crlb")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sigmas = np.geomspace(0.003, 0.3, 9 if args.full else 5)
    reps = 4 if args.full else 1
    runs = [(float(s), rep) for s in sigmas for rep in range(reps)]
    rows = [r for s, rep in tqdm(runs, desc="posteriors", unit=" run", leave=False)
            for r in one_run(s, rep)]
    cols = ["sigma", "rep", "param", "ratio", "mc_error", "flagged", "converged", "rhat",
            "reason", "warnings"]
    text = [",".join(cols)] + [",".join(
        f"{r[c]:.6g}" if isinstance(r[c], float) else f'"{r[c]}"' if c in ("reason", "warnings")
        else str(r[c]) for c in cols) for r in rows]
    (out / "posterior_vs_crlb.csv").write_text("\n".join(text) + "\n")
    print(f"{'sigma':>7} {'rep':>3} {'param':9s} {'sd/CRLB':>8} {'+-':>6} flag  reason")
    for r in rows:
        print(f"{r['sigma']:>7.4f} {r['rep']:>3} {r['param']:9s} {r['ratio']:>8.3f} "
              f"{r['mc_error']:>6.3f} {'*' if r['flagged'] else ' ':4s}  {r['reason']}")
    _plot(rows, out / "posterior_vs_crlb.png")
    print(f"wrote {out}/posterior_vs_crlb.csv and .png")


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4), layout="constrained")
    for name in dict.fromkeys(r["param"] for r in rows):
        sel = [r for r in rows if r["param"] == name]
        ax.errorbar([r["sigma"] for r in sel], [r["ratio"] for r in sel],
                    yerr=[r["mc_error"] for r in sel], fmt="o", ms=4, label=name, alpha=0.8)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("sub-sensor noise sigma")
    ax.set_ylabel("posterior sd / CRLB")
    # the chains' R-hat on the figure: a ratio from chains that have not mixed is not
    # the posterior's
    rh = [r["rhat"] for r in rows]
    bad = len({(r["sigma"], r["rep"]) for r in rows if r["rhat"] > 1.01})
    ax.set_title("Ring N=30, Fig. 3 scene (I = 1.0 and 0.2, pi apart)\n"
                 f"largest R-hat {max(rh):.3f}, median {np.median(rh):.3f}; "
                 f"{bad} run(s) with R-hat > 1.01", fontsize=9)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
