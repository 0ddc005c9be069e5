"""Maximum-likelihood estimation of source directions/positions and intensities (Eq. 2).

:func:`fit_ml` fits K sources to one data vector (N,) or a batch (T, N):

* ``method="fast"`` -- polynomial-time: candidate sources from a grid of atoms
  (matching pursuit + alternating projection, and for K >= 2 the best K-tuple of
  a few coarse atom subsets with intensities solved linearly; at K = 4 the
  tuples of 24 subsets only), then batched
  bounded Levenberg–Marquardt with the analytic Jacobian and a few deterministic
  perturbed restarts and kink hops against the false minima of the clipped
  cosine's kink.
  Deterministic, vectorised over trials: a batch equals a loop of single fits;
* ``method="multistart"`` -- the paper's baseline: pseudo-random starts refined
  by a quasi-Newton method (L-BFGS-B).

Results are :class:`MLResult` objects (frozen) with the estimate in canonical
order, its log-likelihood, convergence flags and the inverse Fisher matrix.
:func:`refine_batch` (bounded LM from given starts, batched) and
:func:`estimation_errors` (errors after matching estimated to true sources) are
building blocks for model selection and simulation studies.
"""

from .api import METHODS, fit_ml
from .batch import refine_batch
from .exact import ExactResult, fit_exact
from .grid import default_grid
from .result import MLResult

__all__ = [
    "fit_ml", "MLResult", "METHODS", "refine_batch", "default_grid",
    "fit_exact", "ExactResult",
]
