"""The imaging result and the sample summaries it is built from."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._mcmc_diagnostics import ess_bulk
from .._store import load_result, save_result, storable
from .binary import BinaryMap
from .design import Design

__all__ = ["ImageResult", "hpd_interval", "split_rhat"]


def hpd_interval(
    samples: np.ndarray, level: float, lower: np.ndarray, upper: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Shortest intervals holding ``level`` of the draws, per column.

    Parameters
    ----------
    samples : ndarray, shape (S, K)
    level : float in (0, 1)
    lower, upper : ndarray, shape (K,)
        Support bounds.  When fewer than a tenth of the excluded draws lie below
        the shortest window (above it), the density is highest at that edge and
        the interval is extended to the support bound there -- so a dark pixel
        whose posterior piles up at 0 gets an interval that contains 0.

    Returns
    -------
    lo, hi : ndarray, shape (K,)
    """
    s = np.sort(samples, axis=0)
    n = s.shape[0]
    m = max(1, int(np.ceil(level * n)))
    widths = s[m - 1 :] - s[: n - m + 1]
    start = np.argmin(widths, axis=0)
    cols = np.arange(s.shape[1])
    lo, hi = s[start, cols], s[start + m - 1, cols]
    edge = 0.1 * (n - m)
    lo = np.where((start <= edge) & np.isfinite(lower), lower, lo)
    hi = np.where((n - m - start <= edge) & np.isfinite(upper), upper, hi)
    return lo, hi


def split_rhat(chains: np.ndarray) -> np.ndarray:
    """Split-chain potential scale reduction (Gelman et al. 2013), shape (K,).

    ``chains`` has shape (C, S, K).  Columns constant within every half-chain
    give 1 when all halves agree and inf when they differ (chains frozen in
    different states -- common for discrete draws such as dark/bright pixels).
    """
    c, s, k = chains.shape
    h = s // 2
    if h < 2:
        return np.full(k, np.nan)
    parts = np.concatenate([chains[:, :h], chains[:, s - h :]], axis=0)  # (2C, h, K)
    w = parts.var(axis=1, ddof=1).mean(axis=0)
    b = h * parts.mean(axis=1).var(axis=0, ddof=1)
    var = (h - 1) / h * w + b / h
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.sqrt(var / w)
    return np.where(w > 0, r, np.where(b > 0, np.inf, 1.0))


@storable
@dataclass(frozen=True)
class ImageResult:
    """Posterior of source intensities at known directions.

    Attributes
    ----------
    prior : str
        Name of the prior: ``"gaussian"``, ``"nonnegative"``, ``"bounded"``,
        ``"sparse"`` or ``"two-level"``.
    directions : ndarray, shape (K, d)
        Source locations (rad; length units for near-source positions).
    mean : ndarray, shape (K,)
        Posterior mean of the intensities (the estimate minimising expected
        squared error).
    mode : ndarray, shape (K,)
        A posterior mode: the Gaussian mean; bounded least squares for the box
        priors (not unique when the design has a null space); for ``"sparse"``
        the posterior median (a pixel is dark if P(I = 0) > 1/2); for
        ``"two-level"`` the MAP scene found by the local search.
    sd : ndarray, shape (K,)
        Posterior standard deviations.
    lower, upper : ndarray, shape (K,)
        Credible intervals at ``level`` (closed form for the Gaussian prior,
        highest-density from draws otherwise).
    level : float
        Credibility of the intervals.
    design : Design
        Rank, conditioning and null space of the design matrix.
    samples : ndarray, shape (C, S, K) or None
        Posterior draws per chain (None for the closed-form Gaussian).
    p_bright : ndarray, shape (K,) or None
        Sparse prior: posterior probability that each source is not dark.
    log_evidence : float or None
        Gaussian prior: log p(data) (natural log).
    rhat : float
        Largest split R-hat over intensities (1 for the closed form).
    acceptance : float
        HMC acceptance rate (1 for Gibbs and the closed form).
    sampler : str
        ``"closed-form"``, ``"hmc"``, ``"gibbs"``, ``"eigen"``, ``"mode-only"`` (box priors
        with ``n_samples=0``: mean = mode, sd/intervals/rhat NaN) or
        ``"map-search"`` (two-level prior: mean = mode = the MAP scene found,
        sd/intervals/rhat NaN).
    search : BinaryMap or None
        Two-level prior: how the MAP search ended (log posterior, moves, local
        optimum, and the reference scene's log posterior when one was given).
    i_max : float or None
        Upper bound of the intensity prior actually used (given, or derived from
        the readings); None for the Gaussian and nonnegative priors.
    at_bound : ndarray of bool, shape (K,) or None
        Directions whose posterior reaches ``i_max`` (the bound, not the data,
        limits them; a warning was issued); None when there is no upper bound.
    """

    prior: str
    directions: np.ndarray
    mean: np.ndarray
    mode: np.ndarray
    sd: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    level: float
    design: Design
    samples: np.ndarray | None = None
    p_bright: np.ndarray | None = None
    log_evidence: float | None = None
    rhat: float = 1.0
    acceptance: float = 1.0
    sampler: str = "closed-form"
    search: BinaryMap | None = None
    i_max: float | None = None
    at_bound: np.ndarray | None = None

    @property
    def n_sources(self) -> int:
        """Number K of imaged directions."""
        return int(self.mean.shape[0])

    @property
    def rank(self) -> int:
        """Numerical rank of the design matrix."""
        return self.design.rank

    @property
    def null_fraction(self) -> np.ndarray:
        """Per direction, how much of its intensity the readings cannot see (0..1)."""
        return self.design.null_fraction

    @property
    def ess(self) -> float:
        """Smallest rank-normalised bulk effective sample size over the intensities.

        ArviZ's value, to rounding, from ``samples`` (all chains;
        :mod:`olsbayes._mcmc_diagnostics`); NaN without draws.  With ``rhat`` it
        tells whether the sd and intervals can be trusted (targets: R-hat <= 1.01,
        ESS >= 400).
        """
        if self.samples is None or self.samples.shape[1] < 4:
            return float("nan")
        ess = ess_bulk(np.asarray(self.samples, dtype=float))
        ess = ess[np.isfinite(ess)]
        return float(ess.min()) if ess.size else float("nan")

    def covers(self, truth: np.ndarray) -> np.ndarray:
        """Boolean mask, shape (K,): whether each interval contains ``truth``."""
        t = np.asarray(truth, dtype=float)
        return (self.lower <= t) & (t <= self.upper)

    def summary(self):
        """Table (pandas DataFrame), one row per direction (index ``source``).

        Columns: the direction's coordinates (``theta``; ``lon``, ``lat``; or
        ``x``, ``y``, ``z``), ``mean``, ``mode``, ``sd``, ``lower``, ``upper`` (the
        credible interval at ``level``), ``null_fraction`` and, when defined,
        ``p_bright`` and ``at_bound``.  The scalar facts are in :meth:`diagnostics`.
        """
        import pandas as pd

        d = np.atleast_2d(np.asarray(self.directions, dtype=float))
        if d.shape[0] != self.n_sources:
            d = d.reshape(self.n_sources, -1)
        coord = {1: ["theta"], 2: ["lon", "lat"], 3: ["x", "y", "z"]}.get(
            d.shape[1], [f"loc{j}" for j in range(d.shape[1])])
        cols = {name: d[:, j] for j, name in enumerate(coord)}
        cols.update(mean=self.mean, mode=self.mode, sd=self.sd, lower=self.lower,
                    upper=self.upper, null_fraction=self.null_fraction)
        if self.p_bright is not None:
            cols["p_bright"] = self.p_bright
        if self.at_bound is not None:
            cols["at_bound"] = self.at_bound
        return pd.DataFrame(cols, index=pd.Index(np.arange(self.n_sources), name="source"))

    def diagnostics(self) -> dict:
        """A JSON-ready dict of the scalar facts of the result (design, sampler, search)."""
        return {
            "prior": self.prior,
            "i_max": self.i_max,
            "n_sources": self.n_sources,
            "n_sensors": int(self.design.matrix.shape[0]),
            "rank": self.design.rank,
            "effective_rank": self.design.effective_rank,
            "nullity": self.design.nullity,
            "condition": self.design.condition,
            "level": self.level,
            "mean_sd": float(np.mean(self.sd)),
            "log_evidence": self.log_evidence,
            "rhat": self.rhat,
            "ess": self.ess,
            "acceptance": self.acceptance,
            "sampler": self.sampler,
            "n_draws": 0 if self.samples is None else int(np.prod(self.samples.shape[:2])),
            "n_at_bound": None if self.at_bound is None else int(np.sum(self.at_bound)),
            **self._search_summary(),
        }

    def save(self, path: str | os.PathLike, *, data: np.ndarray | None = None,
             seed: int | None = None) -> Path:
        """Write the result (draws included) to a NetCDF file that :meth:`load` reads back.

        ``data`` (the readings; their SHA-256 is recorded) and ``seed`` are
        recorded with the package version and the command line.
        """
        from .._provenance import provenance
        return save_result(self, path, provenance(seed=seed, data=data))

    @classmethod
    def load(cls, path: str | os.PathLike) -> ImageResult:
        """Read a result written by :meth:`save`."""
        return load_result(path, cls)

    def __repr__(self) -> str:
        bound = "" if self.i_max is None else f", i_max={self.i_max:.4g}"
        rhat = "" if not np.isfinite(self.rhat) else f", rhat={self.rhat:.3g}"
        return (f"ImageResult(prior={self.prior!r}{bound}, K={self.n_sources}, "
                f"rank={self.rank}, sampler={self.sampler!r}{rhat})")

    def _search_summary(self) -> dict:
        if self.search is None:
            return {}
        s = self.search
        return {"log_posterior": s.log_posterior, "local_optimum": s.local_optimum,
                "moves": s.n_flips + s.n_swaps + s.n_group_moves,
                "reference_log_posterior": s.reference_log_posterior,
                "reference_better": s.reference_better}
