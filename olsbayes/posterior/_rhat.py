"""The R-hat half of the stopping rule: rank-normalised split R-hat on the kept draws.

:func:`rank_rhat` is ArviZ's default R-hat (``arviz.rhat(method="rank")``, Vehtari
et al. 2021) of one parameter in plain numpy: the larger of the bulk R-hat (split
chains, draws replaced by the normal scores of their pooled average ranks) and the
tail R-hat (the same of the draws' absolute deviations from their median).  It
equals ArviZ's value to rounding without building an xarray dataset per call.

:class:`RhatCheck` applies it to the draws the result keeps, as the stopping rule
needs it: parameter by parameter, stopping at the first one above the bound.
"""

from __future__ import annotations

import numpy as np

from .._mcmc_diagnostics import split_rhat
from ..circular import circular_mean, wrap_angle
from ..priors import ScenePrior
from ._labels import relabel
from ._logpost import LogPosterior

__all__ = ["rank_rhat", "average_ranks", "RhatCheck"]


def average_ranks(values: np.ndarray) -> np.ndarray:
    """Ranks 1..n of ``values`` (n,), ties given their average rank (``scipy.stats.rankdata``)."""
    order = np.argsort(values)
    return _ranks(values[order], order)


def _ranks(ordered: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Average ranks of the values whose sorted copy ``ordered`` is ``values[order]``."""
    new = np.empty(ordered.size, dtype=bool)
    new[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=new[1:])
    starts = np.flatnonzero(new)
    ends = np.append(starts[1:], ordered.size)
    ranks = np.empty(ordered.size)
    ranks[order] = np.repeat(0.5 * (starts + ends + 1), ends - starts)
    return ranks


def _scores(split: np.ndarray) -> np.ndarray:
    """Normal scores ``ndtri((r - 3/8) / (n + 1/4))`` of the pooled average ranks r of ``split``.

    ``split`` (chains, draws) holds n values.  A walker that rejects a proposal
    repeats its position, so the chains are runs of equal values: the runs are
    sorted instead of the draws, each distinct value's average rank is counted
    from the run lengths (``(first + last) / 2`` of the positions its copies
    would take in the full sort) and its score is spread back over its runs --
    the same ranks, hence the same scores, as ranking every draw (which is
    done when fewer than half the draws repeat their predecessor).
    """
    from scipy.special import ndtri  # on use: scipy is slow to import
    values = split.ravel()
    head = np.empty(values.size, dtype=bool)
    head[:1] = True
    np.not_equal(values[1:], values[:-1], out=head[1:])
    head[::split.shape[1]] = True  # every chain starts a run
    starts = np.flatnonzero(head)
    if 2 * starts.size > values.size:  # few repeats: rank the draws themselves
        rank = average_ranks(values)
        return ndtri((rank - 0.375) / (rank.size + 0.25)).reshape(split.shape)
    lengths = np.diff(np.append(starts, values.size))
    order = np.argsort(values[starts])
    ordered = values[starts][order]
    new = np.empty(ordered.size, dtype=bool)
    new[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=new[1:])
    first = np.flatnonzero(new)  # the sorted runs where a distinct value starts
    position = np.concatenate([[0], np.cumsum(lengths[order])])
    low, high = position[first], position[np.append(first[1:], ordered.size)]
    score = ndtri((0.5 * (low + high + 1) - 0.375) / (values.size + 0.25))
    run_score = np.empty(ordered.size)
    run_score[order] = np.repeat(score, np.diff(np.append(first, ordered.size)))
    return np.repeat(run_score, lengths).reshape(split.shape)


def _split_rhat_of_scores(split: np.ndarray) -> float:
    """Split R-hat of (2 chains, half) draws after their normal-score transform."""
    return float(split_rhat(_scores(split)[:, :, None])[0])


def rank_rhat(draws: np.ndarray, bound: float = np.inf) -> float:
    """Rank-normalised split R-hat of one parameter's draws (chains, draws).

    NaN with fewer than 2 chains or 4 draws, or when a draw is NaN (as ArviZ).
    With a finite ``bound``, a bulk R-hat not below it is returned at once (the
    tail R-hat cannot bring the maximum below the bound).
    """
    x = np.asarray(draws, dtype=float)
    if x.ndim != 2 or x.shape[0] < 2 or x.shape[1] < 4 or np.isnan(x).any():
        return float("nan")
    half = x.shape[1] // 2
    split = np.concatenate([x[:, :half], x[:, -half:]])
    bulk = _split_rhat_of_scores(split)
    if not bulk < bound:
        return bulk
    tail = _split_rhat_of_scores(np.abs(split - np.median(split)))
    return max(bulk, tail)


class RhatCheck:
    """``check(tmax, upto)``: whether max R-hat < ``rhat_max`` on the first ``upto`` steps.

    The draws checked are those the result keeps (burn-in ``ceil(5 tmax)`` at most
    half the run, thin 1, angles unwrapped around their circular means), so a
    converged result reports R-hat < ``rhat_max``.  Raw draws are tried first;
    they are relabelled only if they fail and K > 1, and only if relabelling every
    ``ceil(tmax)``-th step (one draw per autocorrelation time, a cheap screen)
    changes some draw's labels: a walker whose sources swap stays swapped for a
    stretch of steps, so a chain with label switches shows them on the thinned
    draws too.  A relabelling that permutes every draw alike leaves the set of
    R-hat values as it was and is not checked again.  R-hat is computed parameter
    by parameter and the check stops at the first one above the bound, starting
    with the one that failed last time.  ``last`` holds the R-hat of the parameter
    that failed last (NaN before any failure).
    """

    def __init__(self, sampler, logpost: LogPosterior, rhat_max: float | None):
        self.sampler, self.logpost, self.rhat_max = sampler, logpost, rhat_max
        self.prior: ScenePrior = logpost.prior
        self.first = 0  # the parameter that failed last: checked first next time
        self.last = float("nan")

    def below(self, x: np.ndarray) -> bool:
        """max R-hat of draws x (W, D, P) < rhat_max, stopping at the first above."""
        column = _unwrapped_columns(x, self.prior)
        order = [self.first] + [j for j in range(x.shape[-1]) if j != self.first]
        for j in order:
            value = rank_rhat(column(j), self.rhat_max)
            if not value < self.rhat_max:
                self.first, self.last = j, value
                return False
        return True

    def __call__(self, tmax: float, upto: int) -> bool:
        """Whether the kept draws of the first ``upto`` steps pass (tau estimate ``tmax``)."""
        if self.rhat_max is None:
            return True
        prior, logpost = self.prior, self.logpost
        chain = self.sampler.get_chain()[:upto]
        n_burn = min(int(np.ceil(5 * tmax)), chain.shape[0] // 2)
        z = chain[n_burn:].swapaxes(0, 1)
        x = logpost.to_params(z)
        if self.below(x):
            return True
        if prior.n_sources < 2:
            return False
        lpost = self.sampler.get_log_prob()[n_burn:upto].T - logpost.jacobian(z)
        periodic = prior.periodic[: prior.n_loc + 1]
        stride = max(1, int(np.ceil(tmax)))
        if stride > 1 and _one_permutation(relabel(
                x[:, ::stride], prior.n_sources, periodic, lpost[:, ::stride])[1]):
            return False  # no label switch on the thinned draws
        x, perms = relabel(x, prior.n_sources, periodic, lpost)
        if _one_permutation(perms):
            return False  # every draw permuted alike: the same values that just failed
        return self.below(x)


def _one_permutation(perms: np.ndarray) -> bool:
    """Whether every draw of ``perms`` (..., K) has the same permutation."""
    flat = perms.reshape(-1, perms.shape[-1])
    return bool(np.all(flat == flat[0]))


def _unwrapped_columns(x: np.ndarray, prior: ScenePrior):
    """``column(j)``: column j (W, D) of draws x (W, D, P), angles unwrapped on demand.

    An angle column is ``centre + wrap(x - centre)`` around the circular mean of
    its draws (the means of all angles computed at once), as
    :func:`olsbayes.circular.unwrap_around`; a column is unwrapped only when asked
    for, and the check stops at the first parameter above the bound.
    """
    per = prior.periodic
    centre = np.zeros(per.size)
    if per.any():
        centre[per] = circular_mean(x[..., per].reshape(-1, int(per.sum())), axis=0)

    def column(j: int) -> np.ndarray:
        if not per[j]:
            return x[..., j]
        return centre[j] + wrap_angle(x[..., j] - centre[j])

    return column

