"""Simulation-based calibration (SBC, Talts et al. 2018) of the package's posteriors.

For each replicate a scene is drawn from the prior, readings are simulated, the
posterior is sampled, and the rank of every true parameter among L posterior
draws is recorded; if the posterior is right, each rank is uniform on 0..L.
Sources are exchangeable, so truth and draws are both put in canonical order
(angles wrapped to (-pi, pi], sources sorted by angle) before ranking -- any
fixed function of the parameters is a valid SBC statistic.  The number of
sources is calibrated the same way with the randomised PIT
``P(K < K_true) + V P(K = K_true)``, V ~ U(0, 1), of the posterior over K.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import OlsBayesWarning
from ..model import Model
from ._work import trial_outputs, trial_settings
from .trials import ring_model

__all__ = ["sbc_posterior", "sbc_k", "ranks_of", "RankTest", "rank_test", "N_DRAWS"]

#: Posterior draws per replicate used for ranks (ranks lie in 0..N_DRAWS).
N_DRAWS = 99


def _prior(model: Model, settings: dict, k: int):
    from ..priors import default_priors

    return default_priors(model, k, i_max=float(settings.get("i_max", 2.0)))


def ranks_of(truth: np.ndarray, draws: np.ndarray) -> np.ndarray:
    """Rank of each truth coordinate (P,) among draws (L, P): counts of draws below it."""
    return np.sum(draws < truth, axis=0)


def _thinned(res, n: int) -> np.ndarray:
    """``n`` draws spread evenly over walkers and the post-burn chain, (n, P)."""
    s = res.samples  # (W, D, P)
    step = max(1, int(np.ceil(np.max(res.tau) / max(res.thin, 1))))
    pool = s[:, ::step].reshape(-1, s.shape[-1])
    idx = np.linspace(0, len(pool) - 1, n).round().astype(int)
    return pool[idx]


@trial_outputs(rank=("rank of the truth among the thinned draws, per parameter", ""),
               in50=("truth inside the central 50 % interval, per parameter", ""),
               in90=("truth inside the central 90 % interval, per parameter", ""),
               converged=("the sampler met its convergence criteria (1) or not (0)", ""),
               seconds=("wall time of the posterior run", "s"))
@trial_settings("n_sensors", "sigma", "n_sources", "i_max", "tau_multiple", "max_steps")
def sbc_posterior(settings: dict, *, rng: np.random.Generator) -> dict:
    """One SBC replicate of :func:`olsbayes.posterior.sample` on a ring.

    Settings: ``n_sensors``, ``sigma``, ``n_sources``, ``i_max`` (intensity prior
    Uniform(0, i_max), default 2), ``tau_multiple`` (default 50), ``max_steps``
    (default 20000).

    Returns
    -------
    dict
        ``rank`` (P,) in 0..N_DRAWS, ``in50``/``in90`` (P,) whether the truth lies in
        the central 50 % / 90 % interval of the draws, ``converged``, ``seconds``.
    """
    from ..posterior import SamplerOptions, sample

    model = ring_model(settings)
    k = int(settings.get("n_sources", 1))
    prior = _prior(model, settings, k)
    truth = prior.sample(rng=rng)
    data = model.simulate(truth, rng=rng)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OlsBayesWarning)
        opts = SamplerOptions(tau_multiple=float(settings.get("tau_multiple", 50.0)),
                              max_steps=int(settings.get("max_steps", 20000)))
        res = sample(model, data, k, priors=prior, options=opts, rng=rng, progress=False)
    draws = model.canonical(_thinned(res, N_DRAWS))
    t = model.canonical(truth)
    lo50, hi50, lo90, hi90 = np.quantile(draws, [0.25, 0.75, 0.05, 0.95], axis=0)
    return {"rank": ranks_of(t, draws), "in50": (t >= lo50) & (t <= hi50),
            "in90": (t >= lo90) & (t <= hi90), "converged": res.converged,
            "seconds": time.perf_counter() - t0}


@trial_outputs(pit=("randomised PIT of the true K under p(K | data)", "1"),
               k_true=("true number of sources", ""), k_best=("chosen number of sources", ""),
               p_true=("p(K_true | data)", "1"))
@trial_settings("n_sensors", "sigma", "k_max", "method", "i_max")
def sbc_k(settings: dict, *, rng: np.random.Generator) -> dict:
    """One SBC replicate of the posterior over K from :func:`olsbayes.select.select_k`.

    K_true is uniform on 0..``k_max`` (default 2), the scene is drawn from the
    prior of that K; returns ``pit`` (randomised PIT, uniform if calibrated),
    ``k_true``, ``k_best`` and ``p_true`` (posterior probability of K_true).
    """
    from ..select import select_k

    model = ring_model(settings)
    k_max = int(settings.get("k_max", 2))
    k_true = int(rng.integers(0, k_max + 1))
    truth = _prior(model, settings, k_true).sample(rng=rng) if k_true else np.zeros(0)
    data = model.simulate(truth, rng=rng) if k_true else model.sigma * rng.standard_normal(
        model.n_sensors)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OlsBayesWarning)
        res = select_k(model, data, k_max=k_max, method=str(settings.get("method", "laplace")),
                       rng=rng, i_max=float(settings.get("i_max", 2.0)), progress=False)
    p, ks = np.asarray(res.probabilities, float), np.asarray(res.ks)
    p_true = float(p[ks == k_true].sum())
    pit = float(p[ks < k_true].sum()) + rng.uniform() * p_true
    return {"pit": pit, "k_true": k_true, "k_best": int(res.best), "p_true": p_true}


@dataclass(frozen=True)
class RankTest:
    """Uniformity of SBC ranks of one parameter.

    Attributes
    ----------
    counts : ndarray (B,)
        Rank histogram over B equal bins of 0..L.
    chi2, p_value : float
        Pearson chi-square against the uniform and its p-value (B - 1 dof).
    ks_p_value : float
        Kolmogorov-Smirnov p-value of the (jittered) normalised ranks vs U(0, 1).
    """

    counts: np.ndarray
    chi2: float
    p_value: float
    ks_p_value: float


def rank_test(ranks: np.ndarray, n_draws: int, n_bins: int, *, rng: np.random.Generator
              ) -> RankTest:
    """Histogram + chi-square and KS tests of ranks in 0..n_draws.

    The bins are equal when n_draws + 1 is divisible by n_bins.
    """
    ranks = np.asarray(ranks, int)
    counts = np.bincount(ranks * n_bins // (n_draws + 1), minlength=n_bins)
    from scipy import stats  # on use: a quarter of the package's import time

    chi2, p = stats.chisquare(counts)
    u = (ranks + rng.uniform(size=ranks.shape)) / (n_draws + 1)
    return RankTest(counts, float(chi2), float(p), float(stats.kstest(u, "uniform").pvalue))
