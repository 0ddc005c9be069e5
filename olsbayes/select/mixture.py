"""Evidence of an awkward K by importance sampling over source locations only.

Where the Laplace approximation fails -- an extra source whose intensity sits at
its bound 0 (its location then barely constrained: the Gaussian in location with
the Fisher width is the wrong volume), a singular Fisher matrix (a source split
within one sensor spacing predicts the same readings), a weak or close source --
the evidence is computed by importance sampling.  Two facts make this cheap:

* The readings are linear in the intensities, ``y = G(loc) I + noise``.  For
  fixed locations the likelihood is Gaussian in I with mean I^ = (G^T G)^-1 G^T y
  and covariance C = sigma^2 (G^T G)^-1, so drawing I from that Gaussian leaves
  the weight  max_I L(loc, I) (2 pi)^(K/2) det(C)^(1/2) pi(loc, I) / q(loc),
  exact for any intensity prior (a box prior: the indicator of the box).  Only
  the K locations are proposed.
* The proposal is a defensive mixture of products over sources: the K-source ML
  locations with their Fisher widths (and, wider, one sensor spacing), the
  (K-1)-source ML locations plus one source anywhere in the prior, and the
  prior itself.  A source whose intensity is within one sd of 0 is proposed from
  the prior (its location is not constrained).  The mixture is symmetrised over
  the K! labellings (its density summed over the permutations of the sources),
  so the estimate integrates the full labelled space and needs no K! factor,
  also where the labelled copies overlap (a split source, a free source).

log Z = log mean(w) with standard error sd(w) / (mean(w) sqrt(n)) (delta method)
and Kish's effective sample size.  Checked against the exact grid evidence of
:mod:`olsbayes.studies.sbc_exact` (tests/test_select_mixture.py).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from .._validation import as_rng, integer, positive_float
from ..bounds import bound_covariance
from ..errors import InputError
from ..exchange import permutations
from ..resolution import sensor_spacing
from .intensity import location_log_weights

__all__ = ["MixtureEvidence", "mixture_log_evidence", "location_scales", "MAX_SOURCES"]

#: Largest K handled (the symmetrised density sums over K! permutations).
MAX_SOURCES = 5
#: Mixture weights: K-fit, (K-1)-fit + one extra source, (K-2)-fit + two, (K-3)-fit +
#: three, prior.  Weights of missing lower fits go to the K-fit.
WEIGHTS = (0.5, 0.2, 0.15, 0.1, 0.05)
#: Each constrained source of a fit is proposed from a normal with its (inflated)
#: Fisher sd, a normal half a sensor spacing wide, a radial density around it (only
#: where sources are missing from the fit; else its weight goes to the first), or
#: its prior, with these weights.
SOURCE_MIX = (0.45, 0.2, 0.2, 0.15)
#: An extra (free) source is proposed one sensor spacing wide around one of the
#: fitted sources (a split source), or with this probability from its prior.
EXTRA_PRIOR = 0.5
#: Narrow components inflate the Fisher sd by this factor (heavier than the target).
INFLATE = 1.5
#: Largest sd (rad) of a proposal normal on a periodic coordinate (nearest image exact).
MAX_PERIODIC_SD = 0.5
#: Radial proposals cover distances RADIAL_RANGE * r_hi .. r_hi (r_hi: the wide sd).
RADIAL_RANGE = 1e-4
#: sd of the wide proposal normals, in sensor spacings (a split source's pair spreads
#: about this far around the fitted location).
WIDE = 0.5
#: A source whose ML intensity is below this many sd is proposed from the prior.
FREE_SNR = 1.0


@dataclass(frozen=True)
class MixtureEvidence:
    """log Z_K by mixture importance sampling over locations.

    Attributes
    ----------
    log_evidence : float
        Nats; -inf if no draw has positive weight.
    error : float
        Delta-method standard error of log Z (nats).
    ess : float
        Kish effective sample size (sum w)^2 / sum w^2.
    n_draws : int
        Location draws (= likelihood evaluations).
    seconds : float
    """

    log_evidence: float
    error: float
    ess: float
    n_draws: int
    seconds: float


def location_scales(model, params: np.ndarray, spacing: float | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Per-source location sd (K, d) at an ML point and which sources are free (K,).

    From the inverse Fisher matrix; a source whose coordinates are unidentifiable
    there (singular Fisher matrix) gets the sd of its own (d+1)-block alone.  A
    source is *free* (to be proposed from the prior) if its intensity is less
    than ``FREE_SNR`` sd above 0 or its location sd is undefined.  Location sds
    are capped at one sensor spacing.
    """
    x = np.asarray(params, float)
    k, w = model.n_sources_of(x), model.n_loc + 1
    if k == 0:
        return np.zeros((0, w - 1)), np.zeros(0, bool)
    f = model.fisher(x)
    cov, _, singular = bound_covariance(f)
    var = np.diag(cov).reshape(k, w).copy()
    for s in range(k):
        blk = slice(s * w, (s + 1) * w)
        if singular[blk].any():
            c, _, sing = bound_covariance(f[blk, blk])
            var[s] = np.where(sing, np.inf, np.diag(c))
    with np.errstate(invalid="ignore", divide="ignore"):
        sd = np.sqrt(np.where(var > 0, var, np.nan))
    snr = x.reshape(k, w)[:, -1] / sd[:, -1]
    loc_sd = np.minimum(sd[:, :-1], sensor_spacing(model) if spacing is None else spacing)
    free = ~(snr >= FREE_SNR) | ~np.all(np.isfinite(loc_sd), axis=1)
    return np.where(np.isfinite(loc_sd), loc_sd, np.nan), free


@dataclass(frozen=True, eq=False)
class _Component:
    """One product component.

    Source a is drawn from normal m (centre ``mu[a, m]``, sd ``sd[a, m]``) with
    probability ``w[a, m]``, from radial r (around ``rmu[a, r]``, density proportional
    to distance^-d between ``r_lo`` and ``r_hi``) with ``w[a, M + r]``, or from its
    prior with ``w[a, -1]``.
    """

    weight: float
    mu: np.ndarray  # (K, M, d)
    sd: np.ndarray  # (K, M, d)
    rmu: np.ndarray  # (K, R, d)
    w: np.ndarray  # (K, M + R + 1)
    r_lo: float = 1.0
    r_hi: float = 1.0


def _fit_component(model, prior, weight: float, params: np.ndarray, n_extra: int,
                   h: float) -> _Component:
    """The sources of ``params`` plus ``n_extra`` sources missing from that fit.

    A fitted source: narrow (its Fisher sd) or one-spacing-wide normal, or its prior;
    with missing sources (``n_extra`` > 0) also a radial proposal around it.  A
    missing source: wide normal or radial around one of the fitted sources (a split
    source), or its prior.  The radial density ~ distance^-d matches the ~1/distance
    evidence density of a source split into two close ones (whose intensities are
    then nearly unidentifiable: a wide Gaussian cut by the box), which a normal
    proposal would leave with an infinite-variance weight at high SNR.
    """
    k, d = prior.n_sources, model.n_loc
    n_fit = k - n_extra
    per = np.array([m.periodic for m in prior.location])
    cap = np.where(per, min(WIDE * h, MAX_PERIODIC_SD), WIDE * h)
    big = max(2, n_fit)
    n_rad = max(1, n_fit)
    mu, sd = np.zeros((k, big, d)), np.ones((k, big, d))
    rmu = np.zeros((k, n_rad, d))
    w = np.zeros((k, big + n_rad + 1))
    w[:, -1] = 1.0
    if n_fit:
        scale, free = location_scales(model, params, h)
        centre = np.asarray(params, float).reshape(n_fit, d + 1)[:, :-1]
        narrow = np.minimum(INFLATE * np.maximum(np.nan_to_num(scale, nan=h), 1e-6 * h), cap)
        mix = SOURCE_MIX if n_extra else (SOURCE_MIX[0] + SOURCE_MIX[2], SOURCE_MIX[1], 0.0,
                                          SOURCE_MIX[3])
        for a in np.flatnonzero(~free):
            mu[a, :2], sd[a, 0], sd[a, 1], rmu[a, 0] = centre[a], narrow[a], cap, centre[a]
            w[a, 0], w[a, 1], w[a, big], w[a, -1] = mix
        for a in range(n_fit, k):  # a missing source near any fitted one, or anywhere
            mu[a, :n_fit], sd[a, :n_fit], rmu[a, :n_fit] = centre, cap, centre
            w[a, :n_fit] = w[a, big:big + n_fit] = 0.5 * (1.0 - EXTRA_PRIOR) / n_fit
            w[a, -1] = EXTRA_PRIOR
    r_hi = float(np.min(cap))
    return _Component(weight, mu, sd, rmu, w, RADIAL_RANGE * r_hi, r_hi)


def _components(model, fit_k: np.ndarray, lower: list[np.ndarray], prior
                ) -> list[_Component]:
    """K-fit, (K-j)-fits plus j extra sources, and the prior (see :data:`WEIGHTS`)."""
    k, h = prior.n_sources, sensor_spacing(model)
    lower = [f for f in lower if 0 < model.n_sources_of(f) < k][: len(WEIGHTS) - 2]
    spare = sum(WEIGHTS[1:len(WEIGHTS) - 1][len(lower):])
    out = [_fit_component(model, prior, WEIGHTS[0] + spare, fit_k, 0, h)]
    for w, f in zip(WEIGHTS[1:], lower):
        out.append(_fit_component(model, prior, w, f, k - model.n_sources_of(f), h))
    out.append(_fit_component(model, prior, WEIGHTS[-1], np.zeros(0), k, h))
    return out


def _draw(comp: _Component, prior, n: int, gen: np.random.Generator) -> np.ndarray:
    """n location draws (n, K, d) of one component (each source picks its sub-proposal)."""
    k, big, d = comp.mu.shape
    n_rad = comp.rmu.shape[1]
    cum = np.cumsum(comp.w, axis=1)
    pick = np.minimum((gen.random((n, k, 1)) > cum[None, :, :-1]).sum(axis=-1), big + n_rad)
    rows = np.arange(k)[None, :]
    normal = np.minimum(pick, big - 1)
    out = comp.mu[rows, normal] + comp.sd[rows, normal] * gen.standard_normal((n, k, d))
    radial = (pick >= big) & (pick < big + n_rad)
    if radial.any():
        r = comp.r_lo * (comp.r_hi / comp.r_lo) ** gen.random((n, k, 1))
        u = gen.standard_normal((n, k, d))
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        around = comp.rmu[rows, np.clip(pick - big, 0, n_rad - 1)] + r * u
        out = np.where(radial[..., None], around, out)
    for j, marg in enumerate(prior.location):
        if marg.periodic:
            out[..., j] = marg.lower + np.mod(out[..., j] - marg.lower, marg.upper - marg.lower)
        out[..., j] = np.where(pick == big + n_rad, marg.ppf(gen.random((n, k))), out[..., j])
    return out


def _log_prior_loc(prior, loc: np.ndarray) -> np.ndarray:
    """log prior density (n, K) of each draw source's location."""
    total = np.zeros(loc.shape[:2])
    for j, marg in enumerate(prior.location):
        if marg.flat:
            total += float(marg.log_prob(np.asarray(0.5 * (marg.lower + marg.upper))))
        else:
            total += np.asarray(marg.log_prob(loc[..., j]), float)
    return total


def _wrapped_diff(prior, loc: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """loc (n, K, d) minus centres (K, C, d), nearest periodic image: (n, K, C, K, d)."""
    diff = loc[:, None, None, :, :] - centre[None, :, :, None, :]
    for j, marg in enumerate(prior.location):
        if marg.periodic:
            per = marg.upper - marg.lower
            diff[..., j] -= per * np.round(diff[..., j] / per)
    return diff


def _q_matrix(comp: _Component, prior, loc: np.ndarray, prior_q: np.ndarray) -> np.ndarray:
    """Density (n, K, K) of component source a (axis 1) at draw source b (axis 2).

    A periodic coordinate's density is wrapped with the nearest image only: widths
    are at most ``MAX_PERIODIC_SD`` = 0.5 rad, so the other images weigh < 3e-9.
    """
    k, big, d = comp.mu.shape
    q = comp.w[None, :, -1, None] * prior_q[:, None, :]
    live = np.flatnonzero(comp.w[:, :big].any(axis=0))  # sub-normals in use
    if live.size:
        sd = comp.sd[:, live]
        coef = comp.w[:, live] / np.prod(sd, axis=-1) * (2 * math.pi) ** (-0.5 * d)
        z = _wrapped_diff(prior, loc, comp.mu[:, live]) / sd[None, :, :, None, :]
        dens = np.exp(-0.5 * np.sum(z * z, axis=-1))  # (n, K, M, K)
        q = q + np.einsum("am,namb->nab", coef, dens)
    rad = np.flatnonzero(comp.w[:, big:-1].any(axis=0))
    if rad.size:
        r = np.linalg.norm(_wrapped_diff(prior, loc, comp.rmu[:, rad]), axis=-1)
        surface = 2 * math.pi ** (0.5 * d) / math.gamma(0.5 * d)
        norm = math.log(comp.r_hi / comp.r_lo) * surface
        inside = (r >= comp.r_lo) & (r <= comp.r_hi)
        with np.errstate(divide="ignore"):
            dens = np.where(inside, 1.0 / (norm * r**d), 0.0)
        q = q + np.einsum("am,namb->nab", comp.w[:, big + rad], dens)
    return q


def _log_q(comps: list[_Component], prior, loc: np.ndarray) -> np.ndarray:
    """log of the permutation-symmetrised mixture density at draws (n, K, d).

    The sum over the K! labellings is taken in the linear domain: every entry of a
    component's (K, K) matrix holds a prior term (>= its weight times the prior
    density), so no product underflows inside the prior's support.
    """
    k = prior.n_sources
    perms = permutations(k)  # (K!, K)
    rows = np.arange(k)
    prior_q = np.exp(_log_prior_loc(prior, loc))
    total = np.zeros(loc.shape[0])
    for comp in comps:
        a = _q_matrix(comp, prior, loc, prior_q)
        total += comp.weight / len(perms) * np.prod(a[:, rows[None, :], perms], axis=-1).sum(-1)
    with np.errstate(divide="ignore"):
        return np.log(total)


def mixture_log_evidence(
    model,
    data: np.ndarray,
    prior,
    fit_k: np.ndarray,
    lower: list[np.ndarray] | tuple[np.ndarray, ...] = (),
    n_draws: int = 2000,
    *,
    target_error: float = 0.1,
    max_draws: int = 16_000,
    rng: np.random.Generator | int | None = None,
) -> MixtureEvidence:
    """log Z_K by importance sampling over the K locations (intensities integrated).

    Doubles the sample (same proposal, every weight kept) until the standard error
    of log Z is below ``target_error`` or ``max_draws`` is reached.

    Parameters
    ----------
    model : Model
        Known noise sd ``model.sigma``.
    data : ndarray, shape (N,)
    prior : ScenePrior
        Prior of K sources (sigma known), 1 <= K <= ``MAX_SOURCES``.
    fit_k : ndarray, shape (K (d+1),)
        ML point of K sources (any labelling).
    lower : sequence of ndarray
        ML points of fewer sources (K - 1, K - 2, K - 3); each adds the component
        "that fit plus the missing sources near one of its sources or anywhere".
    n_draws : int
        Initial number of location draws (>= 100).
    target_error : float
        Stop adding draws once the standard error is below this (nats).
    max_draws : int
        Cap on the total number of draws.
    rng : Generator or seed

    Returns
    -------
    MixtureEvidence
    """
    t0 = time.perf_counter()
    k = prior.n_sources
    if not 1 <= k <= MAX_SOURCES:
        raise InputError(f"mixture_log_evidence needs 1 <= K <= {MAX_SOURCES}; got K = {k}")
    if prior.noise is not None:
        raise InputError("mixture_log_evidence needs sigma known: ScenePrior(noise=None)")
    n_draws = integer("n_draws", n_draws, low=100)
    max_draws = integer("max_draws", max_draws, low=n_draws)
    target_error = positive_float("target_error", target_error)
    gen = as_rng(rng)
    data = np.asarray(data, float)
    comps = _components(model, fit_k, list(lower), prior)
    parts: list[np.ndarray] = []
    n, batch = 0, n_draws
    while True:
        parts.append(_batch(model, data, prior, comps, batch, gen))
        n += batch
        log_z, se, ess = _summary(np.concatenate(parts))
        if se <= target_error or n >= max_draws or not np.isfinite(log_z):
            break
        batch = min(n, max_draws - n)
    return MixtureEvidence(log_z, se, ess, n, time.perf_counter() - t0)


def _batch(model, data: np.ndarray, prior, comps: list[_Component], n: int,
           gen: np.random.Generator) -> np.ndarray:
    """log importance weights (n,) of n draws from the mixture (-inf: weight 0)."""
    counts = gen.multinomial(n, [c.weight for c in comps])
    loc = np.concatenate([_draw(c, prior, int(m), gen) for c, m in zip(comps, counts)])
    log_w = location_log_weights(model, data, prior, loc, rng=gen) - _log_q(comps, prior, loc)
    return np.where(np.isfinite(log_w), log_w, -np.inf)


def _summary(log_w: np.ndarray) -> tuple[float, float, float]:
    """(log mean w, delta-method se of it, Kish ESS) of log weights."""
    if not np.isfinite(log_w).any():
        return -math.inf, math.inf, 0.0
    n = log_w.size
    top = float(np.max(log_w))
    log_mean = top + math.log(float(np.sum(np.exp(log_w - top))) / n)
    w = np.exp(log_w - log_mean)
    return log_mean, float(np.std(w) / math.sqrt(n)), float(w.sum() ** 2 / np.sum(w * w))
