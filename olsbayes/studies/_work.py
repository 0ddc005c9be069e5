"""The task a worker runs: one chunk of trials of one grid cell."""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from ..errors import InputError
from .seeds import trial_rngs

__all__ = ["run_chunk", "vectorized", "is_vectorized", "stack_outputs"]

_FLAG = "olsbayes_vectorized"


def vectorized(fn: Callable) -> Callable:
    """Mark ``fn(settings, rngs)`` as a vectorised trial function.

    It receives a list of T Generators (one per trial, in trial order) and returns
    ``{name: array of shape (T, ...)}``.  Trial i must draw only from ``rngs[i]``
    for its results to be independent of the chunking.  Returns ``fn`` itself, so
    a decorated module-level function stays picklable.
    """
    setattr(fn, _FLAG, True)
    return fn


def is_vectorized(fn: Callable) -> bool:
    """True for functions marked with :func:`vectorized`."""
    return bool(getattr(fn, _FLAG, False))


def _as_numeric(name: str, value: object) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype.kind not in "biuf":
        raise InputError(
            f"trial output {name!r} must be numbers or bools (array of fixed shape); "
            f"got dtype {arr.dtype}"
        )
    return arr


def stack_outputs(outputs: list[Mapping]) -> dict[str, np.ndarray]:
    """Stack per-trial result dicts into ``{name: (T, ...)}``, checking names and shapes."""
    first = outputs[0]
    if not isinstance(first, Mapping) or not first:
        raise InputError(f"a trial function must return a non-empty dict of named numbers; "
                         f"got {type(first).__name__}")
    names = list(first)
    for out in outputs[1:]:
        if not isinstance(out, Mapping) or list(out) != names:
            got = list(out) if isinstance(out, Mapping) else type(out).__name__
            raise InputError(f"every trial must return the same names {names}; got {got}")
    stacked = {}
    for name in names:
        vals = [_as_numeric(name, out[name]) for out in outputs]
        shapes = {v.shape for v in vals}
        if len(shapes) > 1:
            raise InputError(f"trial output {name!r} must have a fixed shape; got {sorted(shapes)}")
        stacked[str(name)] = np.stack(vals)
    return stacked


def run_chunk(
    trial: Callable,
    settings: dict,
    entropy: int,
    cell: int,
    trials: np.ndarray,
) -> tuple[int, np.ndarray, dict[str, np.ndarray]]:
    """Run trials ``trials`` of cell ``cell``; return (cell, trials, {name: (T, ...)})."""
    rngs = trial_rngs(entropy, cell, trials)
    if is_vectorized(trial):
        out = trial(dict(settings), rngs)
        if not isinstance(out, Mapping) or not out:
            raise InputError(f"a vectorised trial function must return a non-empty dict of "
                             f"arrays; got {type(out).__name__}")
        values = {}
        for name, value in out.items():
            arr = _as_numeric(name, value)
            if arr.ndim == 0 or arr.shape[0] != len(trials):
                raise InputError(
                    f"vectorised trial output {name!r} must have leading axis {len(trials)} "
                    f"(one row per rng); got shape {arr.shape}"
                )
            values[str(name)] = arr
        return cell, trials, values
    return cell, trials, stack_outputs([trial(dict(settings), r) for r in rngs])
