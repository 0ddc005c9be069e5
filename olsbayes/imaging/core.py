"""``image``: intensities of sources at known directions, with their posterior."""

from __future__ import annotations

import numbers
import warnings

import numpy as np
from scipy.optimize import lsq_linear
from scipy.special import ndtri

from .._validation import as_rng, finite_array, integer, positive_float
from ..errors import ConvergenceWarning, InputError, NullSpaceWarning
from ..geometry import lonlat_to_unit
from ..model import Model
from .binary import sparse_relaxation, two_level_map
from .design import analyse_design, check_directions, design_matrix
from .eigen import eigen_gibbs
from .gaussian import gaussian_posterior
from .result import ImageResult, hpd_interval, split_rhat
from .sparse import gibbs_intensities
from .truncated import sample_truncated_gaussian
from .window import window_moves

__all__ = ["image", "PRIORS", "SAMPLERS"]

PRIORS = ("gaussian", "nonnegative", "bounded", "sparse", "two-level")
SAMPLERS = ("hmc", "gibbs", "eigen")


def _check_options(prior, sampler, level, null_warn):
    if not isinstance(prior, str) or prior.lower() not in PRIORS:
        raise InputError(f"prior must be one of {', '.join(map(repr, PRIORS))}; got {prior!r}")
    if not isinstance(sampler, str) or sampler.lower() not in SAMPLERS:
        raise InputError(
            f"sampler must be one of {', '.join(map(repr, SAMPLERS))}; got {sampler!r}"
        )
    if isinstance(level, bool) or not isinstance(level, numbers.Real) or not 0 < level < 1:
        raise InputError(f"level must be a number in (0, 1); got {level!r}")
    level = float(level)
    null_warn = positive_float("null_warn", null_warn, upper=1.0)
    return prior.lower(), sampler.lower(), level, null_warn


def image(
    model: Model,
    data: np.ndarray,
    directions: np.ndarray,
    prior: str = "bounded",
    i_max: float = 1.0,
    rng: np.random.Generator | int | None = None,
    *,
    level: float = 0.9,
    n_samples: int | None = None,
    n_chains: int = 4,
    n_burn: int = 100,
    sampler: str = "gibbs",
    neighbours: int = 4,
    window: int = 15,
    prior_mean: float | None = None,
    prior_sd: float | None = None,
    null_warn: float = 0.1,
    prior_bright: float = 0.5,
    reference: np.ndarray | None = None,
    restarts: int = 0,
) -> ImageResult:
    """Posterior of the intensities of sources at known directions.

    With the directions fixed Eq. 1 is linear, ``data = A I + noise``, with
    ``A = design_matrix(model, directions)`` of shape (N, K).

    Parameters
    ----------
    model : Model
        Array, noise sd (``model.sigma``) and sensitivity law.
    data : array_like, shape (N,)
        One set of readings.
    directions : array_like, shape (K, d) (or (K,) for a ring)
        Known source locations: ring angles, sphere (longitude, latitude) in
        rad, or plate positions.
    prior : {"bounded", "nonnegative", "gaussian", "sparse", "two-level"}
        ``"bounded"``: I uniform on [0, i_max]; ``"nonnegative"``: flat on
        I >= 0; ``"gaussian"``: independent N(prior_mean, prior_sd^2), closed
        form with evidence; ``"sparse"``: spike-and-slab
        ``(1 - w) delta_0 + w U(0, i_max)`` with w ~ Beta(1, 1);
        ``"two-level"``: each I is 0 or i_max, bright with probability
        ``prior_bright`` -- MAP only (a local search, see
        :mod:`olsbayes.imaging.binary`; ``result.search`` says how it ended).
    i_max : float
        Upper bound of the intensities (> 0); the scale of the Gaussian prior.
    rng : Generator or seed, optional
        Random stream of the samplers.
    level : float
        Credibility of the intervals (default 0.9).
    n_samples, n_chains, n_burn : int
        Draws kept per chain, chains, discarded trajectories/sweeps.
        ``n_samples=0`` is the fast mode-only path for the box priors: the
        posterior mode (bounded / nonnegative least squares) and the design
        diagnostics, no sampling; ``mean`` is then the mode and ``sd``,
        ``lower``, ``upper`` and ``rhat`` are NaN (no spread is computed: a
        Gaussian approximation at a mode on the box walls would be wrong).
        Default 200 (0 for ``"two-level"``, which has no sampler; the
        Gaussian prior is closed form and ignores it; ``"sparse"`` needs >= 4).
    sampler : {"gibbs", "hmc", "eigen"}
        For the box priors: Gibbs (single-site, neighbour-pair and window moves),
        ``"eigen"`` (single-site plus exact moves along every eigenvector of
        ``A^T A``, which include the null space; :mod:`olsbayes.imaging.eigen`) or
        exact HMC (Pakman & Paninski; exact but can need ~1e4 wall bounces per
        trajectory on large ill-posed grids).  The sparse prior always uses Gibbs.
    neighbours : int
        Gibbs also trades intensity between each source and its ``neighbours``
        nearest sources (exact moves along ``e_k - e_l``); 0 disables.
    window : int
        Box priors with Gibbs: each sweep also makes exact moves along the slow
        eigen-directions of ``A_B^T A_B`` for every window ``B`` of a source
        and its ``window`` nearest sources -- local patterns the array barely
        sees (:mod:`olsbayes.imaging.window`); 0 disables.  Not used by the
        sparse prior (its point mass at 0 is moved by the pair moves).
    prior_mean, prior_sd : float, optional
        Gaussian prior (default i_max / 2 and i_max / 2).
    null_warn : float
        Warn :class:`NullSpaceWarning` when nullity / K exceeds this fraction.
    prior_bright : float in (0, 1)
        ``"two-level"``: prior probability that a source is bright.
    reference : array_like, shape (K,), optional
        ``"two-level"``: a known scene (e.g. the truth of a simulation) whose
        log posterior ``result.search`` reports next to the one found, so a
        search failure (reference better than the scene found) is visible.
    restarts : int
        ``"two-level"``: extra searches, each from the L1 relaxation rounded at
        random (a source starts bright with probability relaxed value / i_max,
        drawn from ``rng``); the best local optimum is kept.  Fewer search
        failures where the design has a large null space, ~20 ms CPU each on Fig. 2.

    Returns
    -------
    ImageResult

    Raises
    ------
    InputError
        Bad model, data length, directions (empty, wrong shape, latitude
        outside [-pi/2, pi/2], unseen by every sub-sensor), i_max <= 0,
        unknown prior or sampler names.
    """
    prior, sampler, level, null_warn = _check_options(prior, sampler, level, null_warn)
    loc = check_directions(model, directions)
    y = finite_array("data", data, ndim=1)
    if y.shape[0] != model.n_sensors:
        raise InputError(
            f"data must have length {model.n_sensors} (one reading per sub-sensor); "
            f"got {y.shape[0]}"
        )
    i_max = positive_float("i_max", i_max)
    n_samples = _n_samples(prior, n_samples)
    n_chains = integer("n_chains", n_chains, low=1)
    n_burn = integer("n_burn", n_burn, low=0)
    neighbours = integer("neighbours", neighbours, low=0)
    window = integer("window", window, low=0)
    gen = as_rng(rng)
    a = design_matrix(model, loc)
    design = analyse_design(a, loc, model.sigma, i_max)
    k = loc.shape[0]
    if design.nullity > null_warn * k:
        warnings.warn(
            f"the design matrix has rank {design.rank} for {k} directions: {design.nullity} "
            "intensity combinations are invisible to the array and set by the prior alone "
            "(see result.design.null_space)",
            NullSpaceWarning,
            stacklevel=2,
        )
    if prior == "gaussian":
        return _gaussian(a, y, model.sigma, design, i_max, level, prior_mean, prior_sd)
    hi = np.inf if prior == "nonnegative" else i_max
    mode = lsq_linear(a, y, bounds=(0.0, hi), method="bvls").x
    if prior == "two-level":
        restarts = integer("restarts", restarts, low=0)
        return _two_level(model, loc, a, y, mode, design, level, i_max, prior_bright, reference,
                          neighbours, restarts, gen)
    if n_samples == 0:
        nan = np.full(k, np.nan)
        return ImageResult(prior=prior, directions=design.directions, mean=mode, mode=mode,
                           sd=nan, lower=nan, upper=nan, level=level, design=design,
                           rhat=float("nan"), sampler="mode-only")
    x0 = _starts(mode, n_chains, hi, i_max, gen)
    if prior == "sparse" or sampler == "gibbs":
        spike = prior == "sparse"
        if spike:  # dim sources of the jittered mode start in the spike
            x0 = np.where(x0 < 0.1 * i_max, 0.0, x0)
        moves = None
        if window and not spike and k > 1:
            moves = window_moves(a, neighbour_groups(model, loc, window), model.sigma)
        run = gibbs_intensities(a, y, model.sigma, hi, x0, n_samples, gen, n_burn=n_burn,
                                spike=spike, pairs=neighbour_pairs(model, loc, neighbours),
                                windows=moves)
        draws, acc, used = run.samples, 1.0, "gibbs"
    elif sampler == "eigen":
        run = eigen_gibbs(a.T @ a / model.sigma**2, a.T @ y / model.sigma**2, np.zeros(k),
                          np.full(k, hi), x0, n_samples, gen, n_burn=n_burn)
        draws, acc, used = run.samples, 1.0, "eigen"
    else:
        draws, acc = _hmc(a, y, model.sigma, hi, i_max, x0, n_samples, n_burn, gen, design)
        used = "hmc"
    return _from_draws(prior, draws, mode, design, level, hi, acc, used)


def _n_samples(prior, n_samples):
    if n_samples is None:
        return 0 if prior == "two-level" else 200
    n = integer("n_samples", n_samples, low=0)
    if 0 < n < 4 or (n == 0 and prior == "sparse") or (n > 0 and prior == "two-level"):
        need = {"sparse": ">= 4", "two-level": "0 (MAP only, no sampler)"}
        need = need.get(prior, "0 (mode only) or >= 4")
        raise InputError(f"n_samples must be {need} for prior {prior!r}; got {n_samples!r}")
    return n


def _two_level(model, loc, a, y, mode, design, level, i_max, prior_bright, reference, neighbours,
               restarts, gen):
    p = positive_float("prior_bright", prior_bright, upper=1.0)
    if p >= 1.0:
        raise InputError(f"prior_bright must be in (0, 1); got {prior_bright!r}")
    ref = None
    if reference is not None:
        ref = finite_array("reference", reference, ndim=1)
        if ref.shape != mode.shape:
            raise InputError(f"reference must have shape {mode.shape}; got {ref.shape}")
    groups = neighbour_groups(model, loc, 2 * neighbours) if neighbours else None
    best = None
    relaxed = sparse_relaxation(a, y, model.sigma, i_max)
    starts = [mode, relaxed] + [
        i_max * (gen.random(relaxed.shape[0]) < relaxed / i_max) for _ in range(restarts)
    ]
    for start in starts:
        run = two_level_map(a, y, model.sigma, i_max, start, p_bright=p, groups=groups,
                            reference=ref)
        if best is None or run.log_posterior > best.log_posterior:
            best = run
    nan = np.full(mode.shape[0], np.nan)
    return ImageResult(prior="two-level", directions=design.directions, mean=best.x,
                       mode=best.x, sd=nan, lower=nan, upper=nan, level=level, design=design,
                       rhat=float("nan"), sampler="map-search", search=best)


def neighbour_pairs(model: Model, loc: np.ndarray, n: int) -> np.ndarray:
    """Unique pairs (k, l), shape (P, 2), of each source with its n nearest sources."""
    k = loc.shape[0]
    n = min(n, k - 1)
    if n <= 0:
        return np.zeros((0, 2), dtype=int)
    near = _nearest(model, loc, n)
    pairs = np.sort(np.column_stack([np.repeat(np.arange(k), n), near.ravel()]), axis=1)
    return np.unique(pairs, axis=0)


def neighbour_groups(model: Model, loc: np.ndarray, n: int) -> np.ndarray:
    """Each source with its n nearest sources, shape (K, min(n, K - 1) + 1)."""
    n = min(n, loc.shape[0] - 1)
    return np.column_stack([np.arange(loc.shape[0]), _nearest(model, loc, n)])


def _nearest(model: Model, loc: np.ndarray, n: int) -> np.ndarray:
    """Indices, shape (K, n), of each source's n nearest other sources."""
    if model.kind == "position":
        d2 = np.sum((loc[:, None, :] - loc[None, :, :]) ** 2, axis=-1)
    else:  # angular distance through unit vectors (1 - cos)
        if model.kind == "angle":
            v = np.column_stack([np.cos(loc[:, 0]), np.sin(loc[:, 0])])
        else:
            v = lonlat_to_unit(loc[:, 0], loc[:, 1])
        d2 = 1.0 - v @ v.T
    np.fill_diagonal(d2, np.inf)
    return np.argsort(d2, axis=1, kind="stable")[:, :n]


def _starts(mode, n_chains, hi, i_max, gen):
    """Chains start dispersed around the bounded least-squares mode, inside the box."""
    jitter = 0.05 * i_max * gen.standard_normal((n_chains, mode.shape[0]))
    x0 = np.abs(mode + jitter)
    return np.minimum(x0, hi - 1e-6 * i_max) if np.isfinite(hi) else x0


def _hmc(a, y, sigma, hi, i_max, x0, n_samples, n_burn, gen, design):
    q = a.T @ a / sigma**2
    b = a.T @ y / sigma**2
    k = q.shape[0]
    ridge = 0.0 if design.nullity == 0 and design.singular_values[-1] / sigma > 1e-3 / i_max else (
        1.0 / i_max**2
    )
    run = sample_truncated_gaussian(
        q, b, np.zeros(k), np.full(k, hi), x0, n_samples, gen, n_burn=n_burn, ridge=ridge,
        centre=np.full(k, 0.5 * i_max),
    )
    return run.samples, run.acceptance


def _gaussian(a, y, sigma, design, i_max, level, prior_mean, prior_sd):
    k = a.shape[1]
    m0 = 0.5 * i_max
    if prior_mean is not None:
        m0 = float(finite_array("prior_mean", prior_mean, ndim=0))
    s0 = 0.5 * i_max if prior_sd is None else positive_float("prior_sd", prior_sd)
    post = gaussian_posterior(a, y, sigma, np.full(k, m0), np.full(k, s0))
    z = ndtri(0.5 + level / 2)
    sd = post.sd
    return ImageResult(
        prior="gaussian", directions=design.directions, mean=post.mean, mode=post.mean, sd=sd,
        lower=post.mean - z * sd, upper=post.mean + z * sd, level=level, design=design,
        log_evidence=post.log_evidence,
    )


def _from_draws(prior, draws, mode, design, level, hi, acc, used):
    flat = draws.reshape(-1, draws.shape[-1])
    k = flat.shape[1]
    lo_b, hi_b = np.zeros(k), np.full(k, hi)
    lower, upper = hpd_interval(flat, level, lo_b, hi_b)
    rhat = float(np.nanmax(split_rhat(draws))) if draws.shape[0] > 1 else float("nan")
    if rhat > 1.1:
        warnings.warn(
            f"the {used} chains have not mixed: largest split R-hat {rhat:.3g} > 1.1; "
            "increase n_samples/n_burn and treat sd and intervals with care",
            ConvergenceWarning,
            stacklevel=3,
        )
    p_bright = np.mean(flat > 0, axis=0) if prior == "sparse" else None
    return ImageResult(
        prior=prior, directions=design.directions, mean=flat.mean(axis=0),
        mode=np.median(flat, axis=0) if prior == "sparse" else mode,
        sd=flat.std(axis=0, ddof=1), lower=lower, upper=upper, level=level, design=design,
        samples=draws, p_bright=p_bright, rhat=rhat, acceptance=acc, sampler=used,
    )
