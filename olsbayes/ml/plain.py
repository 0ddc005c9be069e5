"""The fit under Gaussian noise of one known sigma: validate, scale, run a method, assemble."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .._budget import check_memory
from .._notice import notice
from .._validation import as_rng, choice
from ..antipodal import ANTIPODAL_SPACINGS, pair_offsets
from ..bounds import SINGULAR_RTOL, bound_covariance
from ..errors import AntipodalWarning, ConvergenceWarning, InputError, MultimodalWarning
from ..model import Model
from ..resolution import ANTIPODAL_DOUBT, antipodal_doubts
from .atoms import cached_default_grid, check_atom_memory, check_grid, default_grid_size
from .exact import check_exact, enumerate_optimum
from .fast import FastOptions, fit_fast
from .honesty import warn_honesty
from .inputs import check_fit_inputs
from .mirror import mirror_gap
from .multistart import MultistartOptions, fit_multistart
from .outcome import FitOutcome
from .result import MLResult
from .rivals import DISTINCT_STD, RIVAL_WARN, rival_gap
from .scaling import reading_scales, rescale, scaled_model

__all__ = ["fit_plain", "warn_rivals", "METHODS", "BLOCK_ROWS", "NOTICE_BATCH"]


@dataclass(frozen=True)
class _Method:
    """One estimator: the type of its options and its runner.

    ``options`` is None when it takes none; the runner is
    ``run(model, data (T, N), K, grid, options, rng, scales (T,)) -> FitOutcome``.
    """

    options: type | None
    run: Callable[..., FitOutcome]


def _run_fast(model, s, k, grid, options, gen, scale) -> FitOutcome:
    return fit_fast(model, s, k, grid, options)


def _run_multistart(model, s, k, grid, options, gen, scale) -> FitOutcome:
    """Multistart fit of data divided by ``scale`` (T,), sigma scaled alike per data vector.

    The objective is in units of sigma; the data vectors run in order (one rng stream).
    """
    if np.all(scale == 1.0):
        return fit_multistart(model, s, k, grid, options, rng=gen)
    parts = [fit_multistart(scaled_model(model, float(c)), s[i : i + 1], k, grid, options,
                            rng=gen)
             for i, c in enumerate(scale)]
    return FitOutcome(*(np.concatenate([getattr(o, f) for o in parts])
                        for f in ("x", "chi2", "converged", "n_evaluations")),
                      alternatives=tuple(np.concatenate([o.alternatives[j] for o in parts])
                                         for j in (0, 1)))


def _run_exact(model, s, k, grid, options, gen, scale) -> FitOutcome:
    """Exact enumeration of data divided by ``scale`` (T,), converged by construction.

    Evaluations = configurations.  Data vectors sharing a scale run in one batch with
    sigma scaled alike: the enumeration ranks its candidates by log-likelihood, whose
    chi^2 term would vanish in rounding against -N log sigma otherwise.
    """
    t, p = s.shape[0], model.n_params(k)
    x, nconf = np.empty((t, p)), np.empty(t, dtype=np.int64)
    for c in np.unique(scale):
        rows = scale == c
        ex = enumerate_optimum(scaled_model(model, float(c)), s[rows], k)
        x[rows], nconf[rows] = ex.params, ex.n_configurations
    chi2 = np.sum((s - model.response(x)) ** 2, axis=-1)
    return FitOutcome(x, chi2, np.ones(t, dtype=bool), nconf, np.zeros(t, dtype=bool))


_METHODS = {
    "fast": _Method(FastOptions, _run_fast),
    "multistart": _Method(MultistartOptions, _run_multistart),
    "exact": _Method(None, _run_exact),
}

#: The default options of each method (validated once; the records are immutable).
_DEFAULT_OPTIONS = {FastOptions: FastOptions(), MultistartOptions: MultistartOptions()}

#: Accepted values of ``method``.
METHODS = tuple(_METHODS)

#: Data vectors fitted together: the working memory of a fit grows with this, not
#: with the number of rows (a batch equals a loop of single fits).
BLOCK_ROWS = 2048

#: Batches of more than this many data vectors x sub-sensors x K^2 say so on stderr
#: before they start: one unit cost 0.2-1 us CPU in batched fast fits (a 10,000-ring
#: at K = 2 0.32 us, a 3000-sphere at K = 4 1.0 us), so such a call takes seconds.
NOTICE_BATCH = 5_000_000


def _result_bytes(p: int) -> int:
    """Bytes of an MLResult per data vector of P parameters (cov, params, scalars, gap)."""
    return 8 * (p * p + p + 6)


def _check_options(model: Model, k: int, method: object, options: object) -> object:
    """The method's options, validated and resolved for the model and K."""
    choice("method", method, METHODS)
    kind = _METHODS[method].options
    if kind is None:
        if options is not None:
            raise InputError(f"method={method!r} takes no options; got {options!r}")
        check_exact(model, k)
        return None
    options = _DEFAULT_OPTIONS[kind] if options is None else options
    if not isinstance(options, kind):
        raise InputError(f"options for method={method!r} must be a {kind.__name__}; got "
                         f"{type(options).__name__}")
    return options.resolve(model, k) if isinstance(options, FastOptions) else options


def fit_plain(model: Model, data: np.ndarray, n_sources: int, method: str = "fast", *,
              options: FastOptions | MultistartOptions | None = None,
              grid: np.ndarray | None = None, rng: np.random.Generator | int | None = None,
              warn: bool = True) -> MLResult:
    """ML fit under Gaussian noise of one known sigma: the search methods of :data:`METHODS`.

    The arguments and the result are those of :func:`olsbayes.ml.fit_ml` (without
    frames); every argument is checked here, before any work.
    """
    arr, k = check_fit_inputs(model, data, n_sources)
    opts = _check_options(model, k, method, options)
    # deterministic methods: validate an rng given, but draw no OS entropy for None
    gen = as_rng(rng) if method == "multistart" or rng is not None else None
    batch = arr.ndim == 2
    s = arr if batch else arr[None, :]
    p = model.n_params(k)
    check_memory(f"fit_ml of {s.shape[0]} data vector(s) x {p} parameters",
                 s.shape[0] * _result_bytes(p))
    if grid is not None:
        grid = check_grid(model, grid)
    if method == "fast":
        m = default_grid_size(model) if grid is None else grid.shape[0]
        check_atom_memory(model, m, min(s.shape[0], BLOCK_ROWS))
    g = cached_default_grid(model) if grid is None else grid
    if method != "exact" and s.shape[0] > 1 and s.shape[0] * model.n_sensors * k * k > NOTICE_BATCH:
        notice(f"fitting {s.shape[0]:,} data vectors of {model.n_sensors:,} readings at "
               f"K = {k} ({method}) ...")
    # rows in blocks, in order (one rng stream): the working arrays of a block are
    # bounded whatever the number of rows
    parts = [_fit_block(model, s[i : i + BLOCK_ROWS], k, method, g, opts, gen)
             for i in range(0, s.shape[0], BLOCK_ROWS)]
    x, ll, cov, gap, conv, nev = parts[0] if len(parts) == 1 else (
        np.concatenate([q[j] for q in parts]) for j in range(6))
    if warn:
        warn_rivals(method, gap, conv)
        warn_honesty(model, x, ll, cov, method)
        _warn_mirror(model, s, x, ll, cov, method)
    sel = (lambda a: a) if batch else (lambda a: a[0])
    return MLResult(params=sel(x), log_likelihood=sel(ll), converged=sel(conv),
                    n_evaluations=sel(nev), cov=sel(cov), rival_gap=sel(gap),
                    method=method, n_sources=k, model=model)


def _fit_block(model: Model, s: np.ndarray, k: int, method: str, g: np.ndarray, opts: object,
               gen: np.random.Generator | None) -> tuple[np.ndarray, ...]:
    """Fit the rows ``s`` (T, N): (x, log L, cov, rival gap, converged, evaluations)."""
    scale = reading_scales(s)  # readings far from order 1: fitted in scaled units
    scaled = bool(np.any(scale != 1.0))
    out = _METHODS[method].run(model, s / scale[:, None] if scaled else s, k, g, opts, gen,
                               scale)
    if scaled:
        out = rescale(model, out, scale)
    x = model.canonical(out.x)
    ll, cov = _statistics(model, x, s)
    std = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    gap = rival_gap(model, x, out.chi2, out.alternatives, std)
    return x, ll, cov, gap, out.converged, out.n_evaluations


def _statistics(model: Model, x: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Log-likelihood (T,) and inverse Fisher matrices (T, P, P) at the estimates x (T, P).

    Of data s (T, N); the inverses by the rule of :func:`olsbayes.bounds.bound_covariance`.
    """
    from ._numba import fit, lm  # numba is imported on first use, not with the package

    if not lm.supports(model):
        return model.log_likelihood(x, s), bound_covariance(model.fisher(x))[0]
    chi2, fisher = fit.chi2_fisher(model, x, s)  # compiled: chi^2 and Fisher in one pass
    n = model.n_sensors
    ll = -0.5 * chi2 / model.sigma**2 - n * (np.log(model.sigma) + 0.5 * np.log(2 * np.pi))
    if np.isfinite(fisher).all():
        return ll, fit.covariances(fisher, SINGULAR_RTOL)
    return ll, bound_covariance(fisher)[0]


def warn_rivals(method: str, gap: np.ndarray, converged: np.ndarray, stacklevel: int = 4) -> None:
    """Warn about rival optima within RIVAL_WARN and about fits that did not converge.

    ``stacklevel`` 4 points at the caller of :func:`olsbayes.ml.fit_ml`.
    """
    close, converged = np.asarray(gap) < RIVAL_WARN, np.asarray(converged)
    if close.any():
        bad = int(close.sum())
        warnings.warn(
            f"{bad} of {close.size} ML fit(s) ({method}) reached a distinct local optimum "
            f"(sources > {DISTINCT_STD:g} Fisher std away) within {RIVAL_WARN:g} of the "
            "estimate's log-likelihood: the likelihood is multimodal there and the Fisher "
            "covariance understates the uncertainty; see MLResult.rival_gap, or sample the "
            "posterior (olsbayes.sample_posterior)",
            MultimodalWarning,
            stacklevel=stacklevel,
        )
    if not converged.all():
        bad = int(np.sum(~converged))
        warnings.warn(
            f"{bad} of {converged.size} ML fit(s) ({method}) did not meet the "
            "convergence criterion of the local optimiser; see MLResult.converged",
            ConvergenceWarning,
            stacklevel=stacklevel,
        )


def _warn_mirror(model: Model, s: np.ndarray, x: np.ndarray, ll: np.ndarray, cov: np.ndarray,
                 method: str) -> None:
    """AntipodalWarning for near-antipodal pairs whose Fisher errors do not hold.

    Either a mirrored configuration is a distinct optimum within RIVAL_WARN, or the
    pairs are where simulation found Fisher intervals under-covering
    (:func:`olsbayes.resolution.antipodal_doubts`).
    """
    if model.kind != "angle" or x.shape[-1] < 2 * (model.n_loc + 1):
        return  # pairs of ring sources only
    if not np.any(np.abs(pair_offsets(model, x)) < max(ANTIPODAL_SPACINGS, ANTIPODAL_DOUBT)):
        return  # no pair near antipodal: neither a mirrored optimum nor a doubt
    std = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    mirrored = mirror_gap(model, s, x, ll, std) < RIVAL_WARN
    finite = np.all(np.isfinite(std), axis=-1)  # singular fits: the ResolutionWarning's
    doubted = antipodal_doubts(model, x) & finite
    bad = mirrored | doubted
    if not np.any(bad):
        return
    why = []
    if mirrored.any():
        why.append("a mirrored configuration (each source at the antipode of the other) "
                   f"that is a distinct optimum within {RIVAL_WARN:g} of the log-likelihood")
    if doubted.any():
        why.append(f"a pair within {ANTIPODAL_DOUBT:g} sensor spacing of antipodal where, in "
                   "simulation, Fisher (CRLB) intervals covered the truth less often than "
                   "stated (far less with two such pairs)")
    warnings.warn(
        f"{int(bad.sum())} of {bad.size} ML fit(s) ({method}) have a pair of sources near "
        f"antipodal with {'; or '.join(why)}: the readings barely tell the pair from its "
        "mirror image and the Fisher covariance describes one optimum; see "
        "olsbayes.antipodal, or sample the posterior (olsbayes.sample_posterior samples "
        "every mode)",
        AntipodalWarning,
        stacklevel=4,
    )
