"""Trial functions that run the package's estimators on simulated ring scenes.

:func:`ring_estimate` is one vectorised trial for every estimator, chosen by the
``method`` setting, so a single study can sweep methods as a grid axis:

==================  ==========================================================
``"fast"``          :func:`olsbayes.ml.fit_ml` fast method, one fit per trial
``"fast_batched"``  the same, all trials of the chunk in one batched call
``"multistart_M"``  the paper's multistart baseline with M random starts
``"exact"``         the global ML optimum by enumeration (clipped cosine, K <= 4)
``"posterior_L"``   posterior mean of an emcee run of exactly L steps
``"nested"``        posterior mean from dynesty (``maxcall`` cap, default 20000)
==================  ==========================================================

Settings: ``n_sensors``, ``sigma``, ``n_sources`` and those of
:func:`olsbayes.studies.scoring.ring_truth`; optionally ``i_max`` (intensity
prior bound of the Bayesian methods, default 3 * intensity), ``maxcall``,
``n_walkers`` and ``select`` (also choose K with :func:`~olsbayes.select.select_k`,
method "laplace", reporting ``k_hat``).  Every trial draws only from its own
Generator (the scene, its noise, then the method's randomness), so results do
not depend on chunking.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from ..errors import InputError, OlsBayesWarning
from ..exchange import match_sources
from ..geometry import Ring
from ..model import Model
from ._work import vectorized
from .scoring import ring_truth, score

__all__ = ["ring_estimate", "parse_method", "OUTPUT_NAMES"]

#: Output names of :func:`ring_estimate` besides the scores.
OUTPUT_NAMES = ("ll_gain", "seconds", "cpu_seconds", "converged", "n_evaluations", "k_hat")


def parse_method(method: str) -> tuple[str, int]:
    """Split ``"multistart_5"`` into ``("multistart", 5)``; plain names give 0."""
    name, _, num = str(method).partition("_")
    if name == "fast" and num in ("", "batched"):
        return ("fast_batched" if num else "fast"), 0
    if name in ("multistart", "posterior") and num.isdigit() and int(num) > 0:
        return name, int(num)
    if name in ("nested", "exact") and not num:
        return name, 0
    raise InputError(
        "method must be 'fast', 'fast_batched', 'multistart_M', 'exact', 'posterior_L' or "
        "'nested' "
        f"(M, L positive integers); got {method!r}"
    )


def _priors(model: Model, settings: dict, k: int):
    from ..priors import default_priors

    i_max = float(settings.get("i_max", 3.0 * float(settings.get("intensity", 1.0))))
    return default_priors(model, k, i_max=i_max)


def _circular_mean(model: Model, draws: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted mean of relabelled draws (S, P): circular for angles."""
    k, w = model.n_sources_of(draws), model.n_loc + 1
    d = draws.reshape(-1, k, w)
    mean = np.einsum("s,skw->kw", weights, d)
    ang = np.arctan2(weights @ np.sin(d[..., 0]), weights @ np.cos(d[..., 0]))
    mean[:, 0] = ang
    return mean.ravel()


def _nested(model: Model, data: np.ndarray, k: int, settings: dict, rng) -> tuple:
    from ..select import nested_log_evidence

    prior = _priors(model, settings, k)
    res = nested_log_evidence(lambda x: float(model.log_likelihood(x, data)), prior.ppf,
                              prior.n_params, periodic=list(range(0, 2 * k, 2)), rng=rng,
                              maxcall=int(settings.get("maxcall", 20000)))
    best = res.samples[np.argmax(res.log_weights)]
    relab = match_sources(model, res.samples, np.broadcast_to(best, res.samples.shape))
    est = _circular_mean(model, relab, np.exp(res.log_weights))
    return est, res.converged, res.n_calls


def _posterior(model: Model, data: np.ndarray, k: int, steps: int, settings: dict, rng) -> tuple:
    from ..posterior import SamplerOptions, sample

    opts = SamplerOptions(n_walkers=settings.get("n_walkers"), max_steps=steps,
                          tau_multiple=1e9, check_every=steps)
    res = sample(model, data, k, priors=_priors(model, settings, k), options=opts, rng=rng,
                 progress=False)
    # a fixed chain length is the point here: report it in autocorrelation times
    return res.estimate, res.n_steps >= 50 * float(np.max(res.tau)), res.n_evaluations


_WARMED: set[str] = set()


def _warm_up(model: Model, k: int, method: str, num: int, settings: dict) -> None:
    """Run ``method`` once per process, untimed, on a fixed noiseless scene.

    A worker's first call of a method pays one-off costs -- imports (emcee,
    arviz, dynesty) and lazy set-up inside xarray and scipy, seconds on a busy
    machine -- that would otherwise be charged to the first trial's ``seconds``.
    Uses its own Generator, so no trial's random stream is touched.
    """
    if method in _WARMED:
        return
    rng = np.random.default_rng(0)
    truth = ring_truth(model, settings, rng)
    cheap = {**settings, "maxcall": 1000}
    single = "fast" if method == "fast_batched" else method
    _one_fit(model, model.response(truth), k, single, min(num, 20), cheap, rng)
    _WARMED.add(method)


def _one_fit(model: Model, data: np.ndarray, k: int, method: str, num: int, settings: dict,
             rng) -> tuple:
    from ..ml import fit_ml

    if method in ("fast", "exact"):
        r = fit_ml(model, data, k, method, warn=False)
        return r.params, bool(r.converged), int(r.n_evaluations)
    if method == "multistart":
        r = fit_ml(model, data, k, "multistart", rng=rng, n_starts=num, warn=False)
        return r.params, bool(r.converged), int(r.n_evaluations)
    if method == "posterior":
        return _posterior(model, data, k, num, settings, rng)
    return _nested(model, data, k, settings, rng)


def _select(model: Model, data: np.ndarray, k: int, settings: dict, rng) -> int:
    from ..select import select_k

    i_max = float(settings.get("i_max", 3.0 * float(settings.get("intensity", 1.0))))
    k_max = min(k + 1, (model.n_sensors - 1) // 2)
    return int(select_k(model, data, k_max=k_max, method="laplace", rng=rng,
                        i_max=i_max).best)


@vectorized
def ring_estimate(settings: dict, rngs: list[np.random.Generator]) -> dict:
    """Simulate one ring scene per rng, estimate it with ``settings["method"]``, score it.

    Returns
    -------
    dict of ndarray (T,)
        The scores of :func:`olsbayes.studies.scoring.score` plus ``seconds``
        (wall time per estimate; for ``fast_batched`` the batch time / T),
        ``cpu_seconds`` (the same in CPU time of this process: unlike wall time,
        not inflated when other processes share the cores), ``converged``,
        ``n_evaluations``, ``k_hat`` (-1 unless ``select``) and ``ll_gain``,
        log-likelihood of the estimate minus that of the truth.
    """
    method, num = parse_method(settings.get("method", "fast"))
    model = Model(Ring(int(settings["n_sensors"])), float(settings["sigma"]))
    k = int(settings.get("n_sources", 1))
    t = len(rngs)
    truth = np.stack([ring_truth(model, settings, r) for r in rngs])
    data = np.stack([model.simulate(x, r) for x, r in zip(truth, rngs)])
    est = np.empty_like(truth)
    conv, nev = np.zeros(t, bool), np.zeros(t, np.int64)
    secs, cpu = np.zeros(t), np.zeros(t)
    k_hat = np.full(t, -1, np.int64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OlsBayesWarning)  # recorded as flags instead
        _warm_up(model, k, method, num, settings)
        if method == "fast_batched":
            from ..ml import fit_ml

            t0, c0 = time.perf_counter(), time.process_time()
            r = fit_ml(model, data, k, "fast", warn=False)
            secs[:], cpu[:] = (time.perf_counter() - t0) / t, (time.process_time() - c0) / t
            est[:], conv[:], nev[:] = r.params, r.converged, r.n_evaluations
        else:
            for i, r in enumerate(rngs):
                t0, c0 = time.perf_counter(), time.process_time()
                est[i], conv[i], nev[i] = _one_fit(model, data[i], k, method, num, settings, r)
                secs[i], cpu[i] = time.perf_counter() - t0, time.process_time() - c0
        if settings.get("select", False):
            k_hat[:] = [_select(model, d, k, settings, r) for d, r in zip(data, rngs)]
    # > 0: the estimate explains the data at least as well as the truth, so a large
    # error is the problem's ambiguity rather than the estimator's failure
    ll_gain = model.log_likelihood(est, data) - model.log_likelihood(truth, data)
    return {**score(model, est, truth), "ll_gain": ll_gain, "seconds": secs,
            "cpu_seconds": cpu, "converged": conv, "n_evaluations": nev, "k_hat": k_hat}
