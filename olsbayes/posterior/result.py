"""The frozen result of :func:`olsbayes.posterior.sample`, and its file round trip."""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..priors import ScenePrior
from ._arviz import from_netcdf, posterior_array, to_netcdf, wrap_periodic
from .audit import CRLBCheck, crlb_check, summary
from .checks import ModelCheck, model_check
from .modes import ModeReport

__all__ = ["PosteriorResult"]

#: Posterior-group attribute holding the result's fields (JSON, arrays by reference).
RESULT_ATTR = "olsbayes_result"
#: Fields stored in :data:`RESULT_ATTR` (the InferenceData holds the draws).
_STORED = ("model", "prior", "n_sources", "names", "estimate", "crlb_cov", "start", "tau",
           "n_steps", "n_burn", "thin", "converged", "acceptance_fraction", "switch_fraction",
           "elapsed", "n_evaluations", "seed", "provenance", "at_bound")


@dataclass(frozen=True, eq=False)
class PosteriorResult:
    """Posterior draws of one scene, burn-in removed and labels fixed.

    Attributes
    ----------
    idata : arviz.InferenceData
        Groups ``posterior`` (walkers as chains; variables ``theta``/``lon``/
        ``lat``/``x``/``y``/``z`` and ``I`` with a ``source`` dim, ``sigma`` if
        inferred; angles unwrapped around their circular means, with
        ``circular``/``units`` attributes), ``posterior_predictive`` (``obs``:
        one replicate of the readings per draw), ``sample_stats`` (``lp``,
        ``log_prior``, ``acceptance_rate``), ``log_likelihood`` (``obs``, one
        entry per sub-sensor; computed on its first access), ``observed_data``
        (``obs``), ``constant_data`` (``normals``, ``positions`` for plates,
        ``sigma`` when known, and ``crlb_cov``, ``estimate``, ``tau``, ``start``,
        ``acceptance_fraction`` with named dims) and ``prior``; the attributes
        name the inference library and versions and hold the provenance
        (:mod:`olsbayes._provenance`).  The two per-reading groups,
        ``posterior_predictive`` and ``log_likelihood``, hold every draw up to
        ``olsbayes.posterior._assemble.READING_FLOATS`` numbers each (walkers x
        draws x sub-sensors), else every s-th draw:
        their ``draw`` labels are the posterior's, s is the attribute
        ``reading_stride`` (1 when they hold every draw).
    model : Model
    prior : ScenePrior
    n_sources : int
    names : tuple of str
        Flat parameter names (``Model.param_names`` plus ``"sigma"``).  Source j
        is the one matched to source j of ``start`` (the ML estimate by default,
        in canonical order): the ML table's order, whatever the seed.
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
    seed : int or None
        The integer seed of the run (drawn from the system's entropy when ``rng``
        was None; a SeedSequence's entropy, its spawn key in ``provenance``); None
        when a Generator was given.
    provenance : Mapping
        Package version, seed, SHA-256 of the readings, command line, time.
    at_bound : tuple of str
        Parameters whose posterior piles up at a bound of their prior (a
        :class:`~olsbayes.errors.PriorBoundWarning` was issued).
    modes : ModeReport or None
        The modes the multimodal sampler found and their weights
        (:mod:`olsbayes.posterior.multimodal`); None for a single ensemble.
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
    seed: int | None = None
    provenance: Mapping = field(default_factory=dict)
    at_bound: tuple[str, ...] = ()
    modes: ModeReport | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "at_bound", tuple(self.at_bound))
        _stamp(self)

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
        return wrap_periodic(posterior_array(self.idata, list(self.names)), self.periodic)

    @property
    def flat_samples(self) -> np.ndarray:
        """Draws pooled over walkers, shape (n_walkers * n_draws, P)."""
        s = self.samples
        return s.reshape(-1, s.shape[-1])

    def unwrapped_samples(self) -> np.ndarray:
        """Draws with angles unwrapped around their circular means, (W, D, P).

        A source near +-pi then has a continuous, not a split, distribution:
        use this for every linear statistic or plot of an angle.  These are the
        values stored in ``idata``.
        """
        return posterior_array(self.idata, list(self.names))

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

    def model_check(self) -> ModelCheck:
        """chi^2/dof and the posterior predictive p-value (:mod:`olsbayes.posterior.checks`)."""
        return model_check(self)

    def to_netcdf(self, path: str | os.PathLike) -> Path:
        """Write the InferenceData to NetCDF atomically; :meth:`from_netcdf` reads it back."""
        return to_netcdf(self.idata, path)

    @classmethod
    def from_netcdf(cls, path: str | os.PathLike, *, model: object = None) -> PosteriorResult:
        """The result written by :meth:`to_netcdf` (or a report's ``posterior.nc``).

        ``model`` is needed only for a model with a custom sensitivity law (a
        Python function), which cannot be stored.
        """
        from .._store import decode
        from ..errors import InputError

        idata = from_netcdf(path)
        meta = getattr(idata, "posterior", None)
        if meta is None or RESULT_ATTR not in meta.attrs:
            raise InputError(f"path {str(path)!r} holds no olsbayes posterior result")
        arrays = {name: np.asarray(var.values) for name, var in idata.constant_data.items()}
        tree = json.loads(meta.attrs[RESULT_ATTR])
        fields = {name: decode(value, arrays, model) for name, value in tree.items()}
        return cls(idata=idata, **fields)

    def __repr__(self) -> str:
        w, d, _ = self.samples.shape
        return (
            f"PosteriorResult(K={self.n_sources}, walkers={w}, draws={d}, steps={self.n_steps}, "
            f"n_burn={self.n_burn}, converged={self.converged}, tau_max={np.max(self.tau):.1f}"
            + ("" if self.modes is None else f", modes={self.modes.n_modes}") + ")"
        )


def _stamp(result: PosteriorResult) -> None:
    """Write the result's fields into ``idata`` so that a saved file restores it.

    Scalars go into the posterior group's attribute :data:`RESULT_ATTR` (JSON);
    arrays not already in ``constant_data`` (the model's) are added there.
    """
    from .._store import encode

    arrays: dict[str, np.ndarray] = {}
    names = _STORED if result.modes is None else _STORED + ("modes",)
    tree = {name: encode(getattr(result, name), arrays, name) for name in names}
    const = result.idata.constant_data
    for name, arr in arrays.items():
        if name in const and np.array_equal(const[name].values, arr, equal_nan=True):
            continue
        const[name] = ([f"{name}_{i}" for i in range(np.ndim(arr))], np.asarray(arr))
    result.idata.posterior.attrs[RESULT_ATTR] = json.dumps(tree)
