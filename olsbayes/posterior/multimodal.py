"""A posterior sampler that stays calibrated on multimodal posteriors.

An emcee ensemble started in one mode samples that mode: its walkers do not
cross the valleys between the optima of a multimodal likelihood, and it reports
the one mode as the posterior.  This sampler runs one ensemble per mode found by
:func:`~.modes.find_modes` (each started in a CRLB-shaped ball around its
optimum, each run to the options' convergence criteria), weighs the modes by
their evidence and pools the draws:

* the evidence of mode m, ``Z_m = int_{mode m} L(x) pi(x) dx``, by importance
  sampling from a multivariate Student-t (5 degrees of freedom) with the mean
  and covariance of the ensemble's draws, in the sampler's coordinates:
  ``log Z_m = log mean_i L(x_i) pi(x_i) / q(x_i)``, standard error
  ``sd(w) / (mean(w) sqrt(n))`` (delta method);
* the space is cut into one cell per mode (the nearest mode, distances in
  CRLB sd, :func:`nearest_mode`); the mass of cell m is estimated from run m
  alone, ``Z_m f_m`` with ``f_m`` the share of run m's draws inside cell m, and
  its draws are run m's draws inside it.  Where modes are disjoint ``f_m = 1``;
  where two runs explore one connected region (optima joined by a ridge), each
  supplies its own cell and the region is not counted twice;
* every stored draw of the result is taken from cell m with probability
  ``Z_m f_m / sum_j Z_j f_j`` (systematic allocation, then shuffled).

The result is an ordinary :class:`~.result.PosteriorResult` (the same
InferenceData), labelled as the ML point; ``result.modes``
(:class:`~.modes.ModeReport`) lists the modes, their evidences and weights.  Its
``tau`` is the largest over the modes, ``n_steps`` the stored steps per walker of
the pooled draws, ``converged`` whether every mode's run converged.

When it is used (``SamplerOptions.multimodal``): True always, False never,
None (default) when two ring sources are within ``antipodal_spacings`` sensor
spacings of antipodal (:mod:`olsbayes.antipodal`), both intensities at least
:data:`olsbayes.resolution.WEAK_SDS` Cramer-Rao sd above zero, and no two sources
of the ML point are closer than the resolution limit
(:data:`olsbayes.resolution.RESOLUTION_SPACINGS`) -- and, when
:class:`~.modes.ModeOptions` switches them on, when the ML fit reached a rival
optimum within 3 of its log-likelihood (``MLResult.rival_gap``, ``on_rival``) or
the Fisher matrix at the ML point is near-singular (``on_singular``) -- and then
only if the search finds more than one mode; also, under ``crlb_alarm``, after a
default run whose posterior sd is far below the CRLB at high SNR.
"""

from __future__ import annotations

import numpy as np

from ..antipodal import antipodal_pairs
from ..bounds import bound_covariance
from ..ml.rivals import RIVAL_WARN
from ..resolution import RESOLUTION_SPACINGS, min_separation, weak_sources
from ._start import ball_covariance, initial_ensemble
from .modes import ModeOptions

__all__ = ["trigger_reason", "model_point", "mode_walkers", "mode_evidence", "pool_labels",
           "PooledChain", "nearest_mode"]


def trigger_reason(model, centre: np.ndarray, rival_gap: float, options: ModeOptions) -> str:
    """Why the automatic choice looks for modes around ``centre`` (P_model,); "" if not."""
    reasons = []
    if options.on_rival and np.isfinite(rival_gap) and rival_gap < RIVAL_WARN:
        reasons.append(f"a rival ML optimum within {rival_gap:.2g} of the log-likelihood")
    pairs = antipodal_pairs(model, centre, within=options.antipodal_spacings)
    if pairs and not _crowded(model, centre):
        pairs = _pinned(model, centre, pairs)
        if pairs:
            what = ", ".join(f"({i}, {j}) {off:+.2f}" for i, j, off in pairs)
            reasons.append(f"near-antipodal source pair(s) {what} sensor spacings from pi")
    if options.on_singular and centre.size:
        _, cond, _ = bound_covariance(model.fisher(centre))
        if not cond <= options.condition_max:
            reasons.append(f"a near-singular Fisher matrix (condition {cond:.3g})")
    return "; ".join(reasons)


def _crowded(model, centre: np.ndarray) -> bool:
    """Two sources of ``centre`` (P_model,) closer than the resolution limit.

    Such an ML point does not pin the configuration (the pair's separation is
    free along a flat valley), so a near-antipodal pair in it says little about
    the posterior's modes: on the calibration map's rings of three and four
    sources where it would switch (mostly half to one spacing apart), one ensemble
    per mode covered 0.75 and 0.59 at 90 %, one ensemble 0.98 and 0.95.
    """
    return bool(min_separation(model, centre[None])[0] < RESOLUTION_SPACINGS)


def _pinned(model, centre: np.ndarray, pairs: tuple) -> tuple:
    """The ``pairs`` (i, j, offset) of ``centre`` (P_model,) whose two sources are pinned.

    A source is pinned when it is not weak
    (:func:`olsbayes.resolution.weak_sources`: an intensity at least
    :data:`~olsbayes.resolution.WEAK_SDS` Cramer-Rao sd above zero; an infinite
    sd, a singular Fisher matrix, is not).  A pair with
    a source the readings do not tell from nothing is an artefact of the ML point,
    not two sources whose mirror configuration competes: on the calibration map's
    rings of two to four sources where such pairs switched to one ensemble per
    mode (15, 58 and 69 scenes, mostly sources one spacing apart or SNR 10), those
    ensembles covered 0.92, 0.74 and 0.70 at 90 %, one ensemble 1.00, 0.98 and
    0.95; every near-antipodal four-source scene that switched kept its pairs.
    """
    cov, _, _ = bound_covariance(model.fisher(centre))
    weak = weak_sources(model, centre[None], cov[None])[0]
    return tuple(pair for pair in pairs if not (weak[pair[0]] or weak[pair[1]]))


def model_point(model, prior, data: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A model point (P_model,) as a full point (P,) inside the prior.

    The residual rms is appended when sigma is inferred; clipped to the support.
    """
    if prior.noise is None:
        return np.clip(x, prior.lower, prior.upper)
    rms = max(float(np.sqrt(np.mean((data - model.response(x)) ** 2))), 1e-300)
    return np.clip(np.append(x, rms), prior.lower, prior.upper)


def mode_walkers(model, data: np.ndarray, prior, mode: np.ndarray, n_walkers: int,
                 gen: np.random.Generator) -> np.ndarray:
    """Walkers (W, P) in a CRLB-shaped ball (:func:`~._start.ball_covariance`) at one mode."""
    centre = model_point(model, prior, data, mode)
    cov = ball_covariance(model, prior, centre)
    return initial_ensemble(centre, cov, n_walkers, prior.contains, gen)


def mode_evidence(logpost, z: np.ndarray, n_draws: int, gen: np.random.Generator
                  ) -> tuple[float, float]:
    """log Z of one mode and its standard error (nats) from its draws z (n, P).

    Importance sampling in the sampler's coordinates (whose density ``logpost``
    carries the Jacobian, so Z is the same as in the parameters'): a Student-t
    proposal (5 degrees of freedom) with the draws' mean and covariance.
    """
    from scipy import stats
    from scipy.special import logsumexp

    mean = z.mean(axis=0)
    cov = np.cov(z, rowvar=False).reshape(z.shape[1], z.shape[1])
    cov = cov + np.diag(np.maximum(1e-12 * np.diag(cov), 1e-300))
    try:
        q = stats.multivariate_t(loc=mean, shape=cov, df=5.0, seed=gen)
        draws = q.rvs(size=n_draws).reshape(n_draws, -1)
        log_q = q.logpdf(draws)
    except np.linalg.LinAlgError:  # scales too far apart, or draws on a lower-dim set
        draws, log_q = _scaled_t(mean, cov, n_draws, gen)
    log_w = np.asarray(logpost(draws), dtype=float) - log_q
    log_w = np.where(np.isfinite(log_w), log_w, -np.inf)
    log_mean = float(logsumexp(log_w) - np.log(n_draws))
    w = np.exp(log_w - log_mean)
    return log_mean, float(np.std(w) / np.sqrt(n_draws))


def _scaled_t(mean: np.ndarray, cov: np.ndarray, n_draws: int, gen: np.random.Generator
              ) -> tuple[np.ndarray, np.ndarray]:
    """Draws (n, P) of the Student-t proposal built on the correlation matrix, and log q.

    Each coordinate is scaled by its sd and the correlation matrix gets a ridge of
    1e-6, so the proposal exists when the covariance is numerically singular;
    log q includes the Jacobian of the scaling.
    """
    from scipy import stats

    sd = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sd, sd) + 1e-6 * np.eye(sd.size)
    q = stats.multivariate_t(loc=np.zeros(sd.size), shape=corr, df=5.0, seed=gen)
    u = q.rvs(size=n_draws).reshape(n_draws, -1)
    return mean + u * sd, q.logpdf(u) - float(np.sum(np.log(sd)))


def pool_labels(weights: np.ndarray, n_draws: int, n_walkers: int,
                gen: np.random.Generator) -> np.ndarray:
    """The mode (n_draws, n_walkers) each pooled slot takes its draw from.

    Systematic allocation of the weights (each mode's share exact to one slot),
    then shuffled.
    """
    n = n_draws * n_walkers
    edges = np.floor(np.cumsum(weights / weights.sum()) * n + 0.5).astype(int)
    counts = np.diff(np.concatenate([[0], edges]))
    return gen.permutation(np.repeat(np.arange(weights.size), counts)).reshape(n_draws,
                                                                                n_walkers)


class PooledChain:
    """The pooled draws of the modes' ensembles, read like a finished emcee sampler.

    Enough of ``emcee.EnsembleSampler``'s interface (``get_chain``,
    ``get_log_prob``, ``get_autocorr_time``, ``acceptance_fraction``) for
    :func:`~._assemble.assemble`, which then stores them as any run's.

    Parameters
    ----------
    chain : ndarray (D, W, P)
        Pooled draws in the sampler's coordinates (burn-in already removed).
    log_prob : ndarray (D, W)
        Their log densities in the sampler's coordinates.
    tau : ndarray (P,)
        Largest autocorrelation time of each coordinate over the modes.
    acceptance : ndarray (W,)
        Acceptance fraction of the walker of the mode most of the column's draws came from.
    """

    def __init__(self, chain: np.ndarray, log_prob: np.ndarray, tau: np.ndarray,
                 acceptance: np.ndarray):
        self._chain, self._log_prob, self._tau = chain, log_prob, tau
        self.acceptance_fraction = acceptance

    def get_chain(self) -> np.ndarray:
        """The pooled draws (D, W, P)."""
        return self._chain

    def get_log_prob(self) -> np.ndarray:
        """Their log densities (D, W)."""
        return self._log_prob

    def get_autocorr_time(self, tol: float = 0) -> np.ndarray:
        """The modes' largest autocorrelation times (P,) (``tol`` is ignored)."""
        return self._tau



def nearest_mode(model, prior, draws: np.ndarray, modes: np.ndarray) -> np.ndarray:
    """Index (n,) of the mode (M, P_model) nearest each draw (n, P).

    Distance to mode m: the location errors (sources matched) in units of the
    CRLB sd at mode m.  This partitions the parameter space into one cell per
    mode.
    """
    from ..exchange import estimation_errors

    k, w = prior.n_sources, model.n_loc + 1
    flat = draws[:, : k * w]
    loc = np.ones(k * w, dtype=bool)
    loc[w - 1 :: w] = False
    dist = np.empty((flat.shape[0], modes.shape[0]))
    for m, x in enumerate(modes):
        sd = np.sqrt(np.clip(np.diag(bound_covariance(model.fisher(x))[0]), 0.0, None))
        sd = np.where(np.isfinite(sd) & (sd > 0), sd, 1.0)
        err = estimation_errors(model, flat, x)
        dist[:, m] = np.sum((err[:, loc] / sd[loc]) ** 2, axis=1)
    return np.argmin(dist, axis=1)
