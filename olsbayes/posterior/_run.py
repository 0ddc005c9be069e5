"""The emcee run: an ensemble stepped until its autocorrelation and R-hat criteria hold."""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import as_strided

from .._one import sum_products
from .._progress import progress_bar
from ._checkpoint import ChainCheckpoint
from ._logpost import LogPosterior
from ._rhat import RhatCheck
from .options import SamplerOptions, emcee_moves

__all__ = ["make_sampler", "posterior_bar", "run_ensemble", "AutocorrTime"]


def make_sampler(logpost: LogPosterior, n_walkers: int, options: SamplerOptions,
                 gen: np.random.Generator):
    """An ``emcee.EnsembleSampler`` on ``logpost`` whose random state is seeded from ``gen``."""
    import emcee

    vectorize = options.vectorize
    fn = logpost if vectorize else (lambda z: float(logpost(z)))
    cls = _vector_sampler_class() if vectorize else emcee.EnsembleSampler
    sampler = cls(n_walkers, logpost.prior.n_params, fn, vectorize=vectorize,
                  moves=emcee_moves(options.moves))
    seed = int(gen.integers(2**32))
    sampler.random_state = np.random.RandomState(seed).get_state()
    return sampler


def posterior_bar(enabled: bool, options: SamplerOptions) -> Any:
    """The status line of one ensemble run: steps taken (of ``n_steps`` when fixed).

    Made by the caller of :func:`run_ensemble`, so that it spans the run's set-up and
    the assembly of its draws as well as the steps: a call that lasts shows it after
    :data:`~olsbayes._progress.DELAY` seconds whichever part is running.
    """
    return progress_bar(enabled=enabled, desc="posterior", unit=" steps",
                        total=options.n_steps)


@functools.cache
def _vector_sampler_class() -> type:
    """``emcee.EnsembleSampler`` taking the log-posterior's float array (W,) as it is.

    emcee turns a vectorised log-probability into floats walker by walker (and
    first looks for blobs in each entry); :class:`LogPosterior` returns a float
    array without blobs, so one conversion gives the same numbers.  The checks
    (no infinite or NaN position, no NaN log-probability) are emcee's.  With
    ``lean_state`` the sampler's ``random_state`` reads None, so emcee does not copy
    the generator's state into every step's ``State`` (reading it draws nothing).
    """
    import emcee

    class VectorSampler(emcee.EnsembleSampler):
        #: True: emcee's copy of the generator's state into every step's State is
        #: skipped (a 624-word copy per step that only a checkpoint reads; the draws
        #: are the same).
        lean_state = False

        @property
        def random_state(self):
            if self.lean_state:
                return None
            return emcee.EnsembleSampler.random_state.fget(self)

        @random_state.setter
        def random_state(self, state):
            emcee.EnsembleSampler.random_state.fset(self, state)

        def compute_log_prob(self, coords):
            if self.params_are_named:  # pragma: no cover - the package never names them
                return super().compute_log_prob(coords)
            if np.any(np.isinf(coords)):
                raise ValueError("At least one parameter value was infinite")
            if np.any(np.isnan(coords)):
                raise ValueError("At least one parameter value was NaN")
            log_prob = np.array(self.log_prob_fn(coords), dtype=float).reshape(len(coords))
            if np.any(np.isnan(log_prob)):
                raise ValueError("Probability function returned NaN")
            return log_prob, None

    return VectorSampler


def run_ensemble(sampler, z0: np.ndarray, logpost: LogPosterior, options: SamplerOptions,
                 bar: Any, checkpoint: ChainCheckpoint | None = None,
                 seed: int | None = None) -> bool:
    """Step from ``z0`` (W, P); True if the convergence criteria held before the limit.

    Without ``options.n_steps`` the run stops once ``n >= tau_multiple * tau`` (tau
    stable to 10 %) and R-hat < ``rhat_max``, checked every ``check_every`` steps,
    or at ``max_steps``; tau is emcee's estimate, kept up to date incrementally
    (:class:`AutocorrTime`).  R-hat is costlier than tau, so once the tau criterion
    holds it is checked at steps growing by 25 % at least.  With ``n_steps`` the
    run takes exactly that many steps and returns False.

    ``bar`` (:func:`posterior_bar`) counts the steps taken and shows the stopping
    rule's state (tau and the steps it asks for, the last R-hat against its bound).
    ``checkpoint``: steps already stored there are loaded first (their convergence
    checks replayed) and the run continues from the last one; the file is written
    as the run goes, when it stops and when it is interrupted (``seed`` recorded).
    """
    watch = _Convergence(sampler, logpost, options, AutocorrTime(z0))
    start, done = z0, 0
    if checkpoint is not None:
        done = checkpoint.restore(sampler)
        if done:
            start = sampler.get_last_sample()
            replay = () if watch.fixed else range(options.check_every, done + 1,
                                                  options.check_every)
            if any(watch.check(it) for it in replay):
                return True  # it had converged at a check already stored
    import emcee

    sampler.lean_state = checkpoint is None  # only a checkpoint reads the per-step state
    bar.initial = bar.n = bar.last_print_n = done  # steps loaded: not in the rate
    try:
        for _ in sampler.sample(emcee.State(start), progress=False,
                                iterations=max(options.step_limit - done, 0)):
            bar.update(1)
            if checkpoint is not None:
                checkpoint.seen(sampler, seed)
            it = sampler.iteration
            if watch.fixed or it % options.check_every:
                continue
            stop = watch.check(it)
            bar.set_postfix_str(watch.status, refresh=False)
            if stop:
                return True
    finally:
        if checkpoint is not None:
            checkpoint.write(sampler, seed)
    return False


class _Convergence:
    """The stopping rule's state across checks: the last tau, the next R-hat check."""

    def __init__(self, sampler, logpost: LogPosterior, options: SamplerOptions,
                 autocorr: AutocorrTime):
        self.sampler, self.options, self.autocorr = sampler, options, autocorr
        self.fixed = options.n_steps is not None
        self.rhat_ok = RhatCheck(sampler, logpost, options.rhat_max)
        self.old, self.next_rhat = np.inf, 0
        self.status = ""

    def check(self, it: int) -> bool:
        """Whether the criteria hold on the first ``it`` steps (a multiple of check_every)."""
        opts = self.options
        tau = self.autocorr.update(self.sampler.get_chain()[:it])
        tmax = float(np.max(tau))
        stable = abs(self.old - tmax) < 0.1 * tmax
        self.old = tmax
        self.status = f"tau {tmax:.0f} -> {opts.tau_multiple * tmax:.0f} steps needed"
        if (np.isfinite(tmax) and it >= opts.tau_multiple * tmax and stable
                and it >= self.next_rhat):
            if self.rhat_ok(tmax, it):
                return True
            self.next_rhat = int(1.25 * it)
        if np.isfinite(self.rhat_ok.last):  # the last R-hat measured, until the next
            self.status += f", R-hat {self.rhat_ok.last:.3f} -> needs < {opts.rhat_max:g}"
        return False


class AutocorrTime:
    """emcee's integrated autocorrelation time of a growing chain, at a cost per new step.

    emcee's estimate (``integrated_time`` with ``c = 5``) of a chain of n steps:
    for every walker and parameter the autocovariance of the centred series at
    lags 0..n-1, normalised by its lag-0 value and averaged over the walkers;
    ``taus = 2 cumsum - 1``; tau = ``taus[M]`` at the first lag M with
    ``M >= 5 taus[M]`` (tau = 1 if there is none).  emcee recomputes it by FFT of
    the whole chain; here the lag sums ``sum_t y_t y_(t+lag)`` of ``y = z - z_0``
    are accumulated as steps arrive, for lags up to a bound L that doubles
    whenever the window M may lie beyond it, and the centring is applied
    algebraically, ``sum (y_t - m)(y_(t+lag) - m) = S(lag) - m (A + B) + (n - lag) m^2``
    with A, B the sums of the first and last n - lag values.  The result equals
    emcee's up to rounding.

    Parameters
    ----------
    z0 : ndarray (W, P)
        The walkers' start (the reference subtracted to keep the sums well conditioned).
    max_lag : int
        Initial lag bound L.
    """

    def __init__(self, z0: np.ndarray, max_lag: int = 64):
        self._ref = np.array(z0, dtype=float)
        self._lags = np.zeros((max_lag + 1,) + self._ref.shape)
        self._total = np.zeros(self._ref.shape)  # sum of y over the steps absorbed
        self._n = 0  # steps absorbed

    def update(self, chain: np.ndarray) -> np.ndarray:
        """tau (P,) of ``chain`` (n, W, P), whose first steps are those seen before."""
        n = chain.shape[0]
        self._total += (chain[self._n:n] - self._ref).sum(axis=0)
        self._absorb(chain, self._n, n)
        self._n = n
        while True:
            tau, found = self._estimate(chain, n)
            if found or self._lags.shape[0] >= n:
                return tau
            self._lags = np.zeros((2 * self._lags.shape[0] - 1,) + self._ref.shape)
            self._absorb(chain, 0, n)

    def _absorb(self, chain: np.ndarray, start: int, stop: int) -> None:
        """Add the products of steps start..stop-1 with their predecessors to the lag sums."""
        n_lag = self._lags.shape[0]
        lo = max(0, start - n_lag + 1)
        y = chain[lo:stop] - self._ref  # the new steps and the n_lag - 1 before them
        shared = min(n_lag, start + 1) if start < stop else 0
        if shared:  # lags up to ``start``: all sum over the new steps, in one kernel call
            now = y[start - lo:]
            back = as_strided(now, shape=(shared,) + now.shape,
                              strides=(-now.strides[0],) + now.strides, writeable=False)
            self._lags[:shared] += sum_products("lt...,t...->l...", back, now)
        for lag in range(shared, min(n_lag, stop)):
            first = max(start, lag) - lo
            if first < stop - lo:
                self._lags[lag] += sum_products("t...,t...->...", y[first - lag:stop - lo - lag],
                                                y[first:])

    def _estimate(self, chain: np.ndarray, n: int) -> tuple[np.ndarray, bool]:
        """(tau (P,), whether every parameter's window lies within the lag bound)."""
        n_lag = min(self._lags.shape[0], n)
        zero = np.zeros((1,) + self._ref.shape)
        head = np.concatenate([zero, np.cumsum(chain[:n_lag - 1] - self._ref, axis=0)])
        tail = np.concatenate([zero, np.cumsum(chain[n - 1:n - n_lag:-1] - self._ref, axis=0)])
        total, mean = self._total, self._total / n
        lag = np.arange(n_lag)[:, None, None]
        acov = self._lags[:n_lag] - mean * (2 * total - head - tail) + (n - lag) * mean**2
        with np.errstate(invalid="ignore", divide="ignore"):
            rho = (acov / acov[0]).mean(axis=1)  # (n_lag, P)
        taus = 2.0 * np.cumsum(rho, axis=0) - 1.0
        inside = np.arange(n_lag)[:, None] < 5.0 * taus  # emcee's auto_window, c = 5
        beyond = inside.all(axis=0)  # no window within the bound
        window = np.where(beyond, 0, np.argmin(inside, axis=0))
        window = np.where(~inside.any(axis=0), n_lag - 1, window)
        tau = taus[window, np.arange(taus.shape[1])]
        return tau, bool(not beyond.any() or n_lag >= n)
