"""A trial that runs one of the package's estimators on simulated ring scenes.

:func:`ring_estimate` is one vectorised trial for every estimator, chosen by the
``estimator`` setting (an :class:`~olsbayes.studies.estimator_spec.Estimator`:
a name plus its options), so a single study can sweep estimators as a grid axis::

    run_study(ring_estimate,
              {"estimator": [Estimator("fast"), Estimator("multistart", n_starts=5)],
               "sigma": [1e-3, 1e-2]},
              n_trials=200, fixed={"n_sensors": 16, "n_sources": 2}, rng=1)

The dataset's ``estimator`` coordinate holds the canonical labels, e.g.
``"multistart(n_starts=5)"``.  Settings: ``n_sensors``, ``sigma``, ``n_sources``,
``estimator`` (default ``"fast"``) and those of
:func:`olsbayes.studies.scoring.ring_truth`; optionally ``i_max`` (intensity
prior bound of the Bayesian estimators and of ``select``, default 3 * intensity)
and ``select`` (also choose K with :func:`~olsbayes.select.select_k`, method
"laplace", reporting ``k_hat``; NaN for trials without it).  Every trial draws
only from its own Generator (the scene, its noise, then the estimator's
randomness), so results do not depend on chunking.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from ..errors import OlsBayesWarning
from ..exchange import match_sources
from ..model import Model
from ._work import trial_outputs, trial_settings, vectorized
from .estimator_spec import Estimator, as_estimator
from .grid import Setting
from .scoring import ring_truth, score
from .trials import RING_SETTINGS, ring_model

__all__ = ["ring_estimate", "OUTPUT_NAMES", "OUTPUTS"]

#: Output names of :func:`ring_estimate` besides the scores.
OUTPUT_NAMES = ("ll_gain", "seconds", "cpu_seconds", "converged", "n_evaluations", "k_hat")

#: (long_name, units) of every output of :func:`ring_estimate` (the dataset's attributes).
OUTPUTS = {
    "dir_err_rms": ("RMS over sources of the direction error", "rad"),
    "dir_crlb_rms": ("RMS over sources of the CRLB sd of the direction", "rad"),
    "dir_z2": ("mean over sources of (direction error / CRLB sd)^2", "1"),
    "int_z2": ("mean over sources of (intensity error / CRLB sd)^2", "1"),
    "max_z": ("largest |error| / CRLB sd over all parameters", "1"),
    "resolvable": ("Fisher matrix of the true scene is regular (1) or singular (0)", ""),
    "on_kink": ("a true source lies on a sub-sensor's horizon (1) or not (0)", ""),
    "ll_gain": ("log-likelihood of the estimate minus that of the truth", "nats"),
    "seconds": ("wall time per estimate", "s"),
    "cpu_seconds": ("CPU time per estimate in the trial's process", "s"),
    "converged": ("the estimator met its stopping rule (1) or not (0)", ""),
    "n_evaluations": ("likelihood or model evaluations of the estimate", ""),
    "k_hat": ("number of sources chosen by select_k (NaN: not chosen)", ""),
}


def _i_max(settings: dict) -> float:
    return float(settings.get("i_max", 3.0 * float(settings.get("intensity", 1.0))))


def _priors(model: Model, settings: dict, k: int):
    from ..priors import default_priors

    return default_priors(model, k, i_max=_i_max(settings))


def _circular_mean(model: Model, draws: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted mean of relabelled draws (S, P): circular for angles."""
    k, w = model.n_sources_of(draws), model.n_loc + 1
    d = draws.reshape(-1, k, w)
    mean = np.einsum("s,skw->kw", weights, d)
    ang = np.arctan2(weights @ np.sin(d[..., 0]), weights @ np.cos(d[..., 0]))
    mean[:, 0] = ang
    return mean.ravel()


def _one_fit(model: Model, data: np.ndarray, k: int, est: Estimator, rng) -> tuple:
    """The ML estimators ("fast", "multistart", "exact"): the one place that calls fit_ml.

    ``data`` is (N,) or, for the batched fast fit, (T, N).  Returns the fit's
    ``params``, ``converged`` and ``n_evaluations``.
    """
    from ..ml import MultistartOptions, fit_ml

    if est.name == "multistart":
        opts = MultistartOptions(n_starts=est.option("n_starts"))
        r = fit_ml(model, data, k, "multistart", options=opts, rng=rng, warn=False)
    else:
        r = fit_ml(model, data, k, est.name, warn=False)
    return r.params, r.converged, r.n_evaluations


def _posterior(model: Model, data: np.ndarray, k: int, est: Estimator, settings: dict,
               rng) -> tuple:
    """The posterior mean of an emcee run of exactly ``n_steps`` steps."""
    from ..posterior import SamplerOptions, sample

    steps = est.option("n_steps")
    opts = SamplerOptions(n_walkers=est.option("n_walkers"), max_steps=steps,
                          tau_multiple=1e9, check_every=steps)
    res = sample(model, data, k, priors=_priors(model, settings, k), options=opts, rng=rng,
                 progress=False)
    # a fixed chain length is the point here: report it in autocorrelation times
    return res.estimate, res.n_steps >= 50 * float(np.max(res.tau)), res.n_evaluations


def _nested(model: Model, data: np.ndarray, k: int, est: Estimator, settings: dict,
            rng) -> tuple:
    """The posterior mean of a dynesty run capped at ``max_calls`` likelihood calls."""
    from ..select import nested_log_evidence

    prior = _priors(model, settings, k)
    res = nested_log_evidence(lambda x: float(model.log_likelihood(x, data)), prior.ppf,
                              prior.n_params, periodic=list(range(0, 2 * k, 2)), rng=rng,
                              maxcall=est.option("max_calls"))
    best = res.samples[np.argmax(res.log_weights)]
    relab = match_sources(model, res.samples, np.broadcast_to(best, res.samples.shape))
    return _circular_mean(model, relab, np.exp(res.log_weights)), res.converged, res.n_calls


def _estimate(model: Model, data: np.ndarray, k: int, est: Estimator, settings: dict,
              rng) -> tuple:
    """One estimate (P,) of ``data`` (N,): (params, converged, n_evaluations)."""
    if est.name == "posterior":
        return _posterior(model, data, k, est, settings, rng)
    if est.name == "nested":
        return _nested(model, data, k, est, settings, rng)
    params, converged, n_evaluations = _one_fit(model, data, k, est, rng)
    return params, bool(converged), int(n_evaluations)


def _cheap(est: Estimator) -> Estimator:
    """A cheap run of the same code: one fit, at most 20 starts or steps, 1000 calls."""
    if est.name == "fast":
        return est.replace(batched=False)
    if est.name == "multistart":
        return est.replace(n_starts=min(est.option("n_starts"), 20))
    if est.name == "posterior":
        return est.replace(n_steps=min(est.option("n_steps"), 20))
    if est.name == "nested":
        return est.replace(max_calls=1000)
    return est


_WARMED: set[str] = set()


def _warm_up(model: Model, k: int, est: Estimator, settings: dict) -> None:
    """Run a cheap version of the estimator once per process, untimed, on a noiseless scene.

    A worker's first call of an estimator pays one-off costs -- imports (emcee,
    arviz, dynesty) and lazy set-up inside xarray and scipy -- that would
    otherwise be charged to the first trial's ``seconds``.  Uses its own
    Generator, so no trial's random stream is touched.
    """
    if est.name in _WARMED:
        return
    rng = np.random.default_rng(0)
    truth = ring_truth(model, settings, rng=rng)
    _estimate(model, model.response(truth), k, _cheap(est), settings, rng)
    _WARMED.add(est.name)


def _select(model: Model, data: np.ndarray, k: int, settings: dict, rng) -> int:
    from ..select import select_k

    k_max = min(k + 1, (model.n_sensors - 1) // 2)
    return int(select_k(model, data, k_max=k_max, method="laplace", rng=rng,
                        i_max=_i_max(settings), progress=False).best)


def _timed_estimates(model: Model, data: np.ndarray, k: int, est: Estimator, settings: dict,
                     rngs: list) -> tuple:
    """Estimates (T, P) of ``data`` (T, N), with their convergence, cost and timing.

    Returns the estimates, converged (T,), n_evaluations (T,), wall and CPU seconds
    per estimate (T,).
    """
    t = len(rngs)
    params = np.empty((t, 2 * k))
    conv, nev = np.zeros(t, bool), np.zeros(t, np.int64)
    secs, cpu = np.zeros(t), np.zeros(t)
    if est.name == "fast" and est.option("batched"):
        t0, c0 = time.perf_counter(), time.process_time()
        params[:], conv[:], nev[:] = _one_fit(model, data, k, est, None)
        secs[:], cpu[:] = (time.perf_counter() - t0) / t, (time.process_time() - c0) / t
        return params, conv, nev, secs, cpu
    for i, r in enumerate(rngs):
        t0, c0 = time.perf_counter(), time.process_time()
        params[i], conv[i], nev[i] = _estimate(model, data[i], k, est, settings, r)
        secs[i], cpu[i] = time.perf_counter() - t0, time.process_time() - c0
    return params, conv, nev, secs, cpu


@vectorized
@trial_outputs(**OUTPUTS)
@trial_settings(**RING_SETTINGS, slots=Setting("int", 1, 10_000), kink=Setting("bool"),
                i_max=Setting("float", high=1e12, positive=True), select=Setting("bool"),
                estimator=as_estimator)
def ring_estimate(settings: dict, *, rngs: list[np.random.Generator]) -> dict:
    """Simulate one ring scene per rng, estimate it with ``settings["estimator"]``, score it.

    Parameters
    ----------
    settings : dict
        See the module docstring; ``estimator`` is an
        :class:`~olsbayes.studies.estimator_spec.Estimator` or any spelling that
        :func:`~olsbayes.studies.estimator_spec.as_estimator` accepts.
    rngs : list of Generator
        One per trial.

    Returns
    -------
    dict of ndarray (T,)
        The scores of :func:`olsbayes.studies.scoring.score` plus ``seconds``
        (wall time per estimate; for the batched fast fit the batch time / T),
        ``cpu_seconds`` (the same in CPU time of this process: unlike wall time,
        not inflated when other processes share the cores), ``converged``,
        ``n_evaluations``, ``k_hat`` (NaN unless ``select``) and ``ll_gain``,
        log-likelihood of the estimate minus that of the truth.
    """
    est = as_estimator(settings.get("estimator", "fast"), "settings['estimator']")
    model = ring_model(settings)
    k = int(settings.get("n_sources", 1))
    truth = np.stack([ring_truth(model, settings, rng=r) for r in rngs])
    data = np.stack([model.simulate(x, rng=r) for x, r in zip(truth, rngs)])
    k_hat = np.full(len(rngs), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OlsBayesWarning)  # recorded as flags instead
        _warm_up(model, k, est, settings)
        params, conv, nev, secs, cpu = _timed_estimates(model, data, k, est, settings, rngs)
        if settings.get("select", False):
            k_hat[:] = [_select(model, d, k, settings, r) for d, r in zip(data, rngs)]
    # > 0: the estimate explains the data at least as well as the truth, so a large
    # error is the problem's ambiguity rather than the estimator's failure
    ll_gain = model.log_likelihood(params, data) - model.log_likelihood(truth, data)
    return {**score(model, params, truth), "ll_gain": ll_gain, "seconds": secs,
            "cpu_seconds": cpu, "converged": conv, "n_evaluations": nev, "k_hat": k_hat}
