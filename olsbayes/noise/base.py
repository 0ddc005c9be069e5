"""The noise models' base: the interface every estimator sees, and frame helpers.

See :mod:`olsbayes.noise` for the interface and the records.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np

from .._validation import finite_array, integer
from ..errors import InputError

__all__ = ["NoiseModel", "MAX_COUNT", "frames_count"]


_LOG_2PI = math.log(2.0 * math.pi)
#: Largest count a Poisson reading may hold (float64 represents integers exactly below 2^53).
MAX_COUNT = 2.0**53
#: Smallest expected count used in a logarithm: a count where the model expects none
#: costs a large but finite penalty, so an optimiser can leave such a point.
_TINY = 1e-300


def _frames_of(data: np.ndarray, frames: bool) -> int:
    """Number of frames F of ``data`` (1 without a frame axis)."""
    return int(data.shape[-2]) if frames else 1


def _sum_frames(values: np.ndarray, frames: bool) -> np.ndarray:
    """Sum over the frame axis (-2) when there is one."""
    return values.sum(axis=-2) if frames else values


def _expand(mu: np.ndarray, frames: bool) -> np.ndarray:
    """``mu`` (..., N) broadcast against data with a frame axis (..., F, N)."""
    return mu[..., None, :] if frames else mu


class NoiseModel(ABC):
    """Base of the noise models (see the module docstring).

    ``theta`` arguments are the values (..., Q) of the noise parameters that are
    inferred (:attr:`inferred`; Q = 0 for the models without any), None meaning
    their nominal values (:meth:`nominal`).
    """

    #: Configuration name (``[noise] model``).
    kind: ClassVar[str] = ""
    #: Names of the noise parameters an estimator infers.
    inferred: ClassVar[tuple[str, ...]] = ()

    @property
    @abstractmethod
    def scale(self) -> float:
        """A nominal sd of one reading (reading units): unit checks and default priors."""

    @property
    def is_default(self) -> bool:
        """True for Gaussian noise of one known sigma (the package's default path)."""
        return False

    def nominal(self) -> np.ndarray:
        """Nominal (true) values (Q,) of the inferred noise parameters."""
        return np.zeros(0)

    def validate(self, n_sensors: int) -> None:
        """Refuse parameter vectors that do not fit an array of ``n_sensors``."""

    def check_data(self, data: object, n_sensors: int, *, frames: bool = False,
                   name: str = "data") -> np.ndarray:
        """Readings as a float array (..., N) or with frames (..., F, N), checked."""
        arr = finite_array(name, data, last=n_sensors)
        if frames and arr.ndim < 2:
            raise InputError(f"{name} with frames must have shape (..., F, {n_sensors}) "
                             f"(F frames of {n_sensors} readings); got shape {arr.shape}")
        return arr

    @abstractmethod
    def pointwise(self, mu: np.ndarray, data: np.ndarray, *, frames: bool = False,
                  theta: np.ndarray | None = None) -> np.ndarray:
        """Log density per sub-sensor (..., N), summed over frames."""

    def log_likelihood(self, mu: np.ndarray, data: np.ndarray, *, frames: bool = False,
                       theta: np.ndarray | None = None) -> np.ndarray:
        """Total log-likelihood (...,) of ``data`` given expected readings ``mu`` (..., N)."""
        return np.sum(self.pointwise(mu, data, frames=frames, theta=theta), axis=-1)

    @abstractmethod
    def score(self, mu: np.ndarray, data: np.ndarray, *, frames: bool = False,
              theta: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(d log L / d mu, w)``, each (..., N): gradient and Fisher weights at ``mu``."""

    @abstractmethod
    def weights(self, mu: np.ndarray, *, n_frames: int = 1,
                theta: np.ndarray | None = None) -> np.ndarray:
        """Fisher weights w (..., N): ``F = J^T diag(w) J`` for ``n_frames`` frames."""

    def theta_information(self, mu: np.ndarray, *, n_frames: int = 1,
                          theta: np.ndarray | None = None) -> np.ndarray:
        """Fisher information (..., Q, Q) of the inferred noise parameters.

        Their cross information with the mean parameters is zero for every model here.
        """
        return np.zeros(np.shape(mu)[:-1] + (0, 0))

    @abstractmethod
    def simulate(self, mu: np.ndarray, gen: np.random.Generator, shape: tuple[int, ...],
                 n_frames: int | None = None) -> np.ndarray:
        """Noisy readings ``shape + mu.shape`` (frames: ``shape + (F,) + mu.shape``)."""

    def describe(self) -> str:
        """One line naming the model and its settings."""
        return repr(self)



def frames_count(data: np.ndarray, frames: bool) -> int:
    """Number of frames of ``data`` (1 without frames); checked >= 1."""
    return integer("number of frames", _frames_of(data, frames), low=1)
