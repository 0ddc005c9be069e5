"""Public entry point :func:`fit_ml`: validation, dispatch and the result."""

from __future__ import annotations

import warnings

import numpy as np

from .._validation import as_rng, integer, positive_float
from ..bounds import SINGULAR_RTOL, bound_covariance
from ..errors import ConvergenceWarning, InputError, MultimodalWarning
from ..model import Model
from .batch import LMOutcome
from .exact import fit_exact
from .fast import fit_fast
from .grid import cached_default_grid, check_grid
from .multistart import fit_multistart
from .result import MLResult
from .rivals import DISTINCT_STD, RIVAL_WARN, rival_gap
from .scaling import reading_scales, rescale, scaled_model

__all__ = ["fit_ml", "METHODS"]

#: Accepted values of ``method``.
METHODS = ("fast", "multistart", "exact")


def _check(model: object, data: object, n_sources: object, method: object) -> tuple:
    if not isinstance(model, Model):
        raise InputError(f"model must be an olsbayes.Model; got {type(model).__name__}")
    arr = model.check_data(data)
    if arr.ndim not in (1, 2):
        raise InputError(
            f"data must have shape (N,) or (T, N) with N = {model.n_sensors}; got {arr.shape}"
        )
    k_max = model.n_sensors // (model.n_loc + 1)
    k = integer("n_sources", n_sources, low=1, high=max(k_max, 1))
    if model.n_params(k) > model.n_sensors:
        raise InputError(
            f"n_sources must be in [1, {k_max}] (K * {model.n_loc + 1} parameters must not "
            f"exceed N = {model.n_sensors} readings); got {k}"
        )
    if method not in METHODS:
        raise InputError(f"method must be one of {METHODS}; got {method!r}")
    return arr, k


def _covariances(model: Model, x: np.ndarray, fisher: np.ndarray | None = None) -> np.ndarray:
    """Inverse Fisher matrices (T, P, P) at the estimates x (T, P), batched: the rule
    of :func:`olsbayes.bounds.bound_covariance`.  ``fisher``: the Fisher matrices at x
    if already known."""
    return bound_covariance(model.fisher(x) if fisher is None else fisher)[0]


def fit_ml(
    model: Model,
    data: np.ndarray,
    n_sources: int,
    method: str = "fast",
    rng: np.random.Generator | int | None = None,
    *,
    grid: np.ndarray | None = None,
    n_starts: int = 20,
    n_restarts: int = 4,
    restart_scale: float = 3.0,
    n_coarse: int | None = None,
    max_iter: int | None = None,
    warn: bool = True,
) -> MLResult:
    """Maximum-likelihood fit of ``n_sources`` sources (Eq. 2), one or many data vectors.

    Parameters
    ----------
    model : Model
        Forward model (array, noise sigma, sensitivity law); ring, sphere or plate.
    data : array_like, shape (N,) or (T, N)
        Readings.  A 2-D array fits T independent data vectors in one vectorised call.
    n_sources : int
        Number K of sources, 1 <= K and K (d + 1) <= N.
    method : {"fast", "multistart", "exact"}
        ``"fast"``: grid matching pursuit + alternating projection and the best
        K-tuples of coarse atom subsets (K = 4: the tuples only; polynomial in K),
        joint bounded Levenberg–Marquardt, ``n_restarts`` deterministic perturbed
        restarts and (ring/planar arrays, K >= 2) one round of kink hops into the
        neighbouring smooth cells of the likelihood; batched over trials.
        ``"multistart"``: the paper's baseline, ``n_starts`` pseudo-random starts
        each refined by L-BFGS-B.
        ``"exact"``: the global optimum by enumerating the likelihood's linear
        cells (:func:`olsbayes.ml.exact.fit_exact`); rings with the clipped
        cosine and K <= 4 only.  On a 30-ring ~0.19 ms per fit at K = 2, ~1.1 ms
        at K = 3, ~15 ms at K = 4 (per data vector in a batch of 20: 0.02, 0.21,
        2.6 ms): a reference, and for close sources at K = 4 (at K = 2, 3 the fast method
        already refits fits with close or lopsided sources this way,
        :mod:`olsbayes.ml.pairs`).  Its
        ``n_evaluations`` counts the configurations solved.
    rng : Generator, int or None
        Randomness of the multistart starts.  ``"fast"`` is deterministic and
        ignores it.
    grid : array_like, shape (M, d), optional
        Candidate source locations for the search (default
        :func:`olsbayes.ml.grid.default_grid`); also the box of multistart
        positions on a plate.
    n_starts : int
        Multistart: number of random starts (the paper's method; 20 by default).
    n_restarts, restart_scale : int, float
        Fast: number of perturbed restarts and their size in grid steps.
    n_coarse : int, optional
        Fast, K >= 2: number of differently placed coarse atom subsets searched
        exhaustively over K-tuples (each adds one candidate start; 0 = pursuit only,
        which at K = 4 then runs too).
        Default 3 for K <= 3 and 24 from K = 4 on, where three left 6-7 % of fits
        of random scenes short of the global optimum
        (:func:`olsbayes.ml.fast.default_coarse`).
    max_iter : int, optional
        Iteration cap of each local optimisation (default 300 for LM, 500 for L-BFGS-B).
    warn : bool
        Warn :class:`~olsbayes.errors.ConvergenceWarning` when a fit did not converge,
        :class:`~olsbayes.errors.MultimodalWarning` when a distinct local optimum is
        within 3 of a fit's log-likelihood (``MLResult.rival_gap``).

    Returns
    -------
    MLResult
        Canonical-order estimates, log-likelihood, convergence flags, evaluation
        counts and the inverse-Fisher covariance at each estimate.

    Raises
    ------
    InputError
        Bad model, data (wrong length, non-finite, more than 2-D), n_sources, method,
        grid or option values.
    """
    arr, k = _check(model, data, n_sources, method)
    # the fast method ignores rng: validate one given, but draw no OS entropy for None
    gen = as_rng(rng) if method == "multistart" or rng is not None else None
    g = cached_default_grid(model) if grid is None else check_grid(model, grid)
    batch = arr.ndim == 2
    s = arr if batch else arr[None, :]
    scale = reading_scales(s)  # readings far from order 1: fitted in scaled units
    scaled = bool(np.any(scale != 1.0))
    s_in = s / scale[:, None] if scaled else s
    if method == "fast":
        n_restarts = integer("n_restarts", n_restarts, low=0, high=64)
        restart_scale = positive_float("restart_scale", restart_scale)
        it = 300 if max_iter is None else integer("max_iter", max_iter, low=1)
        if n_coarse is not None:
            n_coarse = integer("n_coarse", n_coarse, low=0, high=64)
        out = fit_fast(model, s_in, k, g, n_restarts=n_restarts, restart_scale=restart_scale,
                       n_coarse=n_coarse, max_iter=it)
    elif method == "exact":
        out = _exact(model, s_in, k, scale)
    else:
        n_starts = integer("n_starts", n_starts, low=1)
        it = 500 if max_iter is None else integer("max_iter", max_iter, low=1)
        out = _multistart(model, s_in, k, g, gen, scale, n_starts=n_starts, max_iter=it)
    if scaled:
        out = rescale(model, out, scale)
    return _result(model, s, k, method, out, batch, warn)


def _multistart(model: Model, s: np.ndarray, k: int, g: np.ndarray,
                gen: np.random.Generator, scale: np.ndarray, **opts) -> LMOutcome:
    """fit_multistart of data divided by ``scale`` (T,): sigma scaled alike per trial
    (its objective is in units of sigma), trials in order (one rng stream)."""
    if np.all(scale == 1.0):
        return fit_multistart(model, s, k, g, gen, **opts)
    parts = [fit_multistart(scaled_model(model, float(c)), s[i : i + 1], k, g, gen, **opts)
             for i, c in enumerate(scale)]
    return LMOutcome(*(np.concatenate([getattr(o, f) for o in parts])
                       for f in ("x", "chi2", "converged", "n_evaluations")),
                     alternatives=tuple(np.concatenate([o.alternatives[j] for o in parts])
                                        for j in (0, 1)))


def _exact(model: Model, s: np.ndarray, k: int, scale: np.ndarray) -> LMOutcome:
    """fit_exact of data divided by ``scale`` (T,) as an LM outcome (converged by
    construction; evaluations = configurations).  Trials sharing a scale run in one
    batch with sigma scaled alike: fit_exact ranks its candidates by log-likelihood,
    whose chi^2 term would vanish in rounding against -N log sigma otherwise."""
    t, p = s.shape[0], model.n_params(k)
    x, nconf = np.empty((t, p)), np.empty(t, dtype=np.int64)
    for c in np.unique(scale):
        rows = scale == c
        ex = fit_exact(scaled_model(model, float(c)), s[rows], k, count_feasible=False)
        x[rows], nconf[rows] = ex.params, ex.n_configurations
    chi2 = np.sum((s - model.response(x)) ** 2, axis=-1)
    return LMOutcome(x, chi2, np.ones(t, dtype=bool), nconf, np.zeros(t, dtype=bool))


def _result(
    model: Model, s: np.ndarray, k: int, method: str, out: LMOutcome, batch: bool, warn: bool
) -> MLResult:
    from . import _fit_kernel, _kernel  # numba is imported on first use, not with the package

    x = model.canonical(out.x)
    if _kernel.supports(model):  # compiled: chi^2 and Fisher in one pass
        chi2, fisher = _fit_kernel.chi2_fisher(model, x, s)
        n = model.n_sensors
        ll = -0.5 * chi2 / model.sigma**2 - n * (np.log(model.sigma) + 0.5 * np.log(2 * np.pi))
        finite = np.isfinite(fisher).all()
        cov = (_fit_kernel.covariances(fisher, SINGULAR_RTOL) if finite
               else _covariances(model, x, fisher))
    else:
        ll = model.log_likelihood(x, s)
        cov = _covariances(model, x)
    std = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    gap = rival_gap(model, x, out.chi2, out.alternatives, std)
    if warn and np.any(gap < RIVAL_WARN):
        bad = int(np.sum(gap < RIVAL_WARN))
        warnings.warn(
            f"{bad} of {gap.size} ML fit(s) ({method}) reached a distinct local optimum "
            f"(sources > {DISTINCT_STD:g} Fisher std away) within {RIVAL_WARN:g} of the "
            "estimate's log-likelihood: the likelihood is multimodal there and the Fisher "
            "covariance understates the uncertainty; see MLResult.rival_gap, or sample the "
            "posterior (olsbayes.posterior.sample)",
            MultimodalWarning,
            stacklevel=3,
        )
    if warn and not np.all(out.converged):
        bad = int(np.sum(~out.converged))
        warnings.warn(
            f"{bad} of {out.converged.size} ML fit(s) ({method}) did not meet the "
            "convergence criterion of the local optimiser; see MLResult.converged",
            ConvergenceWarning,
            stacklevel=3,
        )
    sel = (lambda a: a) if batch else (lambda a: a[0])
    return MLResult(
        params=sel(x),
        log_likelihood=sel(ll),
        converged=sel(out.converged),
        n_evaluations=sel(out.n_evaluations),
        cov=sel(cov),
        rival_gap=sel(gap),
        method=method,
        n_sources=k,
        model=model,
    )
