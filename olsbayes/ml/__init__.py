"""Maximum-likelihood estimation of source directions/positions and intensities (Eq. 2).

:func:`fit_ml` fits K sources to one data vector (N,) or a batch (T, N):

* ``method="fast"`` -- polynomial-time: matching pursuit and alternating
  projection on a grid of atoms, then batched bounded Levenberg–Marquardt with
  the analytic Jacobian and a few deterministic perturbed restarts;
* ``method="multistart"`` -- the paper's baseline: pseudo-random starts refined
  by a quasi-Newton method (L-BFGS-B).

Results are :class:`MLResult` objects (frozen) with the estimate in canonical
order, its log-likelihood, convergence flags and the inverse Fisher matrix.
"""

from .api import METHODS, fit_ml
from .batch import refine_batch
from .evaluate import estimation_errors
from .grid import default_grid
from .result import MLResult

__all__ = [
    "fit_ml", "MLResult", "METHODS", "refine_batch", "default_grid", "estimation_errors",
]
