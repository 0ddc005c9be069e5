"""Initial walker ensembles: a CRLB-shaped ball around a point, or prior draws."""

from __future__ import annotations

import numpy as np

from .._validation import finite_array
from ..bounds import bound_covariance, covariance_root
from ..errors import InputError
from ..ml import MLResult, fit_ml
from ..priors import ScenePrior
from . import _general
from ._logpost import LogPosterior

__all__ = ["ball_covariance", "initial_ensemble", "ml_start", "check_start", "initial_walkers",
           "start_coordinates"]


def ball_covariance(model, prior: ScenePrior, centre: np.ndarray,
                    n_frames: int | None = None, general: bool = False) -> np.ndarray:
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
    if general:  # every parameter from the full information (extras and priors included)
        return _capped(bound_covariance(_general.information(model, prior, centre, n_frames)),
                       cap)
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


def _capped(bound: tuple, cap: np.ndarray) -> np.ndarray:
    """The bound with unidentifiable or wider-than-prior directions at the prior scale."""
    cov, _, singular = bound
    sub = np.where(np.isfinite(cov), cov, 0.0)
    sd = np.sqrt(np.clip(np.diag(sub), 0.0, None))
    too_wide = singular | ~(sd > 0) | (sd > cap)
    sub[too_wide, :] = 0.0
    sub[:, too_wide] = 0.0
    sub[too_wide, too_wide] = cap[too_wide] ** 2
    return sub


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
    the ball shrinks by 2 each round.  A centre on a corner of the support (say
    two intensities at 0 whose errors are anti-correlated) leaves a share of
    the ball inside that no shrinking raises; the walkers still missing are
    then drawn from the whole ball in batches (:func:`_fill_from_ball`).
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
    out[todo] = _fill_from_ball(centre, root, todo.size, inside, rng)
    return out


#: Rows per batch of :func:`_fill_from_ball` (bounds its memory: rows x P floats).
_BATCH_ROWS = 1 << 16


def _fill_from_ball(centre: np.ndarray, root: np.ndarray, n: int, inside,
                    rng: np.random.Generator, rounds: int = 16) -> np.ndarray:
    """``n`` draws (n, P) of N(centre, root root^T) inside the support, by batches.

    Covers a share of the ball inside down to about ``n / (rounds * 65536)``.
    """
    got: list[np.ndarray] = []
    need = n
    for _ in range(rounds):
        cand = centre + rng.standard_normal((_BATCH_ROWS, centre.size)) @ root.T
        cand = cand[inside(cand)][:need]
        got.append(cand)
        need -= len(cand)
        if need == 0:
            return np.concatenate(got)
    raise InputError("start: could not place walkers inside the prior support around the start")


def ml_start(model, data: np.ndarray, n_sources: int, rng: np.random.Generator
             ) -> np.ndarray:
    """The maximum-likelihood point (P_model,) from :func:`olsbayes.ml.fit_ml`."""
    res = fit_ml(model, data, n_sources, rng=rng)
    return np.asarray(res.params, dtype=float)


def check_start(model, prior: ScenePrior, start: object, n_walkers: int) -> object:
    """Check ``start`` before any work; returns it (an array start as a float array).

    None, ``"prior"``, an ``MLResult`` of one fit of K sources, a point (P,) or an
    ensemble (n_walkers, P) inside the prior's support.
    """
    p = prior.n_params
    if start is None:
        return None
    if isinstance(start, str):
        if start != "prior":
            raise InputError(
                f"start must be None, an MLResult, 'prior' or an array; got {start!r}")
        return start
    if isinstance(start, MLResult):
        shape = (model.n_params(prior.n_sources),)
        if np.shape(start.params) != shape:
            raise InputError(
                f"start: the MLResult must hold one fit of {prior.n_sources} source(s), "
                f"params of shape {shape}; got {np.shape(start.params)}")
        return start
    arr = finite_array("start", start, ndim=(1, 2), last=p)
    if arr.ndim == 2:
        if arr.shape[0] != n_walkers:
            raise InputError(
                f"start ensemble must have shape ({n_walkers}, {p}) (n_walkers, n_params); "
                f"got {arr.shape}")
        bad = ~prior.contains(arr)
        if bad.any():
            raise InputError(
                f"start: {int(bad.sum())} walker(s) lie outside the prior support "
                f"(lower {prior.lower}, upper {prior.upper})")
    return arr


def initial_walkers(model, data: np.ndarray, prior: ScenePrior, start: object,
                    n_walkers: int, gen_ml: np.random.Generator,
                    gen_ball: np.random.Generator, frames: bool = False
                    ) -> tuple[np.ndarray, np.ndarray | None]:
    """Walker positions (W, P) in model coordinates and the ball centre (or None).

    ``start`` is as returned by :func:`check_start`.  None fits the ML point
    (``gen_ml``); a point (ML or given) is the centre of a CRLB-shaped ball
    (``gen_ball``); ``"prior"`` draws the walkers from the prior (``gen_ball``);
    an ensemble is used as is.
    """
    if isinstance(start, str):
        return prior.sample(n_walkers, rng=gen_ball), None
    if isinstance(start, np.ndarray) and start.ndim == 2:
        return start.copy(), None
    general = _general.is_general(model, prior, frames)
    if isinstance(start, np.ndarray):
        centre = start.copy()
    elif general:
        centre = np.clip(_general.ml_centre(model, data, prior, start, gen_ml, frames),
                         prior.lower, prior.upper)
    else:
        ml_point = (ml_start(model, data, prior.n_sources, gen_ml) if start is None
                    else np.asarray(start.params, dtype=float))
        centre = ml_point
        if prior.noise is not None:
            resid = data - model.response(centre)
            centre = np.append(centre, max(float(np.sqrt(np.mean(resid**2))), 1e-300))
        centre = np.clip(centre, prior.lower, prior.upper)
    if not prior.contains(centre):
        raise InputError(
            f"start {np.array2string(centre, precision=4)} lies outside the prior support "
            f"(lower {prior.lower}, upper {prior.upper})")
    cov = ball_covariance(model, prior, centre, data.shape[-2] if frames else None, general)
    return initial_ensemble(centre, cov, n_walkers, prior.contains, gen_ball), centre


def start_coordinates(logpost: LogPosterior, walkers: np.ndarray) -> np.ndarray:
    """The walkers (W, P) in the sampler's coordinates.

    Refused if some have zero posterior density or they are linearly dependent (emcee
    could not move them).
    """
    from emcee.ensemble import walkers_independent

    z0 = logpost.to_sampler(walkers)
    if not np.all(np.isfinite(logpost(z0))):
        raise InputError("start: some walkers have zero posterior density (outside the prior?)")
    if not walkers_independent(z0):
        raise InputError(
            "start: the walkers are not linearly independent (e.g. repeated rows or a "
            "parameter with one value); spread them out or give a single start point"
        )
    return z0
