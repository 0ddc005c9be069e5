"""Counting noise, calibration and background: what the noise model changes.

A ring of N = 24 sub-sensors (clipped cosine) sees one source at theta = pi / 24
(half a spacing: every sub-sensor's horizon as far from the source as the ring
allows); its readings are Poisson counts with mean ``exposure * (I cos + dark)``.
"Counts per source" c is the expected count of the sub-sensors facing the source
(c ~ exposure * I); every sub-sensor has one dark count per frame (without any,
a sub-sensor just past a horizon expects no count at all and the Poisson bound
is dominated by such sub-sensors).  Four parts:

1. **Coverage and efficiency vs counts.**  For c in a grid, T trials of counts
   are fitted by ML under the Poisson model and under a Gaussian model of one
   unknown sigma (profiled out), the natural choice of an analysis that ignores
   the counting.  Reported: the ML efficiency CRLB^2 / MSE of theta against the
   exact Poisson CRLB (sampling sd ~ eff sqrt(2 / T)), and the coverage of the
   interval estimate +- 1.96 sd, sd the model's own Fisher bound at the
   estimate (nominal 0.95; binomial sd sqrt(0.95 0.05 / T)).
2. **CRLB vs counts and calibration uncertainty.**  The exact Poisson bound of
   theta with the gains known, and with every gain inferred under a prior
   LogNormal(0, s) (the bound with the gains marginalised: Schur complement of
   the Bayesian information), for s in {0.02, 0.05, 0.1, 0.2}.
3. **Detection threshold vs calibration.**  A known background of 100 counts
   per sub-sensor, which the gains multiply too; the source's intensity is
   varied and :func:`olsbayes.select_k` (K = 0 or 1, Laplace evidence,
   intensity prior U(0, 400)) decides; the threshold is the counts per source at
   which K = 1 is chosen in half the trials (linear interpolation), with the gains
   known (= 1) or inferred under LogNormal(0, s) (true gains drawn from it).
4. **Structure selection.**  :func:`olsbayes.select.select_structure` between
   the model without and with an inferred background (prior U(0, 2)) on Gaussian
   readings (sigma = 0.1, I = 1): the rate at which the background is chosen
   when there is none, and when it is 5 times its marginal CRLB sd.

Outputs in --out (default out/noise_models/): noise_models.png,
noise_models.txt.  Quick mode by default; --full uses 5x the trials.

Usage::

    python analyses/noise_models.py            # quick
    python analyses/noise_models.py --full
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np

import olsbayes as ob
from olsbayes.circular import wrap_angle
from olsbayes.noise import GaussianUnknown, Poisson
from olsbayes.priors import LogNormal, Uniform
from olsbayes.select import select_structure, structure_candidates

RING = ob.Ring(24)
THETA = np.pi / 24
COUNTS = (5.0, 10.0, 20.0, 50.0, 100.0, 300.0)
GAIN_SD = (0.0, 0.02, 0.05, 0.1, 0.2)


def coverage_efficiency(c: float, trials: int, seed: int) -> dict[str, float]:
    """Part 1 at ``c`` counts per source: efficiency and coverage of both models."""
    model = ob.Model(RING, noise=Poisson(c, 1.0 / c))
    x = np.array([THETA, 1.0])
    counts = model.simulate(x, rng=seed, size=trials)
    bound = float(ob.crlb(model, model.unpack(x)).direction_std[0])
    out = {"counts": c, "crlb": bound}
    gauss = model.with_noise(GaussianUnknown(float(np.sqrt(c))))
    for tag, m in (("poisson", model), ("gauss", gauss)):
        res = ob.fit_ml(m, counts, 1, rng=seed, warn=False)
        err = wrap_angle(res.params[:, 0] - THETA)
        out[f"eff_{tag}"] = bound**2 / float(np.mean(err**2))
        out[f"cov_{tag}"] = float(np.mean(np.abs(err) < 1.96 * res.std[:, 0]))
    return out


def crlb_table(counts: np.ndarray) -> np.ndarray:
    """Part 2: sd(theta) (len(GAIN_SD), len(counts)), gains known in row 0."""
    out = np.empty((len(GAIN_SD), counts.size))
    for i, s in enumerate(GAIN_SD):
        nu = ob.Nuisance(gain_prior=LogNormal(0.0, s)) if s else None
        for j, c in enumerate(counts):
            m = ob.Model(RING, noise=Poisson(float(c), 1.0 / c), nuisance=nu)
            out[i, j] = ob.crlb(m, m.unpack(np.array([THETA, 1.0]))).direction_std[0]
    return out


def detection(gain_sd: float, levels: np.ndarray, trials: int, seed: int) -> np.ndarray:
    """Part 3: P(K = 1 chosen) at each counts-per-source level."""
    prior = LogNormal(0.0, gain_sd) if gain_sd else None
    model = ob.Model(RING, noise=Poisson(1.0), nuisance=ob.Nuisance(background=100.0,
                                                                     gain_prior=prior))
    gen = np.random.default_rng(seed)
    rates = []
    for c in levels:
        wins = []
        for t in range(trials):
            gains = gen.lognormal(0.0, gain_sd, RING.n_sensors) if gain_sd else 1.0
            world = ob.Model(RING, noise=Poisson(1.0),
                             nuisance=ob.Nuisance(background=100.0, gains=gains))
            data = world.simulate(np.array([THETA, c]), rng=gen)
            wins.append(ob.select_k(model, data, 1, method="laplace", i_max=400.0,
                                    rng=t).best)
        rates.append(np.mean(np.asarray(wins) == 1))
    return np.array(rates)


def threshold(levels: np.ndarray, rates: np.ndarray) -> float:
    """Counts per source at 50 % detection (linear interpolation; nan if not crossed)."""
    above = np.nonzero(rates >= 0.5)[0]
    if above.size == 0 or above[0] == 0:
        return float("nan") if above.size == 0 else float(levels[0])
    i = above[0]
    f = (0.5 - rates[i - 1]) / (rates[i] - rates[i - 1])
    return float(levels[i - 1] + f * (levels[i] - levels[i - 1]))


def structure_rates(trials: int, seed: int) -> tuple[float, float, float]:
    """Part 4: background chosen without one, and with one of 5 CRLB sd; that sd."""
    sigma, x = 0.1, np.array([THETA, 1.0])
    cands = structure_candidates(ob.Model(RING, sigma), background=Uniform(0.0, 2.0))
    sd_b = float(ob.crlb(cands["background"], cands["plain"].unpack(x)).extra_std[0])
    rates = []
    for k, b in enumerate((0.0, 5.0 * sd_b)):
        truth = ob.Model(RING, sigma, nuisance=ob.Nuisance(background=b))
        data = truth.simulate(x, rng=seed + k, size=trials)
        rates.append(np.mean([select_structure(cands, data[t], 1, rng=t).best == "background"
                              for t in range(trials)]))
    return rates[0], rates[1], sd_b


def _figure(path: Path, cov: list[dict], counts: np.ndarray, table: np.ndarray,
            levels: np.ndarray, det: dict[float, np.ndarray]) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(14, 4))
    c = [r["counts"] for r in cov]
    for tag, label in (("poisson", "Poisson model"), ("gauss", "Gaussian, unknown sigma")):
        ax[0].plot(c, [r[f"cov_{tag}"] for r in cov], "o-", label=f"coverage, {label}")
        ax[0].plot(c, [r[f"eff_{tag}"] for r in cov], "s--", label=f"efficiency, {label}")
    ax[0].axhline(0.95, color="k", lw=0.5)
    ax[0].set(xscale="log", xlabel="counts per source", ylim=(0, 1.2),
              title="95 % interval coverage and ML efficiency")
    ax[0].legend(fontsize=7)
    for s, row in zip(GAIN_SD, table):
        ax[1].loglog(counts, row, label="gains known" if s == 0 else f"gain sd {s}")
    ax[1].set(xlabel="counts per source", ylabel="CRLB sd(theta) (rad)",
              title="bound vs counts and calibration")
    ax[1].legend(fontsize=7)
    for s, rates in det.items():
        ax[2].plot(levels, rates, "o-", label="gains known" if s == 0 else f"gain sd {s}")
    ax[2].axhline(0.5, color="k", lw=0.5)
    ax[2].set(xscale="log", xlabel="counts per source (background 100 per sensor)",
              ylabel="P(K = 1 chosen)", title="detection")
    ax[2].set_xticks(levels, [f"{c:g}" for c in levels])
    ax[2].minorticks_off()
    ax[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv: list[str] | None = None) -> None:
    """Run the four parts and write the figure and the text report."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--full", action="store_true", help="5x the trials")
    ap.add_argument("--out", type=Path, default=Path("out") / "noise_models")
    ap.add_argument("--seed", type=int, default=20260123)
    args = ap.parse_args(argv)
    scale = 5 if args.full else 1
    args.out.mkdir(parents=True, exist_ok=True)
    warnings.simplefilter("ignore", ob.errors.EvidenceWarning)
    lines = [f"noise_models ({'full' if args.full else 'quick'}), seed {args.seed}", ""]
    cov = [coverage_efficiency(c, 200 * scale, args.seed + i) for i, c in enumerate(COUNTS)]
    t = 200 * scale
    lines += [f"1. ML efficiency vs the Poisson CRLB and coverage of +-1.96 sd, T = {t} "
              f"(efficiency sd ~ sqrt(2/T) = {np.sqrt(2 / t):.3f} relative; coverage sd "
              f"{np.sqrt(0.95 * 0.05 / t):.3f})",
              "counts  CRLB(rad)  eff_Poisson  eff_Gauss  cov_Poisson  cov_Gauss"]
    lines += [f"{r['counts']:6.0f}  {r['crlb']:9.4f}  {r['eff_poisson']:11.3f}  "
              f"{r['eff_gauss']:9.3f}  {r['cov_poisson']:11.3f}  {r['cov_gauss']:9.3f}"
              for r in cov]
    counts = np.geomspace(3.0, 1000.0, 12)
    table = crlb_table(counts)
    lines += ["", "2. CRLB sd(theta) / its value with the gains known, per gain prior sd",
              "counts  " + "  ".join(f"s={s:<5}" for s in GAIN_SD[1:])]
    lines += [f"{c:6.0f}  " + "  ".join(f"{table[i, j] / table[0, j]:7.3f}"
                                         for i in range(1, len(GAIN_SD)))
              for j, c in enumerate(counts)]
    levels = np.array([2.0, 4.0, 8.0, 16.0, 32.0, 64.0])
    det = {s: detection(s, levels, 30 * scale, args.seed + 100) for s in (0.0, 0.05, 0.2)}
    lines += ["", f"3. detection on a background of 100 counts, T = {30 * scale} per level",
              "gain sd  " + "  ".join(f"{c:5.1f}" for c in levels) + "  threshold (counts)"]
    lines += [f"{s:7.2f}  " + "  ".join(f"{r:5.2f}" for r in rates)
              + f"  {threshold(levels, rates):8.2f}" for s, rates in det.items()]
    none, five, sd_b = structure_rates(100 * scale, args.seed + 200)
    lines += ["", f"4. background chosen by select_structure, T = {100 * scale}: without "
              f"background {none:.3f}; with b = 5 sd(b) = {5 * sd_b:.4f}: {five:.3f}"]
    _figure(args.out / "noise_models.png", cov, counts, table, levels, det)
    text = "\n".join(lines)
    (args.out / "noise_models.txt").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
