"""The fast ML estimator: grid search, batched Levenberg–Marquardt, kink moves, escalation.

:func:`fit_fast` runs the pipeline (:mod:`.pipeline`) with the settings of a
:class:`FastOptions` record (:mod:`.options`): the search for candidate sources on
a grid of atoms (:mod:`.search`, with the exhaustive K-tuple scan planned in
:mod:`.tuples`), the local refinement stages (:mod:`.refine`) and the exact refit
of close or lopsided ring fits (:mod:`.escalate`).
"""

from .options import FastOptions
from .pipeline import fit_fast

__all__ = ["FastOptions", "fit_fast"]
