"""Public entry point :func:`fit_ml`: the plain Gaussian fit or the fit of any other measurement."""

from __future__ import annotations

import numpy as np

from .._validation import flag
from ..measurement import is_plain
from ..model import Model
from .fast import FastOptions
from .general import fit_general
from .multistart import MultistartOptions
from .plain import METHODS, fit_plain
from .result import MLResult

__all__ = ["fit_ml", "METHODS"]


def fit_ml(
    model: Model,
    data: np.ndarray,
    n_sources: int,
    method: str = "fast",
    *,
    options: FastOptions | MultistartOptions | None = None,
    grid: np.ndarray | None = None,
    rng: np.random.Generator | int | None = None,
    warn: bool = True,
    frames: bool = False,
) -> MLResult:
    """Maximum-likelihood fit of ``n_sources`` sources (Eq. 2), one or many data vectors.

    Parameters
    ----------
    model : Model
        Forward model (array, noise model, nuisance terms, sensitivity law); ring,
        sphere or plate.  Noise other than Gaussian of known sigma, nuisance terms
        and frames are fitted through a Gaussian surrogate and damped Fisher scoring
        (:mod:`olsbayes.ml.general`).
    data : array_like, shape (N,) or (T, N); with frames (F, N) or (T, F, N)
        Readings.  A batch fits T independent data vectors in one vectorised call.
    n_sources : int
        Number K of sources, 1 <= K and K (d + 1) <= N.
    method : {"fast", "multistart", "exact"}
        ``"fast"``: a polynomial-time global search on a grid of atoms (matching
        pursuit, alternating projection and the best K-tuples of coarse atom
        subsets), then joint bounded Levenberg–Marquardt with deterministic
        restarts and kink moves, batched over data vectors
        (:mod:`olsbayes.ml.fast`; deterministic).
        ``"multistart"``: the paper's baseline, pseudo-random starts each refined
        by L-BFGS-B (:mod:`olsbayes.ml.multistart`).
        ``"exact"``: the global optimum by enumerating the likelihood's linear
        cells (:mod:`olsbayes.ml.exact`); rings with the clipped cosine and K <= 4
        only; ``n_evaluations`` counts the configurations solved.
    options : FastOptions or MultistartOptions, optional
        The method's settings (default: the record's defaults); ``"exact"`` takes none.
    grid : array_like, shape (M, d), optional
        Candidate source locations for the search (default
        :func:`olsbayes.ml.atoms.default_grid`); also the box of multistart
        positions on a plate.
    rng : Generator, int or None
        Randomness of the multistart starts; the other methods are deterministic.
    warn : bool
        Warn :class:`~olsbayes.errors.ConvergenceWarning` when a fit did not converge
        or does not describe the readings (chi^2 / sigma^2 in a tail of the chi-squared
        law of N - P degrees of freedom, p < 1e-3 for the batch;
        :mod:`olsbayes.ml.honesty`), :class:`~olsbayes.errors.ResolutionWarning` when
        a standard error is infinite or NaN, :class:`~olsbayes.errors.MultimodalWarning`
        when a distinct local optimum is within 3 of a fit's log-likelihood
        (``MLResult.rival_gap``).  Warnings never change the result.
    frames : bool
        The data's second-to-last axis holds F frames of one static scene, fitted
        jointly (Poisson: one exposure per frame when the model's exposure is a vector).

    Returns
    -------
    MLResult
        Canonical-order estimates, log-likelihood, convergence flags, evaluation
        counts and the inverse-Fisher covariance at each estimate.

    Raises
    ------
    InputError
        Bad model, data (not real numbers, wrong length, non-finite, more than 2-D,
        far from sigma), n_sources, method, options (of another method, or out of
        range), grid, ``warn`` or ``frames`` (not True or False); more rows than the
        memory budget (:mod:`olsbayes._budget`).
    """
    warn = flag("warn", warn)
    if frames is not False or (isinstance(model, Model) and not is_plain(model)):
        return fit_general(model, data, n_sources, method, options=options, grid=grid,
                           rng=rng, warn=warn, frames=frames)
    return fit_plain(model, data, n_sources, method, options=options, grid=grid, rng=rng,
                     warn=warn)
