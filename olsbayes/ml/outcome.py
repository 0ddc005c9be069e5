"""The raw outcome of a batch of fits, before canonical ordering and statistics.

Every method (the fast pipeline, the multistart baseline, the exact enumeration)
and every Levenberg–Marquardt run returns a :class:`FitOutcome`;
:func:`olsbayes.ml.fit_ml` turns the final one into an :class:`~olsbayes.ml.MLResult`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FitOutcome"]


@dataclass(frozen=True)
class FitOutcome:
    """Fits of T data vectors (internal record; arrays are not copied).

    Attributes
    ----------
    x : ndarray, shape (T, P)
        Parameters in the model's flat layout.
    chi2 : ndarray, shape (T,)
        Residual sums of squares (not divided by sigma^2).
    converged : ndarray of bool, shape (T,)
        The local optimiser met its stopping rule.
    n_evaluations : ndarray of int, shape (T,)
        Forward-model evaluations spent (configurations solved, for the exact method).
    stalled : ndarray of bool, shape (T,), optional
        Stopped because no damped step decreased chi^2 (a minimum on a kink of the
        sensitivity law, or working precision).
    alternatives : (ndarray (T, C, P), ndarray (T, C)), optional
        Other optima the method reached per data vector and their chi^2 (inf: no
        optimum in that slot), for :mod:`olsbayes.ml.rivals`.
    """

    x: np.ndarray
    chi2: np.ndarray
    converged: np.ndarray
    n_evaluations: np.ndarray
    stalled: np.ndarray | None = None
    alternatives: tuple[np.ndarray, np.ndarray] | None = None

    def take(self, rows: np.ndarray) -> "FitOutcome":
        """The fits ``rows`` (without alternatives)."""
        return FitOutcome(self.x[rows], self.chi2[rows], self.converged[rows],
                          self.n_evaluations[rows], self.stalled[rows])
