"""InferenceData variables computed on their first access.

A posterior's per-sub-sensor log-likelihood is as large as its draws times the
readings, and only model comparison (LOO, WAIC) reads it.  :class:`Deferred`
holds the recipe instead: xarray sees an array of known shape and dtype (a
backend array, as a file opened lazily is) and the values are made once, by
the same computation, when any access needs them -- ``.values``, indexing,
ArviZ functions, saving to NetCDF, a copy or a pickle.  Nothing random is
deferred.  The module imports xarray: import it where ArviZ is imported.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np
import xarray as xr
from xarray.backends import BackendArray
from xarray.core import indexing

__all__ = ["Deferred", "DeferredArray"]


class Deferred:
    """Values (``shape``, float64) made by ``make()`` when first needed, then kept.

    Parameters
    ----------
    make : callable
        No arguments; returns the array (deterministic, so any time gives the same numbers).
    shape : tuple of int
    """

    def __init__(self, make: Callable[[], np.ndarray], shape: tuple[int, ...]):
        self._make, self.shape = make, tuple(int(n) for n in shape)
        self._values: np.ndarray | None = None
        self._lock = threading.Lock()

    def __getstate__(self) -> dict:
        return {"_make": None, "shape": self.shape, "_values": self.values()}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()

    def values(self) -> np.ndarray:
        """The array, made on the first call."""
        with self._lock:
            if self._values is None:
                out = np.asarray(self._make(), dtype=float)
                if out.shape != self.shape:  # pragma: no cover - a recipe of another shape
                    raise ValueError(f"deferred values of shape {out.shape}, not {self.shape}")
                self._values, self._make = out, None
            return self._values

    def placeholder(self) -> np.ndarray:
        """A read-only zero array of the same shape that takes no memory (for converters)."""
        return np.broadcast_to(np.float64(0.0), self.shape)

    def install(self, dataset, name: str) -> None:
        """Make variable ``name`` of ``dataset`` (its dims and attributes kept) these values."""
        var = dataset[name].variable
        dataset[name] = xr.Variable(var.dims, indexing.LazilyIndexedArray(DeferredArray(self)),
                                    attrs=dict(var.attrs), encoding=dict(var.encoding))


class DeferredArray(BackendArray):
    """xarray's view of a :class:`Deferred` (basic indexing; the rest is xarray's)."""

    def __init__(self, deferred: Deferred):
        self.deferred = deferred
        self.shape = deferred.shape
        self.dtype = np.dtype(float)

    def __getitem__(self, key):
        return indexing.explicit_indexing_adapter(
            key, self.shape, indexing.IndexingSupport.BASIC, self._get)

    def _get(self, key) -> np.ndarray:
        return self.deferred.values()[key]
