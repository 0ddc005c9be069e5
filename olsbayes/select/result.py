"""Frozen results of the choice of the number of sources K."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from .._store import load_result, save_result, storable

__all__ = ["KEvidence", "SelectionResult"]


@storable
@dataclass(frozen=True, eq=False)
class KEvidence:
    """The evidence for one number of sources K and how it was obtained.

    Attributes
    ----------
    k : int
        Number of sources.
    log_evidence : float
        log Z_K = log p(data | K) (nats) from ``method``; for the information
        criteria the pseudo-evidence -BIC/2 or -AIC/2.
    error : float
        Its standard error (nats): 0 for a closed form, dynesty's ``logzerr`` for
        nested sampling, the stratified-sampling error of the quadrature, the
        delta-method error of importance sampling, NaN where
        no error is defined (Laplace, BIC, AIC).
    method : str
        ``"closed-form"``, ``"laplace"``, ``"importance"`` (mixture importance
        sampling over the locations, where Laplace is untrusted), ``"nested"``,
        ``"quadrature"`` (exact up to its stated error: K <= 2 ring sources,
        :mod:`olsbayes.select.quadrature`), ``"bic"`` or ``"aic"``.
    log_likelihood : float
        Maximum log-likelihood (of the ML fit; of the data for K = 0).
    n_params : int
        Number of free parameters, K * (d + 1).
    params : ndarray, shape (n_params,)
        ML point in canonical order (empty for K = 0).
    laplace : float
        The Laplace estimate (NaN where it does not exist), kept after escalation.
    trusted : bool
        Whether the Laplace approximation is expected to hold here.
    reasons : tuple of str
        Why the Laplace approximation is not trusted (empty when it is), then any
        doubt about what replaced it (importance-sampling error > 0.3 nats or < 20
        effective draws; nested sampling stopped at ``maxcall``).
    n_calls : int
        Likelihood evaluations spent on this K by the evidence estimator.
    seconds : float
        Wall time spent on this K (ML fit included), s.
    fit : object
        The :func:`olsbayes.ml.fit_ml` result (None for K = 0).  Its params differ
        from ``params`` when the cross-K repair found a better optimum (``origin``).
    origin : str
        Where ``params`` come from: ``"fit_ml"``, ``"fit_ml (not converged)"``,
        ``"from K+1"`` (a source of the (K+1)-fit dropped, then refined) or
        ``"from K-1"`` (a source added to the (K-1)-fit, then refined).
    nested : NestedRun or None
        dynesty's results where this K's evidence came from nested sampling
        (:meth:`~olsbayes.select.nested.NestedRun.plot` draws its run and trace
        plots); None otherwise.
    """

    k: int
    log_evidence: float
    error: float
    method: str
    log_likelihood: float
    n_params: int
    params: np.ndarray
    laplace: float = math.nan
    trusted: bool = True
    reasons: tuple[str, ...] = ()
    n_calls: int = 0
    seconds: float = 0.0
    fit: Any = None
    origin: str = ""
    nested: Any = None

    def __repr__(self) -> str:
        err = "" if not np.isfinite(self.error) else f" +- {self.error:.3g}"
        return (f"KEvidence(k={self.k}, log_evidence={self.log_evidence:.6g}{err}, "
                f"method={self.method!r}, trusted={self.trusted})")


@storable
@dataclass(frozen=True, eq=False)
class SelectionResult:
    """Posterior over the number of sources K = 0..K_max.

    Attributes
    ----------
    ks : ndarray of int, shape (M,)
        Candidate numbers of sources, 0..K_max.
    log_evidence : ndarray, shape (M,)
        log Z_K per candidate (nats).
    error : ndarray, shape (M,)
        Standard error of each log Z_K (NaN where undefined).
    log_prior_k : ndarray, shape (M,)
        log p(K) of the prior on K.
    probabilities : ndarray, shape (M,)
        Posterior p(K | data), summing to 1.
    best : int
        The chosen K (the most probable, or a smaller K within ``tie`` nats:
        see ``notes``).
    method : str
        The requested method (``"auto"``, ``"laplace"``, ``"nested"``, ``"bic"``, ``"aic"``).
    evidences : tuple of KEvidence
        Per-K records (fits, diagnostics, cost).
    escalated : Mapping[int, str]
        K whose evidence ``auto`` recomputed (by quadrature or nested sampling,
        ``evidences[K].method``), and why.
    notes : tuple of str
        Remarks on the decision (ties broken towards the smaller K, warnings).
    seconds : float
        Total wall time, s.
    """

    ks: np.ndarray
    log_evidence: np.ndarray
    error: np.ndarray
    log_prior_k: np.ndarray
    probabilities: np.ndarray
    best: int
    method: str
    evidences: tuple[KEvidence, ...]
    escalated: Mapping[int, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    seconds: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "escalated", MappingProxyType(dict(self.escalated)))
        for name in ("ks", "log_evidence", "error", "log_prior_k", "probabilities"):
            arr = np.array(getattr(self, name))
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)

    @property
    def log_bayes_factors(self) -> np.ndarray:
        """log Z_K - log Z_best (nats), shape (M,)."""
        return self.log_evidence - self.log_evidence[list(self.ks).index(self.best)]

    def __getitem__(self, k: int) -> KEvidence:
        """The per-K record of ``k`` sources."""
        for ev in self.evidences:
            if ev.k == k:
                return ev
        raise KeyError(f"no candidate with K = {k}; candidates are {list(self.ks)}")

    def nested_plot(self, k: int, kind: str = "run", **kwargs: Any) -> Any:
        """dynesty's ``"run"`` or ``"trace"`` plot of K's nested run (a matplotlib figure).

        InputError when K's evidence did not come from nested sampling.
        """
        from ..errors import InputError

        run = self[k].nested
        if run is None:
            raise InputError(f"K = {k} has no nested-sampling run (its evidence is "
                             f"{self[k].method!r}); use method='nested' or 'auto'")
        return run.plot(kind, **kwargs)

    def summary(self):
        """Table (pandas DataFrame), one row per candidate K (index ``k``).

        Columns ``log_evidence``, ``error`` (nats), ``method``, ``log_prior_k``,
        ``probability`` (p(K | data)), ``log_bayes_factor`` (against the chosen
        K), ``log_likelihood``, ``laplace``, ``trusted``, ``origin``, ``note``
        and ``best`` (the chosen K).
        """
        import pandas as pd

        return pd.DataFrame({
            "log_evidence": self.log_evidence, "error": self.error,
            "method": [ev.method for ev in self.evidences],
            "log_prior_k": self.log_prior_k, "probability": self.probabilities,
            "log_bayes_factor": self.log_bayes_factors,
            "log_likelihood": [ev.log_likelihood for ev in self.evidences],
            "laplace": [ev.laplace for ev in self.evidences],
            "trusted": [bool(ev.trusted) for ev in self.evidences],
            "origin": [ev.origin for ev in self.evidences],
            "note": ["; ".join(ev.reasons) for ev in self.evidences],
            "best": [int(ev.k) == int(self.best) for ev in self.evidences],
        }, index=pd.Index([int(k) for k in self.ks], name="k"))

    def save(self, path: str | os.PathLike, *, data: np.ndarray | None = None,
             seed: int | None = None) -> Path:
        """Write the result (fits included) to a NetCDF file that :meth:`load` reads back.

        ``data`` (the readings; their SHA-256 is recorded) and ``seed`` are
        recorded with the package version and the command line.
        """
        from .._provenance import provenance
        return save_result(self, path, provenance(seed=seed, data=data))

    @classmethod
    def load(cls, path: str | os.PathLike, *, model: Any = None) -> SelectionResult:
        """Read a result written by :meth:`save` (``model``: see :meth:`MLResult.load`)."""
        return load_result(path, cls, model=model)

    def __repr__(self) -> str:
        p = float(self.probabilities[list(self.ks).index(self.best)])
        return (f"SelectionResult(best={self.best}, p(best | data)={p:.3g}, "
                f"K=0..{int(self.ks[-1])}, method={self.method!r})")

    def table(self) -> str:
        """Plain-text table: K, log Z, error, method, p(K | data), notes."""
        head = f"{'K':>2}  {'log Z':>12}  {'+-':>7}  {'method':<11}  {'p(K|data)':>9}  note"
        lines = [head, "-" * len(head)]
        for ev, p in zip(self.evidences, self.probabilities):
            err = "" if not np.isfinite(ev.error) else f"{ev.error:7.3f}"
            mark = "*" if ev.k == self.best else " "
            note = "; ".join(ev.reasons)
            if ev.k in self.escalated:  # why escalated, then what nested sampling added
                why = self.escalated[ev.k]
                note = "; ".join([why] + [r for r in ev.reasons if r not in why])
            lines.append(
                f"{ev.k:>2}{mark} {ev.log_evidence:12.3f}  {err:>7}  {ev.method:<11}  "
                f"{p:9.4f}  {note}"
            )
        lines.append(f"best K = {self.best} (method {self.method}, {self.seconds:.3g} s)")
        lines.extend(f"note: {n}" for n in self.notes)
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no fit objects)."""
        return {
            "best": int(self.best),
            "method": self.method,
            "seconds": float(self.seconds),
            "notes": list(self.notes),
            "escalated": {str(k): v for k, v in self.escalated.items()},
            "candidates": [
                {
                    "k": int(ev.k),
                    "log_evidence": _num(ev.log_evidence),
                    "error": _num(ev.error),
                    "method": ev.method,
                    "probability": float(p),
                    "log_prior_k": _num(lp),
                    "log_likelihood": _num(ev.log_likelihood),
                    "laplace": _num(ev.laplace),
                    "trusted": bool(ev.trusted),
                    "reasons": list(ev.reasons),
                    "names": _names(ev),
                    "params": [float(v) for v in ev.params],
                    "origin": ev.origin,
                    "n_calls": int(ev.n_calls),
                    "seconds": float(ev.seconds),
                }
                for ev, p, lp in zip(self.evidences, self.probabilities, self.log_prior_k)
            ],
        }


def _names(ev: KEvidence) -> list[str] | None:
    """Parameter names of a candidate's ``params`` (from its fit's model), None if unknown."""
    if ev.k == 0:
        return []
    model = getattr(ev.fit, "model", None)
    return list(model.param_names(ev.k)) if hasattr(model, "param_names") else None


def _num(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None
