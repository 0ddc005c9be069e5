"""Poisson counts with an exposure time and a dark rate."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .._validation import finite_array, real_array
from ..errors import InputError
from .base import _TINY, MAX_COUNT, NoiseModel, _frames_of, _sum_frames

__all__ = ["Poisson"]


@dataclass(frozen=True)
class Poisson(NoiseModel):
    """Counting noise: readings are counts ~ Poisson(exposure * (mu + dark)).

    Parameters
    ----------
    exposure : float or ndarray (F,)
        Exposure time (> 0) converting the rate ``mu + dark`` into expected counts;
        a vector gives one exposure per frame (data with frames of that length).
    dark : float or ndarray (N,)
        Known dark rate (>= 0) of every sub-sensor, in the units of ``mu``.

    Notes
    -----
    The Fisher weight of a sub-sensor is ``exposure / (mu + dark)``.  With no dark
    rate and no background, a sub-sensor just inside a source's horizon expects
    almost no count yet carries a large weight, and one just past it expects none
    at all: the bound of such a scene is dominated by these sub-sensors and ML
    intervals built on it undercover.  A realistic dark rate (or background) keeps
    every expected count positive.
    """

    exposure: float | np.ndarray = 1.0
    dark: float | np.ndarray = 0.0
    kind: ClassVar[str] = "poisson"

    def __post_init__(self) -> None:
        e = finite_array("exposure", self.exposure, ndim=(0, 1))
        if np.any(e <= 0):
            raise InputError(f"exposure must be > 0 (a time); got minimum {float(e.min())!r}")
        d = finite_array("dark", self.dark, ndim=(0, 1), nonnegative=True)
        for name, arr in (("exposure", e), ("dark", d)):
            value = float(arr) if arr.ndim == 0 else arr.copy()
            if arr.ndim:
                value.flags.writeable = False
            object.__setattr__(self, name, value)

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Poisson) and np.array_equal(self.exposure, other.exposure)
                and np.array_equal(self.dark, other.dark))

    __hash__ = None  # type: ignore[assignment]

    @property
    def scale(self) -> float:
        """One count, in rate units: 1 / mean exposure."""
        return float(1.0 / np.mean(self.exposure))

    @property
    def n_frames(self) -> int | None:
        """Frames the exposure vector describes (None for one scalar exposure)."""
        return None if np.ndim(self.exposure) == 0 else int(np.size(self.exposure))

    def total_exposure(self, n_frames: int = 1) -> float:
        """Sum of the exposures of ``n_frames`` frames (the vector's sum when given)."""
        return float(np.sum(self.exposure)) if np.ndim(self.exposure) else (
            n_frames * float(self.exposure))

    def validate(self, n_sensors):
        """A dark vector must hold one rate per sub-sensor."""
        if np.ndim(self.dark) and np.shape(self.dark) != (n_sensors,):
            raise InputError(f"dark must be a number or one rate per sub-sensor, shape "
                             f"({n_sensors},); got shape {np.shape(self.dark)}")

    def check_data(self, data, n_sensors, *, frames=False, name="data"):
        """Counts: non-negative integers below 2^53, frames matching the exposures."""
        arr = real_array(name, data)
        if arr.ndim == 0 or arr.shape[-1] != n_sensors:
            raise InputError(f"{name} must have last axis of length {n_sensors}; got shape "
                             f"{arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{name} must be finite counts (no NaN or inf)")
        if np.any(arr < 0) or np.any(arr != np.round(arr)) or np.any(arr > MAX_COUNT):
            raise InputError(f"{name} under Poisson noise must hold counts: integers in "
                             f"[0, 2^53]; got {self._worst(arr)}")
        if frames and arr.ndim < 2:
            raise InputError(f"{name} with frames must have shape (..., F, {n_sensors}); "
                             f"got shape {arr.shape}")
        f = self.n_frames
        if f is not None and (not frames or arr.shape[-2] != f):
            raise InputError(f"{name} must hold {f} frames (one per exposure), shape "
                             f"(..., {f}, {n_sensors}) with frames=True; got shape {arr.shape}")
        return arr

    @staticmethod
    def _worst(arr: np.ndarray) -> str:
        bad = arr[(arr < 0) | (arr != np.round(arr)) | (arr > MAX_COUNT)]
        return f"{float(bad[0])!r}"

    def _lam(self, mu: np.ndarray, frames: bool) -> np.ndarray:
        """Expected counts: exposure * (mu + dark), per frame with frames."""
        rate = mu + self.dark
        if not frames:
            return self.exposure * rate
        e = np.asarray(self.exposure, float)
        return (e[:, None] if e.ndim else e) * rate[..., None, :]

    def pointwise(self, mu, data, *, frames=False, theta=None):
        """``s log lambda - lambda - log s!`` per sub-sensor, summed over frames."""
        from scipy.special import gammaln, xlogy  # on use: scipy is slow to import
        lam = self._lam(np.asarray(mu, float), frames)
        with np.errstate(divide="ignore"):
            term = xlogy(data, np.maximum(lam, _TINY)) - lam - gammaln(data + 1.0)
        return _sum_frames(term, frames)

    def score(self, mu, data, *, frames=False, theta=None):
        """``S / (mu + dark) - E`` and ``E / (mu + dark)``: S the counts summed over frames."""
        rate = np.maximum(np.asarray(mu, float) + self.dark, _TINY)
        counts = _sum_frames(data, frames)
        e_tot = self.total_exposure(_frames_of(data, frames))
        return counts / rate - e_tot, e_tot / rate

    def weights(self, mu, *, n_frames=1, theta=None):
        """E / (mu + dark), with E the total exposure: the Poisson Fisher weights."""
        rate = np.maximum(np.asarray(mu, float) + self.dark, _TINY)
        return self.total_exposure(n_frames) / rate

    def simulate(self, mu, gen, shape, n_frames=None):
        """Poisson counts of mean exposure * (mu + dark); one frame per exposure entry."""
        if n_frames is None and self.n_frames is not None:
            n_frames = self.n_frames
        lam = self._lam(np.asarray(mu, float), n_frames is not None)
        if n_frames is not None and self.n_frames is None:
            lam = np.repeat(lam, n_frames, axis=-2)
        if np.any(lam < 0):
            raise InputError("Poisson simulation needs expected counts >= 0 (a negative "
                             "offset or rate?)")
        return gen.poisson(np.broadcast_to(lam, shape + lam.shape)).astype(float)

    def __repr__(self) -> str:
        def short(v):
            return f"{v!r}" if np.ndim(v) == 0 else f"<{np.size(v)} values>"
        return f"Poisson(exposure={short(self.exposure)}, dark={short(self.dark)})"

