"""The emcee run: an ensemble stepped until its autocorrelation and R-hat criteria hold."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..circular import circular_mean, wrap_angle
from ..priors import ScenePrior
from ._arviz import rhat_array
from ._labels import relabel
from ._logpost import LogPosterior
from .options import SamplerOptions, emcee_moves

__all__ = ["make_sampler", "run_ensemble"]


def make_sampler(logpost: LogPosterior, n_walkers: int, options: SamplerOptions,
                 gen: np.random.Generator):
    """An ``emcee.EnsembleSampler`` on ``logpost`` whose random state is seeded from ``gen``."""
    import emcee

    vectorize = options.vectorize
    fn = logpost if vectorize else (lambda z: float(logpost(z)))
    sampler = emcee.EnsembleSampler(n_walkers, logpost.prior.n_params, fn, vectorize=vectorize,
                                    moves=emcee_moves(options.moves))
    seed = int(gen.integers(2**32))
    sampler.random_state = np.random.RandomState(seed).get_state()
    return sampler


def run_ensemble(sampler, z0: np.ndarray, logpost: LogPosterior, options: SamplerOptions,
                 progress: bool) -> bool:
    """Step from ``z0`` (W, P); True if the convergence criteria held before the limit.

    Without ``options.n_steps`` the run stops once ``n >= tau_multiple * tau`` (tau
    stable to 10 %) and R-hat < ``rhat_max``, checked every ``check_every`` steps,
    or at ``max_steps``.  R-hat is costlier than tau, so once the tau criterion
    holds it is checked at steps growing by 25 % at least.  With ``n_steps`` the
    run takes exactly that many steps and returns False.
    """
    import emcee

    fixed = options.n_steps is not None
    rhat_ok = _rhat_checker(sampler, logpost, logpost.prior, options.rhat_max)
    old = np.inf
    next_rhat = 0
    for _ in sampler.sample(emcee.State(z0), iterations=options.step_limit, progress=progress):
        it = sampler.iteration
        if fixed or it % options.check_every:
            continue
        tau = sampler.get_autocorr_time(tol=0)
        tmax = float(np.max(tau))
        stable = abs(old - tmax) < 0.1 * tmax
        old = tmax
        if (np.isfinite(tmax) and it >= options.tau_multiple * tmax and stable
                and it >= next_rhat):
            if rhat_ok(tmax):
                return True
            next_rhat = int(1.25 * it)
    return False


def _rhat_checker(sampler, logpost: LogPosterior, prior: ScenePrior, rhat_max: float | None
                  ) -> Callable[[float], bool]:
    """Closure: True when the post-burn-in draws have max R-hat < rhat_max.

    The draws checked are those the result keeps (same burn-in, thin 1), so a
    converged result reports R-hat < rhat_max.  Raw draws are tried first; they
    are relabelled only if they fail and K > 1.
    """

    def check(tmax: float) -> bool:
        if rhat_max is None:
            return True
        chain = sampler.get_chain()
        n_burn = min(int(np.ceil(5 * tmax)), chain.shape[0] // 2)
        z = chain[n_burn:].swapaxes(0, 1)
        x = logpost.to_params(z)
        if _rhat_max(x, prior) < rhat_max:
            return True
        if prior.n_sources < 2:
            return False
        lpost = sampler.get_log_prob()[n_burn:].T - logpost.jacobian(z)
        x, perms = relabel(x, prior.n_sources, prior.periodic[: prior.n_loc + 1], lpost)
        if np.all(perms == np.arange(prior.n_sources)):
            return False  # nothing relabelled: the same draws that just failed
        return _rhat_max(x, prior) < rhat_max

    return check


def _rhat_max(x: np.ndarray, prior: ScenePrior) -> float:
    """Largest split R-hat over the parameters of draws (W, D, P).

    Angles are unwrapped around their circular means.
    """
    if prior.periodic.any():
        per = prior.periodic
        centre = circular_mean(x[..., per].reshape(-1, int(per.sum())), axis=0)
        x = x.copy()
        x[..., per] = centre + wrap_angle(x[..., per] - centre)
    return float(np.max(rhat_array(x)))
