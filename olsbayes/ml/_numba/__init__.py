"""Compiled (numba) twins of the ML wing's numpy code, each named after its counterpart.

=================  ==========================================================
module             compiles
=================  ==========================================================
``model``          the forward model and its Jacobian (:mod:`olsbayes.model`)
``linalg``         small dense solves (LU, Cholesky) for the kernels below
``lm``             bounded Levenberg–Marquardt (:mod:`olsbayes.ml.lm`)
``horizons``       its steps cut and sources held at sub-sensor horizons (for ``lm``)
``cells``          the linear cells where its runs stop at known optima (for ``lm``)
``fit``            a result's chi^2, Fisher matrix and covariance (:mod:`olsbayes.ml.fit`)
``refine``         kink hops and kink tests (:mod:`olsbayes.ml.fast.refine`)
``search``         pursuit, alternation, runners-up (:mod:`olsbayes.ml.fast.search`)
``tuples``         the exhaustive K-tuple scan (:mod:`olsbayes.ml.fast.tuples`)
``escalate``       which fits to refit exactly (:mod:`olsbayes.ml.fast.escalate`)
``exact``          the configuration scan (:mod:`olsbayes.ml.exact`)
``rivals``         rival optima of angle fits (:mod:`olsbayes.ml.rivals`)
``circular``       angle wrapping (:mod:`olsbayes.circular`)
``resolution``     doubts about Gaussian errors (:mod:`olsbayes.resolution`)
=================  ==========================================================

numba is imported when a kernel is first needed, not with the package: importing
this package only chooses numba's cache folder (:mod:`olsbayes._jit`).  Every
kernel is compiled once per machine and cached (``cache=True``).
"""

import numpy as np

from ..._jit import prepare

__all__ = ["kernel_array"]

prepare()  # numba's cache folder, before any kernel module imports numba


def kernel_array(a: object, dtype: type) -> np.ndarray:
    """``a`` as a C-contiguous, writeable array of ``dtype``: a kernel argument.

    ``np.require(a, dtype, ["C", "W"])`` (a copy only where needed), with the common
    case -- already such an array -- answered without numpy's argument parsing.
    Writeable and C-ordered, every call has the same array types: one compiled
    signature per kernel.
    """
    if type(a) is np.ndarray and a.dtype == dtype:
        flags = a.flags
        if flags.c_contiguous and flags.writeable:
            return a
    return np.require(a, dtype, ["C", "W"])
