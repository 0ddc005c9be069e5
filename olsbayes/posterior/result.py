"""The frozen result of :func:`olsbayes.posterior.sample`."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..circular import unwrap_around
from ..priors import ScenePrior
from ._arviz import posterior_array, to_netcdf
from .audit import CRLBCheck, crlb_check, summary

__all__ = ["PosteriorResult"]


@dataclass(frozen=True, eq=False)
class PosteriorResult:
    """Posterior draws of one scene, burn-in removed and labels fixed.

    Attributes
    ----------
    idata : arviz.InferenceData
        Groups ``posterior`` (walkers as chains; variables ``theta``/``lon``/
        ``lat``/``x``/``y``/``z`` and ``I`` with a ``source`` dim, ``sigma`` if
        inferred; angles wrapped to (-pi, pi]), ``sample_stats`` (``lp``,
        ``log_prior``, ``acceptance_rate``), ``log_likelihood`` (``obs``, one
        entry per sub-sensor), ``observed_data`` (``obs``), ``constant_data``
        (``normals``, ``positions`` for plates, ``sigma`` when known,
        ``crlb_cov`` and ``estimate`` in the flat layout).
    model : Model
    prior : ScenePrior
    n_sources : int
    names : tuple of str
        Flat parameter names (``Model.param_names`` plus ``"sigma"``).
    estimate : ndarray (P,)
        Posterior mean (circular mean for angles) of the relabelled draws.
    crlb_cov : ndarray (P, P)
        CRLB covariance at ``estimate`` (inf rows where unidentifiable).
    start : ndarray (P,) or None
        Centre of the starting ball (the ML point by default); None for prior starts.
    tau : ndarray (P,)
        emcee integrated autocorrelation time (steps) of each sampler coordinate
        (``log x`` for parameters with a log-uniform prior), listed under the
        relabelled parameter it mostly supplies (the dominant relabelling
        permutation), so it lines up with ``names`` and ``summary()``.
    n_steps, n_burn, thin : int
        Steps run, steps discarded as burn-in, thinning of the stored draws.
    converged : bool
        Whether ``n_steps >= tau_multiple * max(tau)`` held before the step limit.
    acceptance_fraction : ndarray (n_walkers,)
    switch_fraction : float
        Fraction of stored draws whose relabelling permutation differs from the
        most common one (0 when the raw labels never swapped).
    elapsed : float
        Wall time of the sampling (s).
    n_evaluations : int
        Calls of the log-posterior (one call evaluates all walkers if vectorised).
    """

    idata: object
    model: object
    prior: ScenePrior
    n_sources: int
    names: tuple[str, ...]
    estimate: np.ndarray
    crlb_cov: np.ndarray
    start: np.ndarray | None
    tau: np.ndarray
    n_steps: int
    n_burn: int
    thin: int
    converged: bool
    acceptance_fraction: np.ndarray
    switch_fraction: float
    elapsed: float
    n_evaluations: int

    @property
    def n_params(self) -> int:
        """P, the length of a flat draw."""
        return len(self.names)

    @property
    def periodic(self) -> np.ndarray:
        """Boolean mask (P,) of periodic parameters."""
        return self.prior.periodic

    @property
    def samples(self) -> np.ndarray:
        """Relabelled draws, shape (n_walkers, n_draws, P), angles in (-pi, pi]."""
        return posterior_array(self.idata, list(self.names))

    @property
    def flat_samples(self) -> np.ndarray:
        """Draws pooled over walkers, shape (n_walkers * n_draws, P)."""
        s = self.samples
        return s.reshape(-1, s.shape[-1])

    def unwrapped_samples(self) -> np.ndarray:
        """Draws with angles unwrapped around their circular means, (W, D, P).

        A source near +-pi then has a continuous, not a split, distribution:
        use this for every linear statistic or plot of an angle.
        """
        return unwrap_around(self.samples, self.estimate, self.periodic)

    @property
    def crlb_std(self) -> np.ndarray:
        """CRLB of every parameter's sd at ``estimate``, shape (P,)."""
        return np.sqrt(np.diag(self.crlb_cov))

    def summary(self, hdi_prob: float = 0.94):
        """Table (pandas DataFrame) of mean, sd, HDI, ESS, R-hat, tau, CRLB.

        :func:`olsbayes.posterior.summary` of this result.
        """
        return summary(self, hdi_prob=hdi_prob)

    def crlb_check(self, rtol: float = 0.2) -> CRLBCheck:
        """Posterior sd against the CRLB; :func:`olsbayes.posterior.crlb_check` of this result."""
        return crlb_check(self, rtol=rtol)

    def to_netcdf(self, path: str | os.PathLike) -> Path:
        """Write the InferenceData to NetCDF atomically."""
        return to_netcdf(self.idata, path)

    def __repr__(self) -> str:
        w, d, _ = self.samples.shape
        return (
            f"PosteriorResult(K={self.n_sources}, walkers={w}, draws={d}, steps={self.n_steps}, "
            f"n_burn={self.n_burn}, converged={self.converged}, tau_max={np.max(self.tau):.1f})"
        )
