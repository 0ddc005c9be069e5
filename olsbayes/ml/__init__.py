"""Maximum-likelihood estimation of source directions/positions and intensities (Eq. 2).

:func:`fit_ml` fits K sources to one data vector (N,) or a batch (T, N) and returns
an :class:`MLResult` (frozen): the estimate in canonical order, its
log-likelihood, convergence flags, the inverse Fisher matrix and the gap to the
best rival optimum found.  Its methods:

* ``"fast"`` (:mod:`.fast`, settings :class:`FastOptions`) -- polynomial-time:
  candidate sources from a grid of atoms, then batched bounded
  Levenberg–Marquardt (:mod:`.lm`) with deterministic restarts and kink moves;
  a batch equals a loop of single fits;
* ``"multistart"`` (:mod:`.multistart`, settings :class:`MultistartOptions`) --
  the paper's baseline: pseudo-random starts refined by L-BFGS-B;
* ``"exact"`` (:mod:`.exact`) -- the global optimum of a ring with the clipped
  cosine by enumerating the likelihood's linear cells.

Around them: the readings' units (:mod:`.scaling`), candidate atoms
(:mod:`.atoms`), rival optima (:mod:`.rivals`) and the compiled twins
(:mod:`._numba`).  :func:`refine_batch` (bounded LM from given starts, batched)
and :func:`default_grid` are building blocks for model selection and studies.
"""

from .atoms import default_grid
from .fast import FastOptions
from .fit import METHODS, fit_ml
from .lm import refine_batch
from .multistart import MultistartOptions
from .result import MLResult

__all__ = ["fit_ml", "MLResult", "METHODS", "FastOptions", "MultistartOptions",
           "refine_batch", "default_grid"]
