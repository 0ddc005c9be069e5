"""Argument checks shared by the public boundary.

Each helper raises :class:`~olsbayes.errors.InputError` with a message that names
the argument, the value received and the accepted range, so that deep numpy
tracebacks never reach a user.
"""

from __future__ import annotations

import numbers
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .errors import InputError

__all__ = [
    "real_array",
    "finite_array",
    "noise_sd",
    "check_reading_range",
    "SIGMA_RANGE",
    "READING_RATIO",
    "DTYPE_KINDS",
    "positive_float",
    "nonnegative_float",
    "integer",
    "flag",
    "choice",
    "file_path",
    "as_rng",
]


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


#: Accepted noise standard deviations (reading units): sigma^2, 1 / sigma^2 and the
#: Fisher information ~ N (I / sigma)^2 stay far inside the floating-point range.
SIGMA_RANGE = (1e-100, 1e100)
#: Largest ratio, either way, of a data vector's largest |reading| to sigma (an all-zero
#: vector is accepted): the likelihood's (reading / sigma)^2 and the fits' internal
#: rescaling of the readings stay within floating point.  Beyond ~1e13 the noise lies
#: below the rounding of float64 readings (16 digits), and fits warn that chi^2 does
#: not follow sigma (:mod:`olsbayes.ml.honesty`).
READING_RATIO = 1e90

#: dtype kinds refused as numbers, with the name used in messages.
DTYPE_KINDS = {"b": "bool", "c": "complex", "U": "string", "S": "bytes", "M": "datetime",
             "m": "timedelta", "O": "object", "V": "structured"}


def real_array(name: str, value: object) -> np.ndarray:
    """``value`` as a float64 array, refusing anything that is not real numbers.

    Integer and floating dtypes are converted; complex, bool, string, bytes,
    datetime, timedelta, object and structured arrays are refused (a complex
    array would lose its imaginary part, a string or datetime would be parsed or
    counted as a number), and so are masked arrays with masked entries (numpy
    would drop the mask).  The message names the argument and the dtype, never
    the values.
    """
    if type(value) is np.ndarray and value.dtype == np.float64:
        return value
    if isinstance(value, np.ma.MaskedArray) and np.ma.is_masked(value):
        raise InputError(f"{name} has masked entries; drop or fill them first "
                         "(e.g. value.filled(...) or value.compressed())")
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be an array of real numbers; got a ragged or "
                         f"non-numeric {type(value).__name__}") from None
    kind = DTYPE_KINDS.get(raw.dtype.kind)
    if kind is None and raw.dtype.kind not in "fiu":
        kind = str(raw.dtype)
    if kind is not None:
        hint = (" (or numbers too large for a float)" if kind == "object" else "")
        raise InputError(f"{name} must be an array of real numbers (int or float); got "
                         f"{kind} values of dtype {raw.dtype}{hint}")
    try:
        return raw.astype(np.float64, copy=False)
    except (TypeError, ValueError, OverflowError):  # pragma: no cover - fiu always casts
        raise InputError(f"{name} must be an array of real numbers; got dtype {raw.dtype}"
                         ) from None


def noise_sd(name: str, value: object) -> float:
    """Check a noise standard deviation: a real number in :data:`SIGMA_RANGE`."""
    lo, hi = SIGMA_RANGE
    x = positive_float(name, value)
    if not lo <= x <= hi:
        raise InputError(
            f"{name} must be in [{lo:g}, {hi:g}] (reading units; express the readings in "
            f"a unit that brings the noise level into this range); got {x!r}")
    return x


def check_reading_range(name: str, data: np.ndarray, sigma: float) -> None:
    """Refuse data vectors whose largest |reading| is not within a factor of sigma.

    The factor is :data:`READING_RATIO`, either way; all-zero vectors pass.
    ``data`` (..., N) holds finite floats; each vector along the last axis is checked.
    """
    if data.size == 0:
        return
    top = np.max(np.abs(data), axis=-1)
    high = top > READING_RATIO * sigma
    low = (top > 0) & (top < sigma / READING_RATIO)
    if np.any(high) or np.any(low):
        worst = float(np.max(top[high])) if np.any(high) else float(np.min(top[low]))
        raise InputError(
            f"{name}: the largest |reading| of a data vector must be within a factor "
            f"{READING_RATIO:g} of sigma = {sigma:g} (or all readings 0); got {worst:.3g} "
            "(check the units of the readings and of sigma)")


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

    The dtype rules are those of :func:`real_array` (real numbers only).

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
    arr = real_array(name, value)
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


def positive_pair(name: str, value: object) -> tuple[float, float]:
    """Check a pair (a, b) of finite numbers > 0 (e.g. a Beta distribution's shapes)."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
        raise InputError(f"{name} must be a pair (a, b) of numbers > 0; got {_short(value)}")
    return positive_float(name, value[0]), positive_float(name, value[1])


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


def flag(name: str, value: object) -> bool:
    """Check a switch: True or False (a numpy bool too; not 0, 1 or a string)."""
    if not isinstance(value, (bool, np.bool_)):
        raise InputError(f"{name} must be True or False; got {_short(value)}")
    return bool(value)


def choice(name: str, value: object, allowed: tuple[str, ...]) -> str:
    """Check a name among ``allowed`` (a string; not an array, list or other object)."""
    if not isinstance(value, str) or value not in allowed:
        raise InputError(f"{name} must be one of {allowed}; got {_short(value)}")
    return value


def file_path(name: str, value: object) -> Path:
    """Check a file or folder path: a non-empty str or os.PathLike (not bytes or a number)."""
    text = os.fspath(value) if isinstance(value, (str, os.PathLike)) else None
    if not isinstance(text, str) or not text or "\0" in text:
        raise InputError(f"{name} must be a file path (a non-empty str or os.PathLike); "
                         f"got {_short(value)}")
    return Path(text)


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
