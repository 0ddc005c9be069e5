"""Nested-sampling evidence whose error bar includes the scatter between independent runs.

One dynesty run quotes ``logzerr``, the spread of log Z over the random volume
shrinkage of *that* run's path.  It cannot see a mode the run never found: on an
over-complete K (the extra source splits off any true one) runs that lose a mode
scatter by several nats while each quotes a few tenths.  Here R independent runs
(own random streams, each with ``n_live`` live points) are combined:

* estimate: Z = mean of the runs' Z_r (each run is an estimate of the same Z;
  their mean is the evidence of the merged run with R n_live live points);
* within-run error: the runs' own errors propagated to log of the mean,
  ``e_w^2 = sum_r (Z_r / sum Z)^2 e_r^2``;
* between-run error: the standard error of that mean from the runs' scatter,
  ``e_b = sd(Z_r / Z) / sqrt(R)`` (the importance sampler's rule; for small
  scatter it is ``sd(log Z_r) / sqrt(R)``);
* quoted error ``hypot(e_w, e_b)``.  When every run is honest both terms
  estimate the same number, the sum is sqrt(2) times it -- a deliberate margin,
  since an R = 3 sample sd alone (2 degrees of freedom) is too noisy to carry a
  Gaussian interval; when runs lose modes the scatter term dominates.

Runs that differ by more than ``3 hypot(e_r, e_s)`` are reported
(``disagree``): some found posterior mass the others missed, and the evidence is
a lower bound whatever its error says.

The call cap of each run scales with the problem (:func:`scaled_maxcall`): the
number of nested-sampling iterations is about ``n_live (H + few)`` with H the
information (prior-to-posterior KL, nats) -- here bounded by ``h_param`` nats per
parameter -- and dynesty's ``rslice`` sampler spends ``3 + P`` slices of a few
calls each per iteration.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .._budget import memory_limit
from .._validation import as_rng, integer, positive_float
from .nested import NestedCheckpoint, NestedEvidence, nested_log_evidence

__all__ = ["RepeatedEvidence", "combine_runs", "repeated_log_evidence", "scaled_maxcall"]

#: Likelihood calls per slice of dynesty's ``rslice`` sampler (stepping out and
#: shrinking), used by :func:`scaled_maxcall`.
CALLS_PER_SLICE = 6


@dataclass(frozen=True, eq=False)
class RepeatedEvidence:
    """log Z from R independent nested runs.

    Attributes
    ----------
    log_evidence : float
        log of the mean of the runs' evidences (nats).
    error : float
        ``hypot(within, between)`` (nats).
    within, between : float
        The runs' own errors propagated to the combination, and the standard
        error of the mean from their scatter (nats).
    runs : tuple of NestedEvidence
        The individual runs.
    disagree : bool
        Some pair of runs differs by more than three of their combined errors.
    """

    log_evidence: float
    error: float
    within: float
    between: float
    runs: tuple[NestedEvidence, ...]
    disagree: bool

    @property
    def n_calls(self) -> int:
        """Likelihood calls of all runs."""
        return int(sum(r.n_calls for r in self.runs))

    @property
    def converged(self) -> bool:
        """Whether every run met its ``dlogz`` tolerance before its call cap."""
        return all(r.converged for r in self.runs)

    @property
    def seconds(self) -> float:
        """Wall time of all runs, s."""
        return float(sum(r.seconds for r in self.runs))

    @property
    def spread(self) -> float:
        """Largest minus smallest log Z of the runs (nats)."""
        z = [r.log_evidence for r in self.runs]
        return float(max(z) - min(z))

    def __repr__(self) -> str:
        return (f"RepeatedEvidence(log_evidence={self.log_evidence:.3f}, "
                f"error={self.error:.3f}, runs={len(self.runs)}, disagree={self.disagree})")


def combine_runs(runs: Sequence[NestedEvidence]) -> RepeatedEvidence:
    """Combine independent nested runs of the same evidence (module notes).

    Parameters
    ----------
    runs : sequence of NestedEvidence
        At least one run; with one run ``between`` is 0 and the error is the run's.

    Returns
    -------
    RepeatedEvidence
    """
    from scipy.special import logsumexp  # on use: scipy is slow to import
    runs = tuple(runs)
    if not runs:
        raise ValueError("combine_runs needs at least one run")
    log_z = np.array([r.log_evidence for r in runs], dtype=float)
    err = np.array([r.error for r in runs], dtype=float)
    n = log_z.size
    comb = float(logsumexp(log_z) - math.log(n))
    share = np.exp(log_z - logsumexp(log_z))  # Z_r / sum Z
    within = float(math.sqrt(np.sum(share**2 * err**2)))
    between = float(np.std(np.exp(log_z - comb), ddof=1) / math.sqrt(n)) if n > 1 else 0.0
    gap = np.abs(log_z[:, None] - log_z[None, :])
    disagree = bool(np.any(gap > 3.0 * np.hypot(err[:, None], err[None, :])))
    return RepeatedEvidence(log_evidence=comb, error=float(math.hypot(within, between)),
                            within=within, between=between, runs=runs, disagree=disagree)


def scaled_maxcall(n_params: int, n_live: int, *, h_param: float = 10.0,
                   n_sensors: int = 0, n_runs: int = 1) -> int:
    """Call cap of one nested run for P parameters and ``n_live`` live points.

    ``n_live (P h_param + 10) (3 + P) CALLS_PER_SLICE``: iterations to compress
    the prior by ``h_param`` nats per parameter plus 10 nats of stopping margin,
    times dynesty's ``rslice`` calls per iteration.  At most the calls whose
    saved points (P + 4 floats each, plus the ``n_live`` live points with their
    N-reading responses) of ``n_runs`` kept runs fit in the memory budget
    (:func:`olsbayes._budget.memory_limit`), and at least 1000.

    Parameters
    ----------
    n_params : int
        P >= 1.
    n_live : int
        Live points (> P).
    h_param : float
        Information per parameter, nats (> 0); about ``log(prior width /
        posterior sd)``, which is 5-8 for a direction or an intensity at
        SNR 10^2-10^3.
    n_sensors : int
        Readings N per likelihood call (only for the memory bound).
    n_runs : int
        Runs whose saved points are kept together (>= 1; only for the memory bound).
    """
    p = integer("n_params", n_params, low=1)
    live = integer("n_live", n_live, low=p + 1)
    h = positive_float("h_param", h_param)
    calls = live * (p * h + 10.0) * (3 + p) * CALLS_PER_SLICE
    live_bytes = 8.0 * live * (integer("n_sensors", n_sensors, low=0) + p) * 4
    runs = integer("n_runs", n_runs, low=1)
    by_memory = (memory_limit() / runs - live_bytes) / (8.0 * (p + 4))
    return int(max(1000, min(calls, by_memory)))


def repeated_log_evidence(
    log_likelihood: Callable[[np.ndarray], float],
    prior_transform: Callable[[np.ndarray], np.ndarray],
    ndim: int,
    *,
    n_runs: int = 3,
    rng: np.random.Generator | int | None = None,
    maxcall: int | None = None,
    n_live: int | None = None,
    checkpoints: Sequence[NestedCheckpoint | None] | None = None,
    **kwargs,
) -> RepeatedEvidence:
    """log Z from ``n_runs`` independent :func:`~olsbayes.select.nested.nested_log_evidence` runs.

    Parameters
    ----------
    log_likelihood, prior_transform, ndim
        As for :func:`~olsbayes.select.nested.nested_log_evidence`.
    n_runs : int
        Independent runs (>= 1), each on its own stream spawned from ``rng``.
    rng : Generator or seed, optional
    maxcall : int or None
        Cap on the calls of *each* run; None: :func:`scaled_maxcall`.
    n_live : int or None
        Live points of each run; None: ``max(100, 25 ndim)``.
    checkpoints : sequence of NestedCheckpoint or None, optional
        One checkpoint per run (``n_runs`` of them), or None.
    **kwargs
        ``periodic``, ``dlogz``, ``sample``, ``progress`` of ``nested_log_evidence``.

    Returns
    -------
    RepeatedEvidence
    """
    ndim = integer("ndim", ndim, low=1)
    n_runs = integer("n_runs", n_runs, low=1)
    live = max(100, 25 * ndim) if n_live is None else integer("n_live", n_live, low=ndim + 1)
    cap = (scaled_maxcall(ndim, live, n_runs=n_runs) if maxcall is None
           else integer("maxcall", maxcall, low=1000))
    if checkpoints is None:
        checkpoints = [None] * n_runs
    elif len(checkpoints) != n_runs:
        raise ValueError(f"checkpoints must hold one entry per run ({n_runs}); "
                         f"got {len(checkpoints)}")
    streams = as_rng(rng).spawn(n_runs)
    runs = [nested_log_evidence(log_likelihood, prior_transform, ndim, rng=s, maxcall=cap,
                                n_live=live, checkpoint=c, **kwargs)
            for s, c in zip(streams, checkpoints)]
    return combine_runs(runs)
