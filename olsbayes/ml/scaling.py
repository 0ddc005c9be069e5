"""Units of the readings: fits run on data scaled by a power of two into a fixed band.

The likelihood is covariant under a change of the readings' unit (data, sigma
and intensities scaled by one factor: the same angles, log-likelihood shifted by
N log of the factor), but the optimisers are not: Levenberg–Marquardt's initial
damping and eigenvalue floor mix angles (rad) with intensities (data units), and
L-BFGS-B's gradient tolerance is absolute, so fits of readings many orders of
magnitude from 1 stop short of the optimum.  :func:`olsbayes.ml.fit_ml` therefore divides each
data vector whose largest reading lies outside :data:`BAND` by the power of two
that brings it to 1 -- exact in floating point -- and scales the intensities and
residual sums back.  Data inside the band (readings of order 1, where the
tolerances were tuned) is not touched, so its fits are bit-for-bit those of an
unscaled fit.  Each trial has its own factor, so a batch still equals a loop of
single fits.
"""

from __future__ import annotations

import numpy as np

from ..model import Model
from .outcome import FitOutcome

__all__ = ["BAND", "reading_scales", "rescale", "scaled_model"]

#: Largest reading of a data vector within which it is fitted as is.
BAND = (2.0**-10, 2.0**10)


def reading_scales(data: np.ndarray) -> np.ndarray:
    """Power-of-two factor per data vector: (T, N) -> (T,).

    1 inside :data:`BAND` (and for an all-zero vector), else 2^round(log2 max |reading|).
    """
    top = np.max(np.abs(data), axis=-1)
    inside = (top == 0.0) | ((top >= BAND[0]) & (top <= BAND[1]))
    if inside.all():  # the usual case: every factor 1
        return np.ones(top.shape)
    with np.errstate(divide="ignore"):
        exp = np.where(inside, 0.0, np.round(np.log2(np.where(inside, 1.0, top))))
    return np.ldexp(1.0, exp.astype(np.int64))


def scaled_model(model: Model, scale: float) -> Model:
    """The model in readings divided by ``scale`` (sigma / scale); itself for 1."""
    if scale == 1.0:
        return model
    return model.with_sigma(model.sigma / scale)


def rescale(model: Model, out: FitOutcome, scale: np.ndarray) -> FitOutcome:
    """An outcome of data divided by ``scale`` (T,), in the original units.

    Intensities times the scale, residual sums of squares times its square.
    """
    d1 = model.n_loc + 1

    def up(x: np.ndarray) -> np.ndarray:
        x = x.copy()
        x[..., d1 - 1 :: d1] *= scale.reshape(scale.shape + (1,) * (x.ndim - 1))
        return x

    alt = out.alternatives
    if alt is not None:
        alt = (up(alt[0]), alt[1] * (scale**2)[:, None])
    return FitOutcome(up(out.x), out.chi2 * scale**2, out.converged, out.n_evaluations,
                     out.stalled, alt)
