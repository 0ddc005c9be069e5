"""The frozen result of a maximum-likelihood fit (single data vector or a batch)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._store import load_result, save_result, storable
from .._validation import integer
from ..errors import InputError
from ..model import Model
from ..scene import Scene

__all__ = ["MLResult"]


@storable
@dataclass(frozen=True, eq=False)
class MLResult:
    """Maximum-likelihood estimate(s) of Eq. 2.

    A single fit (``data`` of shape (N,)) has scalar/1-D fields; a batch fit
    (``data`` of shape (T, N)) has a leading trial axis T on every array field.

    Attributes
    ----------
    params : ndarray, shape (P,) or (T, P)
        Estimates in the model's flat layout ``[location..., intensity]`` per
        source, in canonical order (:meth:`Model.canonical`: angles wrapped to
        (-pi, pi], sources sorted by first location coordinate).  Intensities >= 0.
    log_likelihood : ndarray, shape () or (T,)
        Gaussian log-likelihood at the estimate.
    converged : ndarray of bool, shape () or (T,)
        True when the local optimiser met its stopping criterion; False fits
        were also warned about with :class:`~olsbayes.errors.ConvergenceWarning`.
    n_evaluations : ndarray of int, shape () or (T,)
        Forward-model evaluations (responses plus Jacobians) spent by the local
        optimiser per fit, over all starts (the fast method's grid scoring, a
        few matrix products on precomputed atoms, is not counted).
    cov : ndarray, shape (P, P) or (T, P, P)
        Inverse Fisher information at the estimate (the CRLB evaluated at the
        estimate), rows/columns of unidentifiable parameters set to inf.
    rival_gap : ndarray, shape () or (T,)
        Log-likelihood of the estimate minus that of the best *distinct* local
        optimum the method's starts reached (source locations more than 3 Fisher
        std apart; :mod:`olsbayes.ml.rivals`): small values (< 3 warns
        :class:`~olsbayes.errors.MultimodalWarning`) mean a rival mode, where
        ``cov`` understates the uncertainty.  inf: no distinct optimum reached
        (not a proof that none exists); NaN: not assessed (``"exact"``).
    method : str
        ``"fast"``, ``"multistart"`` or ``"exact"``.
    n_sources : int
        Number K of sources fitted.
    model : Model
        The model fitted (used by :attr:`scene`).
    extra : ndarray, shape (Q,) or (T, Q)
        Estimates of the extra parameters the model infers (an unknown sigma,
        background, gains, offsets; :func:`olsbayes.measurement.extra_names`);
        empty for the default model.
    extra_std : ndarray, shape (Q,) or (T, Q)
        Their Fisher standard errors (nuisance priors included).
    extra_names : tuple of str
        Names of the extra parameters.
    """

    params: np.ndarray
    log_likelihood: np.ndarray
    converged: np.ndarray
    n_evaluations: np.ndarray
    cov: np.ndarray
    rival_gap: np.ndarray
    method: str
    n_sources: int
    model: Model = field(repr=False)
    extra: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    extra_std: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    extra_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in ("params", "log_likelihood", "converged", "n_evaluations", "cov",
                     "rival_gap", "extra", "extra_std"):
            arr = np.array(getattr(self, name))
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)

    @property
    def is_batch(self) -> bool:
        """True for a batch fit (leading trial axis)."""
        return self.params.ndim == 2

    @property
    def n_trials(self) -> int:
        """Number T of data vectors fitted (1 for a single fit)."""
        return int(self.params.shape[0]) if self.is_batch else 1

    @property
    def std(self) -> np.ndarray:
        """Fisher standard errors sqrt(diag(cov)), shape (P,) or (T, P)."""
        return np.sqrt(np.diagonal(self.cov, axis1=-2, axis2=-1))

    @property
    def scene(self) -> Scene:
        """The estimated :class:`~olsbayes.Scene` of a single fit."""
        if self.is_batch:
            raise InputError(
                f"scene is defined for a single fit; this result holds {self.n_trials} "
                "trials, use scene_at(i)"
            )
        return self.model.unpack(self.params)

    def scene_at(self, i: int) -> Scene:
        """The estimated scene of trial ``i`` (0 <= i < T) of a batch fit."""
        if not self.is_batch:
            integer("i", i, low=0, high=0)
            return self.scene
        i = integer("i", i, low=-self.n_trials, high=self.n_trials - 1)
        return self.model.unpack(self.params[i])

    def __len__(self) -> int:
        return self.n_trials

    def summary(self):
        """Table (pandas DataFrame): estimate and Fisher sd per parameter.

        One row per parameter (index ``parameter``, names as
        :meth:`Model.param_names`), columns ``estimate`` and ``sd``; a batch fit
        has a two-level index (``trial``, ``parameter``).  Angles in rad.
        """
        import pandas as pd

        names = self.model.param_names(self.n_sources) if hasattr(self.model, "param_names") \
            else [f"x[{i}]" for i in range(self.params.shape[-1])]
        est, sd = np.atleast_2d(self.params), np.atleast_2d(self.std)
        if not self.is_batch:
            index = pd.Index(names, name="parameter")
        else:
            index = pd.MultiIndex.from_product([range(self.n_trials), names],
                                               names=["trial", "parameter"])
        return pd.DataFrame({"estimate": est.ravel(), "sd": sd.ravel()}, index=index)

    def save(self, path: str | os.PathLike, *, data: np.ndarray | None = None,
             seed: int | None = None) -> Path:
        """Write the result to a NetCDF file that :meth:`load` reads back unchanged.

        Parameters
        ----------
        path : path
            The file (written atomically).
        data : ndarray, optional
            The readings fitted: their SHA-256 is recorded with the package version
            and the command line.
        seed : int, optional
            The seed of the fit, recorded.
        """
        from .._provenance import provenance
        return save_result(self, path, provenance(seed=seed, data=data))

    @classmethod
    def load(cls, path: str | os.PathLike, *, model: Model | None = None) -> MLResult:
        """Read a result written by :meth:`save`.

        ``model`` is needed only for a model with a custom sensitivity law, which
        cannot be stored.
        """
        return load_result(path, cls, model=model)

    def __repr__(self) -> str:
        shape = f"trials={self.n_trials}, " if self.is_batch else ""
        ll = np.asarray(self.log_likelihood)
        ll_text = f"{float(ll):.6g}" if ll.ndim == 0 else f"[{ll.min():.6g} .. {ll.max():.6g}]"
        return (f"MLResult(method={self.method!r}, K={self.n_sources}, {shape}"
                f"log_likelihood={ll_text}, converged={bool(np.all(self.converged))})")
