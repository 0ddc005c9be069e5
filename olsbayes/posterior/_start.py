"""Initial walker ensembles: a CRLB-shaped ball around a point, or prior draws."""

from __future__ import annotations

import numpy as np

from ..bounds import bound_covariance, covariance_root
from ..errors import InputError
from ..priors import ScenePrior

__all__ = ["ball_covariance", "initial_ensemble", "ml_start"]


def ball_covariance(model, prior: ScenePrior, centre: np.ndarray) -> np.ndarray:
    """Covariance (P, P) of the starting ball: the CRLB at ``centre``.

    Unidentifiable or wider-than-prior directions are capped at the prior's
    scale (a tenth of the support width, or the prior sd for unbounded
    supports), so the ball stays inside the region where the bound means
    something.  When sigma is inferred its bound sigma / sqrt(2 N) is appended.
    """
    k = prior.n_sources
    p_model = model.n_params(k)
    cap = np.array([_prior_scale(p) for p in prior.marginals])
    cov = np.diag(cap**2)
    if p_model:
        fisher = model.fisher(centre[:p_model])
        if prior.noise is not None:
            fisher = fisher * (model.sigma / centre[-1]) ** 2
        bound, _, singular = bound_covariance(fisher)
        sub = np.where(np.isfinite(bound), bound, 0.0)
        sd = np.sqrt(np.clip(np.diag(sub), 0.0, None))
        too_wide = singular | ~(sd > 0) | (sd > cap[:p_model])
        sub[too_wide, :] = 0.0
        sub[:, too_wide] = 0.0
        sub[too_wide, too_wide] = cap[:p_model][too_wide] ** 2
        cov[:p_model, :p_model] = sub
    if prior.noise is not None:
        cov[-1, -1] = min(cap[-1], centre[-1] / np.sqrt(2 * model.n_sensors)) ** 2
    return cov


def _prior_scale(prior) -> float:
    width = prior.upper - prior.lower
    if np.isfinite(width):
        return 0.1 * width
    draws = prior.ppf(np.array([0.16, 0.84]))
    return 0.5 * float(draws[1] - draws[0])


def initial_ensemble(
    centre: np.ndarray,
    cov: np.ndarray,
    n_walkers: int,
    inside,
    rng: np.random.Generator,
    max_tries: int = 50,
) -> np.ndarray:
    """``n_walkers`` draws from N(centre, cov) that satisfy ``inside`` (a mask fn).

    Draws outside the prior support are redrawn; after ``max_tries`` rounds
    the ball shrinks by 2 each round.
    """
    root = covariance_root(cov)
    out = np.empty((n_walkers, centre.size))
    todo = np.arange(n_walkers)
    shrink = 1.0
    for attempt in range(4 * max_tries):
        z = rng.standard_normal((todo.size, centre.size))
        cand = centre + shrink * z @ root.T
        ok = inside(cand)
        out[todo[ok]] = cand[ok]
        todo = todo[~ok]
        if todo.size == 0:
            return out
        if attempt >= max_tries:
            shrink *= 0.5
    raise InputError("start: could not place walkers inside the prior support around the start")


def ml_start(model, data: np.ndarray, n_sources: int, rng: np.random.Generator
             ) -> np.ndarray:
    """The maximum-likelihood point from :func:`olsbayes.ml.fit_ml`."""
    try:
        from ..ml import fit_ml
    except ImportError as exc:  # pragma: no cover - ml subpackage missing
        raise InputError(
            "start=None needs olsbayes.ml.fit_ml; give start= explicitly "
            f"(a point or an ensemble) or start='prior' ({exc})"
        ) from None
    res = fit_ml(model, data, n_sources, rng=rng)
    return np.asarray(res.params, dtype=float)
