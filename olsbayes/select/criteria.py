"""Cheap baselines: BIC, AIC, and PSIS-LOO over sub-sensors as a predictive check.

BIC and AIC are penalised maximum log-likelihoods, reported as pseudo-evidences
-BIC/2 = log L - (P/2) log N and -AIC/2 = log L - P (nats), so that
``exp`` of their differences are Schwarz / Akaike weights.  On *unconstrained*
ML fits they pick a spurious extra source on 5-8 % of three-source scenes (the
drop in chi^2 from an extra source is heavier-tailed than chi^2 with 2 degrees
of freedom); the ML fits used here keep intensities non-negative.

LOO: the Laplace posterior N(x^, F^-1) of every K (draws clipped to the prior's
support) gives per-sub-sensor log-likelihoods; ArviZ's PSIS-LOO (through the
helpers of :mod:`olsbayes.posterior._arviz`, the only module that calls ArviZ)
estimates the expected log predictive density of a held-out sub-sensor.  It is a
predictive cross-check, not an evidence: it does not penalise a spurious source
that fits noise as strongly.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from .._validation import as_rng, integer
from ..bounds import bound_covariance, covariance_root
from ..model import Model
from ..posterior._arviz import from_dict, loo

__all__ = ["bic", "aic", "LOOResult", "loo_compare"]


def bic(log_likelihood: float, n_params: int, n_data: int) -> float:
    """Schwarz's criterion -2 log L + P log n (smaller is better)."""
    return -2.0 * log_likelihood + n_params * math.log(n_data)


def aic(log_likelihood: float, n_params: int) -> float:
    """Akaike's criterion -2 log L + 2 P (smaller is better)."""
    return -2.0 * log_likelihood + 2.0 * n_params


@dataclass(frozen=True, eq=False)
class LOOResult:
    """PSIS-LOO per candidate K.

    Attributes
    ----------
    ks : ndarray of int (M,)
    elpd : ndarray (M,)
        Expected log pointwise predictive density (nats); NaN where the Laplace
        posterior does not exist (singular Fisher matrix).
    se : ndarray (M,)
        Its standard error.
    pareto_k : ndarray (M,)
        Largest finite Pareto shape k over sub-sensors (> 0.7: LOO unreliable;
        sub-sensors no source reaches have a constant log-likelihood and are exact).
    best : int
        K with the largest elpd.
    """

    ks: np.ndarray
    elpd: np.ndarray
    se: np.ndarray
    pareto_k: np.ndarray
    best: int


def _pointwise(model: Model, draws: np.ndarray, data: np.ndarray) -> np.ndarray:
    resid = data - model.response(draws)
    return -0.5 * (resid / model.sigma) ** 2 - math.log(model.sigma) - 0.5 * math.log(2 * math.pi)


def loo_compare(model: Model, data: np.ndarray, result, n_draws: int = 1000, *,
                rng: np.random.Generator | int | None = None) -> LOOResult:
    """PSIS-LOO of every K of a :class:`~olsbayes.select.SelectionResult`.

    Parameters
    ----------
    model : Model
    data : ndarray (N,)
        The readings the selection was run on.
    result : SelectionResult
    n_draws : int
        Draws from each K's Laplace posterior (4 chains of n_draws / 4).
    rng : Generator or seed
    """
    data = model.check_data(data)
    n_draws = integer("n_draws", n_draws, low=100)
    gen = as_rng(rng)
    elpd, se, pk = [], [], []
    for ev in result.evidences:
        if ev.k == 0:  # no parameters: leave-one-out is exact
            point = _pointwise(model, np.zeros(0), data)
            elpd.append(float(point.sum())), se.append(float(np.sqrt(point.size * point.var())))
            pk.append(0.0)
            continue
        cov, _, singular = bound_covariance(model.fisher(ev.params))
        if singular.any():
            elpd.append(np.nan), se.append(np.nan), pk.append(np.nan)
            continue
        root = covariance_root(cov)  # (multivariate_normal's eigh would mix the units)
        draws = ev.params + gen.standard_normal((n_draws, cov.shape[0])) @ root.T
        w = model.n_loc + 1
        draws[:, w - 1 :: w] = np.abs(draws[:, w - 1 :: w])  # reflect at I = 0
        point = _pointwise(model, draws, data).reshape(4, -1, data.size)
        idata = from_dict(posterior={"x": draws.reshape(4, -1, draws.shape[-1])},
                          log_likelihood={"obs": point}, observed_data={"obs": data},
                          dims={"obs": ["sensor"]})
        with warnings.catch_warnings():  # a high Pareto k is reported in the result instead
            warnings.simplefilter("ignore", UserWarning)
            out = loo(idata, pointwise=True)
        elpd.append(float(out.elpd_loo)), se.append(float(out.se))
        k_hat = np.asarray(out.pareto_k, float)
        k_hat = k_hat[np.isfinite(k_hat)]  # dark sub-sensors: constant log-lik, LOO exact
        pk.append(float(k_hat.max()) if k_hat.size else 0.0)
    elpd_a = np.array(elpd)
    best = int(result.ks[np.nanargmax(elpd_a)])
    return LOOResult(ks=np.array(result.ks), elpd=elpd_a, se=np.array(se),
                     pareto_k=np.array(pk), best=best)
