"""Priors on the number of sources K, for model comparison.

Both priors live on ``{0, 1, ..., k_max}``.  They are priors on the *number*
of sources only; how the parameters of K exchangeable sources are weighted is
the business of :class:`~olsbayes.priors.ScenePrior` (see its Notes on K!).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from .._validation import as_rng, integer, positive_float
from ..errors import InputError

__all__ = ["CountPrior", "PoissonCount", "UniformCount"]


class CountPrior(ABC):
    """Base class: a probability mass function on ``0..k_max``."""

    k_max: int

    @abstractmethod
    def _log_weights(self) -> np.ndarray:
        """Unnormalised log masses of 0..k_max, shape (k_max + 1,)."""

    @property
    def support(self) -> np.ndarray:
        """The allowed K, ``arange(k_max + 1)``."""
        return np.arange(self.k_max + 1)

    def log_pmf_table(self) -> np.ndarray:
        """Normalised log probabilities of K = 0..k_max, shape (k_max + 1,)."""
        w = self._log_weights()
        top = w.max()
        return w - (top + np.log(np.exp(w - top).sum()))

    def log_prob(self, k: np.ndarray | int) -> np.ndarray:
        """log P(K = k) for integer ``k`` (any shape); ``-inf`` outside 0..k_max."""
        arr = np.asarray(k)
        if arr.dtype.kind not in "iu":
            if arr.dtype.kind != "f" or np.any(arr[np.isfinite(arr)] % 1):
                raise InputError(f"k must hold integers; got {k!r}")
            arr = np.where(np.isfinite(arr), arr, -1).astype(int)
        table = self.log_pmf_table()
        inside = (arr >= 0) & (arr <= self.k_max)
        out = np.where(inside, table[np.clip(arr, 0, self.k_max)], -np.inf)
        return out if out.ndim else float(out)

    def pmf(self, k: np.ndarray | int) -> np.ndarray:
        """P(K = k)."""
        return np.exp(self.log_prob(k))

    def sample(self, size: int | tuple[int, ...] | None = None, *,
               rng: object = None) -> np.ndarray:
        """Draws of K, integer array of shape ``size``."""
        gen = as_rng(rng)
        return gen.choice(self.support, size=size, p=np.exp(self.log_pmf_table()))


@dataclass(frozen=True)
class PoissonCount(CountPrior):
    """Poisson(``mean``) truncated to ``0..k_max`` and renormalised."""

    mean: float
    k_max: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "mean", positive_float("mean", self.mean))
        object.__setattr__(self, "k_max", integer("k_max", self.k_max, low=0))

    def _log_weights(self) -> np.ndarray:
        from scipy.special import gammaln

        k = self.support
        return k * np.log(self.mean) - gammaln(k + 1.0)


@dataclass(frozen=True)
class UniformCount(CountPrior):
    """Uniform on ``0..k_max`` (or ``k_min..k_max``)."""

    k_max: int
    k_min: int = 0

    def __post_init__(self) -> None:
        k_max = integer("k_max", self.k_max, low=0)
        k_min = integer("k_min", self.k_min, low=0, high=k_max)
        object.__setattr__(self, "k_max", k_max)
        object.__setattr__(self, "k_min", k_min)

    def _log_weights(self) -> np.ndarray:
        return np.where(self.support >= self.k_min, 0.0, -np.inf)
