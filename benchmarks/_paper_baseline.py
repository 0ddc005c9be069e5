"""The paper's ML method as the paper ran it: pseudo-random starts, each refined by BFGS.

"The multi-start global optimization method with pseudo-random initial guesses and
Matlab's quasi-Newton method for finding local optima": here scipy's BFGS
(unconstrained, as Matlab's ``fminunc``; its default tolerances) on Eq. 2 with the
analytic gradient, from the starts of :func:`olsbayes.ml.multistart.random_starts`
(uniform directions, intensities uniform in [0, 2 max(data)]).  The number of starts
is the paper's one free knob: :func:`starts_for_success` measures, per setting, how
many starts reach the global optimum in a given share of data vectors.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from olsbayes.ml.multistart import random_starts

__all__ = ["bfgs_starts", "paper_fit", "starts_for_success"]


def bfgs_starts(model, s: np.ndarray, k: int, n_starts: int, grid: np.ndarray,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Every start's BFGS optimum: parameters (S, P) and log-likelihoods (S,)."""
    scale = 0.5 / model.sigma**2

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        r = s - model.response(x)
        return scale * float(r @ r), -2.0 * scale * (model.jacobian(x).T @ r)

    xs, lls = [], []
    for x0 in random_starts(model, s, k, n_starts, grid, rng=rng):
        res = minimize(fun, x0, jac=True, method="BFGS")
        xs.append(res.x)
        lls.append(float(model.log_likelihood(res.x, s)))
    return np.array(xs), np.array(lls)


def paper_fit(model, s: np.ndarray, k: int, n_starts: int, grid: np.ndarray,
              rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """The best of ``n_starts`` BFGS runs: canonical parameters (P,) and log-likelihood."""
    xs, lls = bfgs_starts(model, s, k, n_starts, grid, rng)
    best = int(np.argmax(lls))
    return model.canonical(xs[best]), float(lls[best])


def starts_for_success(hits: np.ndarray, share: float = 0.99, cap: int = 10_000) -> int:
    """Fewest starts M with mean_i [1 - (1 - p_i)^M] >= share, from per-start hits.

    ``hits`` (D, S): whether start s of data vector i reached the global optimum;
    p_i = its fraction of hits (independent starts).  ``cap`` + 1 if even ``cap``
    starts fall short (data vectors no start reached).
    """
    p = hits.mean(axis=1)
    for m in range(1, cap + 1):
        if np.mean(1.0 - (1.0 - p) ** m) >= share:
            return m
    return cap + 1
