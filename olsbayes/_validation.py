"""Argument checks shared by the public boundary.

Each helper raises :class:`~olsbayes.errors.InputError` with a message that names
the argument, the value received and the accepted range, so that deep numpy
tracebacks never reach a user.
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence

import numpy as np

from .errors import InputError

__all__ = [
    "finite_array",
    "positive_float",
    "nonnegative_float",
    "integer",
    "as_rng",
]


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def finite_array(
    name: str,
    value: object,
    *,
    ndim: int | Sequence[int] | None = None,
    last: int | None = None,
    nonnegative: bool = False,
    allow_empty: bool = False,
) -> np.ndarray:
    """Return ``value`` as a float array after checking it.

    Parameters
    ----------
    name : str
        Argument name used in the error message.
    value : array_like
        The user's value.
    ndim : int or sequence of int, optional
        Accepted numbers of dimensions.
    last : int, optional
        Required length of the last axis.
    nonnegative : bool
        Reject negative entries.
    allow_empty : bool
        Accept arrays with zero elements.
    """
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(
            f"{name} must be an array of real numbers; got {_short(value)}"
        ) from None
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if arr.ndim not in allowed:
            raise InputError(
                f"{name} must have {' or '.join(map(str, allowed))} dimension(s); "
                f"got shape {arr.shape}"
            )
    if last is not None and (arr.ndim == 0 or arr.shape[-1] != last):
        raise InputError(
            f"{name} must have last axis of length {last}; got shape {arr.shape}"
        )
    if arr.size == 0 and not allow_empty:
        raise InputError(f"{name} must not be empty; got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} must be finite (no NaN or inf); got {_short(value)}")
    if nonnegative and np.any(arr < 0):
        raise InputError(
            f"{name} must be >= 0; got minimum {float(arr.min())!r}"
        )
    return arr


def positive_float(name: str, value: object, *, upper: float | None = None) -> float:
    """Check a finite scalar in (0, upper] (upper defaults to +inf)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(f"{name} must be a real number > 0; got {_short(value)}")
    x = float(value)
    if not np.isfinite(x) or x <= 0 or (upper is not None and x > upper):
        rng = f"(0, {upper}]" if upper is not None else "(0, inf)"
        raise InputError(f"{name} must be in {rng}; got {x!r}")
    return x


def nonnegative_float(name: str, value: object) -> float:
    """Check a finite scalar >= 0."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(f"{name} must be a real number >= 0; got {_short(value)}")
    x = float(value)
    if not np.isfinite(x) or x < 0:
        raise InputError(f"{name} must be in [0, inf); got {x!r}")
    return x


def integer(
    name: str, value: object, *, low: int | None = None, high: int | None = None
) -> int:
    """Check an integer in [low, high]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InputError(f"{name} must be an integer; got {_short(value)}")
    x = int(value)
    if (low is not None and x < low) or (high is not None and x > high):
        lo = "-inf" if low is None else str(low)
        hi = "inf" if high is None else str(high)
        raise InputError(f"{name} must be in [{lo}, {hi}]; got {x}")
    return x


def as_rng(rng: object, name: str = "rng") -> np.random.Generator:
    """Turn ``rng`` (None, seed, SeedSequence or Generator) into a Generator (SPEC 7)."""
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None or isinstance(rng, (numbers.Integral, np.random.SeedSequence)):
        if isinstance(rng, bool):
            raise InputError(f"{name} must be a numpy Generator, a seed or None; got {rng!r}")
        if isinstance(rng, numbers.Integral) and int(rng) < 0:
            raise InputError(f"{name} seed must be >= 0; got {int(rng)}")
        return np.random.default_rng(rng)
    raise InputError(
        f"{name} must be a numpy.random.Generator, a non-negative integer seed, "
        f"a SeedSequence or None; got {_short(rng)}"
    )
