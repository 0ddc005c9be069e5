"""Model checking: chi^2 per degree of freedom and the posterior predictive p-value.

For Gaussian noise of sd sigma the discrepancy of readings y from the response
mu(x) of a scene x is

    T(y, x) = sum_n ((y[n] - mu_n(x)) / sigma)^2,

chi^2 with N degrees of freedom at the true scene and about N - P at a fitted
one (P free parameters), so ``chi2 / dof`` near 1 means the model explains the
readings to within the noise; much larger values mean a missed source, a wrong
sigma or a wrong sensitivity law.

The posterior predictive p-value (Gelman, Meng & Stern 1996) compares, draw by
draw, the discrepancy of the observed readings with that of a replicate
``y_rep ~ p(y | x_s)`` (the ``posterior_predictive`` group):

    ppp = P(T(y_rep, x) >= T(y, x) | y),

near 1/2 for a model that fits; values near 0 flag a misfit that the posterior
itself cannot absorb.  (It is conservative: a fitted model tends to give values
closer to 1/2 than a uniform p-value would.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._general import is_general, pearson

__all__ = ["ModelCheck", "model_check", "chi_square"]

#: Draws whose responses are evaluated at once (bounds memory for large arrays).
_CHUNK = 4096


def chi_square(model, data: np.ndarray, params: np.ndarray, sigma: float | None = None
               ) -> float:
    """T(y, x) = sum_n ((y[n] - mu_n(x)) / sigma)^2 for one scene ``params`` (P_model,).

    ``sigma`` defaults to ``model.sigma``.
    """
    sd = model.sigma if sigma is None else float(sigma)
    resid = (np.asarray(data, dtype=float) - model.response(np.asarray(params, dtype=float)))
    return float(np.sum((resid / sd) ** 2))


@dataclass(frozen=True)
class ModelCheck:
    """How well a posterior explains the readings.

    Attributes
    ----------
    chi2 : float
        T(y, x_hat) at the posterior mean ``estimate`` (module notes).
    dof : int
        N - P degrees of freedom (P free parameters, sigma included when inferred).
    ppp : float
        Posterior predictive p-value of the chi^2 discrepancy, in [0, 1].
    n_draws : int
        Draws the p-value averages over.
    """

    chi2: float
    dof: int
    ppp: float
    n_draws: int

    @property
    def chi2_dof(self) -> float:
        """chi2 / dof (near 1 for a model that fits; NaN when dof <= 0)."""
        return self.chi2 / self.dof if self.dof > 0 else float("nan")

    def to_dict(self) -> dict:
        """JSON-ready dict: chi2, dof, chi2_dof, ppp, n_draws."""
        return {"chi2": self.chi2, "dof": self.dof, "chi2_dof": self.chi2_dof,
                "ppp": self.ppp, "n_draws": self.n_draws}

    def __repr__(self) -> str:
        return (f"ModelCheck(chi2/dof={self.chi2_dof:.3g} (dof {self.dof}), "
                f"ppp={self.ppp:.3g}, draws={self.n_draws})")


def _replicated(result) -> tuple[np.ndarray, np.ndarray]:
    """The draws (S, P) that have replicated readings, and those readings (S, N).

    Every draw, or every s-th where the ``posterior_predictive`` group is thinned
    (its ``draw`` labels are the posterior's).
    """
    rep = result.idata.posterior_predictive["obs"]
    where = result.idata.posterior.indexes["draw"].get_indexer(rep["draw"].values)
    x = result.samples[:, where].reshape(-1, result.n_params)
    return x, np.asarray(rep.values, dtype=float).reshape(-1, rep.shape[-1])


def model_check(result) -> ModelCheck:
    """chi^2/dof at the posterior mean and the posterior predictive p-value of a result.

    Uses the result's ``observed_data`` and ``posterior_predictive`` groups, so it
    works on a result read back from a file too.
    """
    model, prior, k = result.model, result.prior, result.n_sources
    data = np.asarray(result.idata.observed_data["obs"].values, dtype=float)
    consts = result.idata.constant_data
    n_frames = int(np.ravel(consts["n_frames"].values)[0]) if "n_frames" in consts else None
    if is_general(model, prior, n_frames is not None):
        return _general_check(result, data, n_frames)
    p_model = model.n_params(k)
    inferred = prior.noise is not None
    est = np.asarray(result.estimate, dtype=float)
    chi2 = chi_square(model, data, est[:p_model], est[-1] if inferred else None)
    x, rep = _replicated(result)
    exceed = 0
    for start in range(0, x.shape[0], _CHUNK):
        xs = x[start:start + _CHUNK]
        mu = model.response(xs[:, :p_model]) if p_model else np.zeros((xs.shape[0],
                                                                        data.shape[-1]))
        sd = xs[:, -1:] if inferred else model.sigma
        t_obs = np.sum(((data - mu) / sd) ** 2, axis=-1)
        t_rep = np.sum(((rep[start:start + _CHUNK] - mu) / sd) ** 2, axis=-1)
        exceed += int(np.sum(t_rep >= t_obs))
    return ModelCheck(chi2=chi2, dof=int(data.shape[-1] - result.n_params),
                      ppp=exceed / x.shape[0], n_draws=int(x.shape[0]))


def _general_check(result, data: np.ndarray, n_frames: int | None) -> ModelCheck:
    """:func:`model_check` with Pearson's chi^2 of the stored statistic (other noise models)."""
    model, prior = result.model, result.prior
    est = np.asarray(result.estimate, dtype=float)
    chi2 = float(pearson(model, prior, data, est, n_frames))
    x, rep = _replicated(result)
    exceed = 0
    for start in range(0, x.shape[0], _CHUNK):
        xs = x[start:start + _CHUNK]
        t_obs = pearson(model, prior, data, xs, n_frames)
        t_rep = pearson(model, prior, rep[start:start + _CHUNK], xs, n_frames)
        exceed += int(np.sum(t_rep >= t_obs))
    return ModelCheck(chi2=chi2, dof=int(data.shape[-1] - result.n_params),
                      ppp=exceed / x.shape[0], n_draws=int(x.shape[0]))
