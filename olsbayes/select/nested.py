"""Nested-sampling evidence with dynesty, always under a cap on likelihood calls.

The prior transform is the priors' ``ppf`` on the unit cube of the full
(unordered, labelled) parameter space, so dynesty integrates over all K! modes
of exchangeable sources -- the same Z_K the Laplace formula reaches with its
log K! term.  Ring angles and sphere longitudes are periodic.  The default
sampler is dynesty's ``rslice`` (random slice sampling), which keeps a bounded
cost on over-complete models (K larger than the truth), where dynesty's default
sampler can run for a very long time; every run is capped by ``maxcall`` anyway.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .._validation import as_rng, integer, positive_float
from ..errors import ConvergenceWarning, InputError

__all__ = ["NestedEvidence", "nested_log_evidence", "SAMPLERS"]

#: dynesty samplers accepted by :func:`nested_log_evidence`.
SAMPLERS = ("rslice", "slice", "rwalk", "unif")


@dataclass(frozen=True, eq=False)
class NestedEvidence:
    """One dynesty run.

    Attributes
    ----------
    log_evidence, error : float
        log Z and dynesty's ``logzerr`` (nats).
    n_calls : int
        Likelihood evaluations used.
    n_iter : int
        Nested-sampling iterations.
    converged : bool
        False if the call cap stopped the run before the remaining-evidence
        tolerance ``dlogz`` was met.
    seconds : float
        Wall time, s.
    samples : ndarray, shape (S, P)
        Dead and live points in the physical space.
    log_weights : ndarray, shape (S,)
        Their log importance weights (normalised).
    """

    log_evidence: float
    error: float
    n_calls: int
    n_iter: int
    converged: bool
    seconds: float
    samples: np.ndarray
    log_weights: np.ndarray


def nested_log_evidence(
    log_likelihood: Callable[[np.ndarray], float],
    prior_transform: Callable[[np.ndarray], np.ndarray],
    ndim: int,
    *,
    periodic: Sequence[int] | None = None,
    rng: np.random.Generator | int | None = None,
    maxcall: int = 200_000,
    n_live: int | None = None,
    dlogz: float = 0.1,
    sample: str = "rslice",
) -> NestedEvidence:
    """Run dynesty's static nested sampler and return log Z +- logzerr.

    Parameters
    ----------
    log_likelihood : callable
        ``f(x) -> float`` for one point x of shape (ndim,).
    prior_transform : callable
        ``g(u) -> x`` from the unit cube to the prior, shape (ndim,) -> (ndim,).
    ndim : int
        Number of parameters (>= 1).
    periodic : sequence of int, optional
        Indices of periodic parameters (ring angles, sphere longitudes).
    rng : Generator or seed, optional
        Randomness; dynesty receives the Generator as ``rstate``.
    maxcall : int
        Cap on likelihood calls (>= 1000); a run stopped by the cap warns
        :class:`~olsbayes.errors.ConvergenceWarning`.
    n_live : int, optional
        Live points (> ndim); default ``max(100, 25 * ndim)``.
    dlogz : float
        Stop when the estimated remaining evidence is below this (nats).
    sample : str
        dynesty sampler, one of :data:`SAMPLERS`.
    """
    import dynesty  # heavy import kept out of `import olsbayes`

    ndim = integer("ndim", ndim, low=1)
    maxcall = integer("maxcall", maxcall, low=1000)
    n_live = max(100, 25 * ndim) if n_live is None else integer("n_live", n_live, low=ndim + 1)
    dlogz = positive_float("dlogz", dlogz)
    if sample not in SAMPLERS:
        raise InputError(f"sample must be one of {SAMPLERS}; got {sample!r}")
    per = None if not periodic else [integer("periodic index", i, low=0, high=ndim - 1)
                                      for i in periodic]
    gen = as_rng(rng)
    t0 = time.perf_counter()
    sampler = dynesty.NestedSampler(
        log_likelihood,
        prior_transform,
        ndim,
        nlive=n_live,
        bound="multi",
        sample=sample,
        periodic=per,
        rstate=gen,
    )
    # the initial live points cost n_live calls that run_nested's cap does not count
    with warnings.catch_warnings():  # dynesty's own cap warning is replaced by ours below
        warnings.filterwarnings("ignore", message="The sampling was stopped short")
        sampler.run_nested(maxcall=max(maxcall - n_live, 1), dlogz=dlogz, print_progress=False)
    res = sampler.results
    n_calls = int(np.sum(res.ncall)) + n_live
    converged = n_calls < maxcall
    if not converged:
        warnings.warn(
            f"nested sampling stopped at the cap maxcall={maxcall} before the remaining "
            f"evidence fell below dlogz={dlogz}; log Z is then biased low",
            ConvergenceWarning,
            stacklevel=2,
        )
    logwt = np.asarray(res.logwt) - res.logz[-1]
    return NestedEvidence(
        log_evidence=float(res.logz[-1]),
        error=float(res.logzerr[-1]),
        n_calls=n_calls,
        n_iter=int(res.niter),
        converged=converged,
        seconds=time.perf_counter() - t0,
        samples=np.asarray(res.samples),
        log_weights=logwt,
    )
