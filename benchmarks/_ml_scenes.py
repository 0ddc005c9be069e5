"""Extra passes of benchmarks/ml_speed_accuracy.py: batch-only efficiency, random scenes."""

from __future__ import annotations

import time
import warnings

import numpy as np

import olsbayes as ob
from olsbayes.exchange import estimation_errors
from olsbayes.ml import fit_ml
from olsbayes.ml.lm import refine_batch

__all__ = ["efficiency_only", "random_scenes", "scene_study"]


def efficiency_only(settings: list, n_trials: int, seed: int) -> None:
    """Batched fast fits only, many trials: efficiency with sampling sd sqrt(2/T).

    ``settings``: (name, sigma, scene) per setting.
    """
    rng = np.random.default_rng(seed)
    print(f"\nbatch-only efficiency, T = {n_trials} (sampling sd {np.sqrt(2 / n_trials):.3f}):")
    for name, sigma, scene in settings:
        model = ob.Model(ob.Ring(30), sigma)
        truth = model.canonical(model.pack(scene))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ob.KinkWarning)
            std = ob.crlb(model, scene.sorted()).std
        data = model.simulate(scene, rng=rng, size=n_trials)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", (ob.ConvergenceWarning, ob.MultimodalWarning))
            res = fit_ml(model, data, scene.n_sources)
        err = estimation_errors(model, res.params, truth)
        eff = std**2 / np.mean(err**2, axis=0)
        fail = np.mean(np.any(np.abs(err) > 5 * std, axis=1))
        print(f"  {name:14s} eff {' '.join(f'{e:.3f}' for e in eff):48s} fail {fail:.4f}")


def random_scenes(model: ob.Model, k: int, n: int, rng: np.random.Generator,
                  min_sep_deg: float = 30.0) -> list[ob.Scene]:
    """``n`` identifiable scenes of K sources: angles uniform with neighbours at least
    ``min_sep_deg`` apart, I ~ U(0.5, 1); scenes with a singular Fisher matrix
    (e.g. a source pair on one kink configuration) are drawn again."""
    out = []
    while len(out) < n:
        a = np.sort(rng.uniform(-np.pi, np.pi, k))
        if np.diff(np.r_[a, a[0] + 2 * np.pi]).min() < np.radians(min_sep_deg):
            continue
        scene = ob.Scene(directions=a, intensities=rng.uniform(0.5, 1.0, k))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ob.ResolutionWarning)
            if np.all(np.isfinite(ob.crlb(model, scene.sorted()).std)):
                out.append(scene)
    return out


def _deciles(v: list[float]) -> str:
    return " ".join(f"{x:.3f}" for x in np.quantile(v, (0.1, 0.25, 0.5, 0.75, 0.9)))


def scene_study(k: int, sigma: float, n_scenes: int, n_trials: int, n_ms: int, n_eff: int,
                seed: int) -> str:
    """Random well-separated scenes: search reliability and per-scene efficiency.

    Per scene: ``n_trials`` fast fits and ``n_ms`` multistart fits (20 starts) of
    the same data; "reached" = within 1e-6 of the best log-likelihood any method
    or an LM run from the truth found.  Then ``n_eff`` batched fast fits per scene
    give its efficiency (min over parameters), next to that of the LM run from the
    truth -- a local ML that cannot jump to a rival mode (an oracle, not an
    estimator): the gap between the two is the ML estimator's own mode jumps.
    """
    rng = np.random.default_rng(seed)
    model = ob.Model(ob.Ring(30), sigma)
    reach_f, reach_m, t_f, t_m, eff_f, eff_o = [], [], 0.0, 0.0, [], []
    ms_rng = np.random.default_rng(rng.integers(2**63))
    scenes = random_scenes(model, k, n_scenes, rng)
    warm = model.simulate(scenes[0], rng=rng, size=2)  # plans and compiled code, for both alike
    fit_ml(model, warm, k)
    fit_ml(model, warm[0], k, method="multistart", rng=0)
    for scene in scenes:
        truth = model.canonical(model.pack(scene))
        data = model.simulate(scene, rng=rng, size=max(n_trials, n_eff))
        ref = refine_batch(model, data, np.repeat(truth[None], data.shape[0], axis=0))
        c0 = time.process_time()
        fast = fit_ml(model, data[:n_trials], k)
        t_f += time.process_time() - c0
        c0 = time.process_time()
        ms = np.array([fit_ml(model, s, k, method="multistart", rng=ms_rng).log_likelihood
                       for s in data[:n_ms]])
        t_m += time.process_time() - c0
        best = np.maximum(model.log_likelihood(ref.x[:n_trials], data[:n_trials]),
                          fast.log_likelihood)
        best[:n_ms] = np.maximum(best[:n_ms], ms)
        reach_f.append(best - fast.log_likelihood <= 1e-6)
        reach_m.append(best[:n_ms] - ms <= 1e-6)
        if n_eff:
            std = ob.crlb(model, scene.sorted()).std
            for x, acc in ((fit_ml(model, data[:n_eff], k).params, eff_f), (ref.x[:n_eff], eff_o)):
                err = estimation_errors(model, x, truth)
                acc.append(float(np.min(std**2 / np.mean(err**2, axis=0))))
    rf, rm = np.concatenate(reach_f), np.concatenate(reach_m)
    line = (f"  K={k} s={sigma:g}  {n_scenes} scenes: optimum reached fast {rf.mean():.4f} "
            f"({rf.size} fits, {1e3 * t_f / rf.size:.3f} ms/fit in batches of {n_trials}), "
            f"multistart-20 {rm.mean():.4f} "
            f"({rm.size} fits, {1e3 * t_m / max(rm.size, 1):.2f} ms/fit)")
    if n_eff:
        ok = 0.95 - 2 * np.sqrt(2 / n_eff)
        line += (f"\n        min efficiency over scenes (quantiles 10/25/50/75/90 %, T={n_eff}): "
                 f"fast {_deciles(eff_f)} | LM from truth {_deciles(eff_o)}; "
                 f"scenes >= 0.95 - 2 sd: "
                 f"fast {np.mean(np.array(eff_f) >= ok):.2f}, LM from truth "
                 f"{np.mean(np.array(eff_o) >= ok):.2f}")
    return line
