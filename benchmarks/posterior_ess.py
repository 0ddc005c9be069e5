"""Effective samples per second of the emcee posterior, side by side in one run.

Setting of Fig. 3: a ring of N = 30 sub-sensors, sigma = 0.01, K = 2 sources pi
apart with intensities 1.0 and 0.2.  For each configuration the script reports
max R-hat, min bulk ESS over the parameters, sampling time, ESS per second and
whether the target (R-hat < 1.01 and bulk ESS >= 1000 within 5 s) was met:

* ``vectorised`` -- one log-posterior call per ensemble half-step (default);
* ``per-walker`` -- emcee calls the log-posterior once per walker;
* ``de-snooker`` -- vectorised, DEMove 0.8 + DESnookerMove 0.2 mixture;
* ``stretch`` -- vectorised, emcee's affine-invariant stretch move instead of
  the default differential-evolution move;
* ``prior-seeded`` -- vectorised, walkers drawn from the prior instead of the
  CRLB ball around the ML point (capped at ``--prior-steps``; K >= 2 chains
  from the prior often stay stuck, which is why this is never the default).

Second table (the goals, K = 1..3, ring N = 30): ``sample`` with its default
stopping rule next to plain vectorised emcee on an equivalent numpy
log-posterior (uniform intensity box, periodic angles; ``I @ max(cos(theta_k -
theta_n), 0)``), the same walkers, run for the same number of steps and timed
interleaved in CPU seconds:

* per-step overhead = CPU per step of ``sample`` / CPU per step of plain emcee
  with the same differential-evolution move -- the stepping loop with its
  convergence checks ("loop"), and the whole call with the result's assembly
  ("call"); goal <= 1.2;
* ESS per CPU second (min bulk ESS over the parameters) of ``sample`` against
  plain emcee with its default stretch move and a tight ball around the ML point
  (burn-in 5 tau discarded); goal >= 2;
* the CPU share of the R-hat checks in the stepping loop, and the share of
  plain emcee's step spent outside the log-probability (emcee's own proposal
  and bookkeeping, which both sides pay).

The ML fit that seeds the ball is timed separately (it is shared).  Times cover
the whole ``sample`` call (sampling, stop checks, relabelling, InferenceData);
a warm-up run first imports ArviZ and emcee, so no configuration pays for the
imports.  BLAS/OpenMP are limited to one thread ("one core").  Timings on a
shared machine are noisy: CPU seconds of this process are printed beside wall
seconds (the "within 5 s" target is judged on wall time; on a loaded machine
read the CPU column); compare ratios within one run.

Usage::

    python benchmarks/posterior_ess.py               # quick, one data set (~2-3 min)
    python benchmarks/posterior_ess.py --goals-only  # only the goal table (~1 min)
    python benchmarks/posterior_ess.py --full        # 5 data sets
    python benchmarks/posterior_ess.py --out out/posterior_ess
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core: set before numpy loads BLAS

import numpy as np  # noqa: E402

import olsbayes.posterior._rhat as _rhat  # noqa: E402
import olsbayes.posterior.sampler as _sampler  # noqa: E402
from olsbayes import ConvergenceWarning, Model, Ring  # noqa: E402
from olsbayes.ml import fit_ml  # noqa: E402
from olsbayes.posterior import SamplerOptions, sample  # noqa: E402
from olsbayes.priors import default_priors  # noqa: E402

TRUTH = np.array([0.3, 1.0, 0.3 + np.pi, 0.2])
SCENES = {1: np.array([0.3, 1.0]), 2: TRUTH, 3: np.array([0.3, 1.0, 2.4, 0.7, -2.0, 0.5])}
# CPU seconds of sample()'s stepping loop, its R-hat checks, plain emcee's log-probability calls
CPU = {"loop": 0.0, "rhat": 0.0, "plain_logp": 0.0}


def _timed(fn, key):
    def wrapped(*args, **kw):
        t0 = time.process_time()
        try:
            return fn(*args, **kw)
        finally:
            CPU[key] += time.process_time() - t0
    return wrapped


_rhat.RhatCheck.__call__ = _timed(_rhat.RhatCheck.__call__, "rhat")
_sampler.run_ensemble = _timed(_sampler.run_ensemble, "loop")


def plain_log_posterior(model, data, i_max):
    """Equivalent numpy log-posterior of ring sources (up to a constant), vectorised (W, P)."""
    th_n = np.arctan2(model.array.normals[:, 1], model.array.normals[:, 0])
    inv2s2 = 0.5 / model.sigma**2

    def log_prob(x):
        th, inten = x[:, 0::2], x[:, 1::2]
        inside = np.all((inten >= 0) & (inten <= i_max), axis=1)
        mu = np.einsum("wk,wkn->wn", inten, np.maximum(np.cos(th[:, :, None] - th_n), 0.0))
        r = data - mu
        return np.where(inside, -inv2s2 * np.einsum("wn,wn->w", r, r), -np.inf)

    return log_prob


def _plain_run(log_prob, start, n_steps, moves, seed, rng):
    import emcee

    log_prob = _timed(log_prob, "plain_logp")
    p0 = start + 1e-4 * rng.standard_normal((max(32, 4 * start.size), start.size))
    sampler = emcee.EnsembleSampler(p0.shape[0], start.size, log_prob, vectorize=True,
                                    moves=moves)
    sampler.random_state = np.random.RandomState(seed).get_state()
    t0 = time.process_time()
    sampler.run_mcmc(p0, n_steps, progress=False)
    return sampler, time.process_time() - t0


def _min_bulk_ess(sampler) -> float:
    import arviz as az

    tau = sampler.get_autocorr_time(tol=0)
    burn = min(int(np.ceil(5 * np.nanmax(tau))), sampler.iteration // 2)
    draws = sampler.get_chain(discard=burn).swapaxes(0, 1)  # (W, D, P)
    return float(np.min(az.ess(az.convert_to_dataset(draws), method="bulk")["x"].values))


def goals(rounds: int) -> list[str]:
    """The goal table: per-step overhead and ESS per CPU second against plain emcee."""
    import emcee

    model = Model(Ring(30), sigma=0.01)
    rows = []
    for k, truth in SCENES.items():
        data = model.simulate(truth, rng=100 + k)
        prior = default_priors(model, k, data=data)
        ml = fit_ml(model, data, k)
        log_prob = plain_log_posterior(model, data, float(prior.upper[1]))
        best = {}
        for _ in range(rounds):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ConvergenceWarning)
                CPU.update(loop=0.0, rhat=0.0)
                t0 = time.process_time()
                # the same seed every round: the same run, so its best round is comparable
                res = sample(model, data, k, priors=prior, start=ml, rng=k, progress=False)
                call = time.process_time() - t0
                ess = float(res.summary()["ess_bulk"].min())
                n = res.n_steps
                row = {"steps": n, "call": call, "loop": CPU["loop"], "rhat": CPU["rhat"],
                       "ess": ess, "converged": res.converged}
                t0 = time.process_time()
                sample(model, data, k, priors=prior, start=ml, rng=k, progress=False,
                       options=SamplerOptions(n_steps=n))
                row["fixed"] = time.process_time() - t0
            gen = np.random.default_rng(k)
            CPU["plain_logp"] = 0.0
            _, row["plain_de"] = _plain_run(log_prob, ml.params, n, emcee.moves.DEMove(), k, gen)
            row["emcee_own"] = row["plain_de"] - CPU["plain_logp"]  # emcee's bookkeeping
            stretch, row["plain_stretch"] = _plain_run(log_prob, ml.params, n, None, k, gen)
            row["plain_ess"] = _min_bulk_ess(stretch)
            for key, value in row.items():  # best (least loaded) round per quantity
                if key in ("ess", "plain_ess", "steps", "converged"):
                    best.setdefault(key, value)
                else:
                    best[key] = min(best.get(key, np.inf), value)
        rows.append((k, best))
    head = (f"{'K':>2} {'steps':>6} {'plain ms/step':>13} {'loop ms/step':>12} "
            f"{'call ms/step':>12} {'fixed ms/step':>13} {'loop x':>7} {'call x':>7} "
            f"{'R-hat share':>11} {'emcee share':>11} {'ESS/cpu-s':>9} {'plain ESS/cpu-s':>15} "
            f"{'ESS x':>6}")
    lines = ["Goals (CPU time, interleaved, best of %d rounds): per-step overhead <= 1.2x plain "
             "emcee (DE move), ESS/CPU-s >= 2x plain emcee (stretch move)" % rounds, head]
    for k, b in rows:
        n = b["steps"]
        per = {key: 1e3 * b[key] / n for key in ("plain_de", "loop", "call", "fixed")}
        loop_x, call_x = per["loop"] / per["plain_de"], per["call"] / per["plain_de"]
        ess_rate, plain_rate = b["ess"] / b["call"], b["plain_ess"] / b["plain_stretch"]
        lines.append(
            f"{k:>2} {n:>6} {per['plain_de']:13.3f} {per['loop']:12.3f} {per['call']:12.3f} "
            f"{per['fixed']:13.3f} {loop_x:7.2f} {call_x:7.2f} {b['rhat'] / b['loop']:11.2f} "
            f"{b['emcee_own'] / b['plain_de']:11.2f} {ess_rate:9.0f} {plain_rate:15.0f} "
            f"{ess_rate / plain_rate:6.2f}")
        lines.append(
            f"   K={k}: per-step overhead (loop) {loop_x:.2f}x: "
            f"{'met' if loop_x <= 1.2 else 'not met'}; (whole call) {call_x:.2f}x: "
            f"{'met' if call_x <= 1.2 else 'not met'}; ESS/CPU-s {ess_rate / plain_rate:.2f}x: "
            f"{'met' if ess_rate / plain_rate >= 2 else 'not met'}"
            + ("" if b["converged"] else " (sample did not converge)"))
    return lines


def run_case(name, model, data, prior, start, seed, **kw) -> dict:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        cpu0, wall0 = time.process_time(), time.perf_counter()
        res = sample(model, data, 2, priors=prior, start=start, options=SamplerOptions(**kw),
                     rng=seed, progress=False)
        cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    table = res.summary()
    rhat = float(table["r_hat"].max())
    ess = float(table["ess_bulk"].min())
    return {
        "config": name, "steps": res.n_steps, "tau_max": float(np.max(res.tau)),
        "r_hat_max": rhat, "ess_bulk_min": ess, "time_s": wall,
        "ess_per_s": ess / wall, "cpu_s": cpu, "ess_per_cpu_s": ess / cpu,
        "target_met": rhat < 1.01 and ess >= 1000 and wall <= 5.0,
        "target_met_cpu": rhat < 1.01 and ess >= 1000 and cpu <= 5.0,
        "converged": res.converged and not caught,
        "max_dev_sd_over_crlb": float(np.max(np.abs(table["sd"] / table["crlb"] - 1.0))),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="5 data sets instead of 1")
    parser.add_argument("--out", default="out/posterior_ess", help="output folder")
    parser.add_argument("--prior-steps", type=int, default=6000,
                        help="step cap of the prior-seeded run")
    parser.add_argument("--goals-only", action="store_true", help="only the goal table")
    parser.add_argument("--rounds", type=int, default=2, help="rounds of the goal table")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    goal_lines = goals(args.rounds)
    print("\n".join(goal_lines), flush=True)
    (out / "goals.txt").write_text("\n".join(goal_lines) + "\n")
    if args.goals_only:
        return
    model = Model(Ring(30), sigma=0.01)
    n_sets = 5 if args.full else 1
    warm = model.simulate(TRUTH, rng=999)  # warm-up: imports and caches, not timed
    sample(model, warm, 2, priors=default_priors(model, 2, i_max=2.0), start=TRUTH,
           options=SamplerOptions(n_steps=300), rng=0, progress=False).summary()
    rows = []
    for rep in range(n_sets):
        data = model.simulate(TRUTH, rng=1000 + rep)
        prior = default_priors(model, 2, i_max=2.0)
        t0 = time.perf_counter()
        ml = fit_ml(model, data, 2)
        t_ml = time.perf_counter() - t0
        centre = np.asarray(ml.params)
        cases = [
            ("vectorised", dict(start=centre)),
            ("per-walker", dict(start=centre, vectorize=False)),
            ("de-snooker", dict(start=centre, moves="de-snooker")),
            ("stretch", dict(start=centre, moves="stretch")),
            ("prior-seeded", dict(start="prior", max_steps=args.prior_steps)),
        ]
        for name, kw in cases:
            row = run_case(name, model, data, prior, seed=rep, **kw)
            row.update(data_set=rep, ml_time_s=t_ml)
            rows.append(row)
            print(f"set {rep} {name:13s} done: {row['time_s']:.2f} s", flush=True)
    _report(rows, out)


def _report(rows: list[dict], out: Path) -> None:
    cols = ["data_set", "config", "steps", "tau_max", "r_hat_max", "ess_bulk_min", "time_s",
            "ess_per_s", "cpu_s", "ess_per_cpu_s", "target_met", "target_met_cpu", "converged",
            "max_dev_sd_over_crlb", "ml_time_s"]
    lines = [",".join(cols)] + [",".join(_fmt(r[c]) for c in cols) for r in rows]
    (out / "posterior_ess.csv").write_text("\n".join(lines) + "\n")
    header = (f"{'set':>3} {'config':13s} {'steps':>6} {'tau':>6} {'R-hat':>7} {'ESS':>7} "
              f"{'time s':>7} {'ESS/s':>7} {'cpu s':>7} {'ESS/cpu-s':>9} {'target':>6} "
              f"{'cpu-tgt':>7} {'|sd/CRLB-1|':>9}")
    print(header)
    for r in rows:
        print(f"{r['data_set']:>3} {r['config']:13s} {r['steps']:>6} {r['tau_max']:>6.1f} "
              f"{r['r_hat_max']:>7.4f} {r['ess_bulk_min']:>7.0f} {r['time_s']:>7.2f} "
              f"{r['ess_per_s']:>7.0f} {r['cpu_s']:>7.2f} {r['ess_per_cpu_s']:>9.0f} "
              f"{str(r['target_met']):>6} {str(r['target_met_cpu']):>7} "
              f"{r['max_dev_sd_over_crlb']:>9.3f}")
    base = {r["data_set"]: r for r in rows if r["config"] == "vectorised"}
    print("relative to vectorised ML-seeded (same data set): ESS/s wall, ESS/s CPU")
    for r in rows:
        b = base[r["data_set"]]
        print(f"  set {r['data_set']} {r['config']:13s} {r['ess_per_s'] / b['ess_per_s']:.2f} "
              f"{r['ess_per_cpu_s'] / b['ess_per_cpu_s']:.2f}")
    print(f"ML fit (shared seed point): {np.mean([r['ml_time_s'] for r in rows]):.2f} s")
    _plot(rows, out / "posterior_ess.png")
    print(f"wrote {out / 'posterior_ess.csv'} and {out / 'posterior_ess.png'}")


def _fmt(v) -> str:
    return f"{v:.6g}" if isinstance(v, float) else str(v)


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    configs = list(dict.fromkeys(r["config"] for r in rows))
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.5), layout="constrained")
    for i, c in enumerate(configs):
        vals = [r for r in rows if r["config"] == c]
        axes[0].scatter([i] * len(vals), [r["ess_per_s"] for r in vals], color="k")
        axes[1].scatter([i] * len(vals), [r["r_hat_max"] for r in vals], color="k")
    for ax, lab in zip(axes, ("min bulk ESS per second", "max R-hat")):
        ax.set_xticks(range(len(configs)), configs, rotation=20)
        ax.set_ylabel(lab)
    axes[0].set_yscale("log")
    axes[1].axhline(1.01, color="crimson", ls="--", lw=1)
    fig.suptitle("emcee posterior, ring N=30, sigma=0.01, K=2 (Fig. 3 setting)")
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
