"""The task a worker runs (one chunk of trials of one grid cell) and how trials declare themselves.

A trial is called as ``trial(settings, rng=generator)``, or, marked with
:func:`vectorized`, as ``trial(settings, rngs=[generator, ...])`` for a chunk.
:func:`trial_settings` declares which settings a trial reads and how some of
them are parsed, so that :func:`~olsbayes.studies.run_study` can refuse unknown
settings and bad values before any trial runs.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from types import MappingProxyType

import numpy as np

from ..errors import InputError
from .seeds import trial_rngs

__all__ = [
    "run_chunk",
    "vectorized",
    "is_vectorized",
    "trial_settings",
    "declared_settings",
    "trial_outputs",
    "declared_outputs",
    "check_signature",
    "stack_outputs",
]

_FLAG = "olsbayes_vectorized"
_SETTINGS = "olsbayes_settings"
_OUTPUTS = "olsbayes_outputs"


def vectorized(fn: Callable) -> Callable:
    """Mark ``fn(settings, *, rngs)`` as a vectorised trial function.

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


def trial_settings(*names: str, **parsers: Callable[[object, str], object]) -> Callable:
    """Declare the settings a trial reads; :func:`~olsbayes.studies.run_study` refuses others.

    Parameters
    ----------
    *names : str
        Settings read as plain numbers, strings or bools, unchecked.
    **parsers : callable
        Settings with a parser ``parser(value, where) -> value`` that validates a
        grid or fixed value (``where`` names it in errors, e.g.
        ``"grid['estimator'][1]"``) and returns a scalar or a record with a
        canonical ``label`` and ``to_json()``: a
        :class:`~olsbayes.studies.grid.Setting` (kind and range, e.g.
        ``n_sensors=Setting("int", 3, 10_000)``, so that a value that would make
        a trial allocate without bound is refused up front), or a parser such as
        :func:`~olsbayes.studies.estimator_spec.as_estimator`.

    Returns
    -------
    callable
        A decorator that records the declaration on the function and returns it.
    """
    declared = (frozenset(names) | frozenset(parsers), MappingProxyType(dict(parsers)))

    def mark(fn: Callable) -> Callable:
        setattr(fn, _SETTINGS, declared)
        return fn

    return mark


def declared_settings(fn: Callable) -> tuple[frozenset[str] | None, Mapping[str, Callable]]:
    """(accepted setting names or None when undeclared, parsers) of a trial."""
    return getattr(fn, _SETTINGS, (None, MappingProxyType({})))


def trial_outputs(**described: tuple[str, str]) -> Callable:
    """Describe a trial's outputs; :func:`~olsbayes.studies.run_study` writes them as attributes.

    Parameters
    ----------
    **described : (str, str)
        ``name=(long_name, units)`` per output, e.g. ``dir_err_rms=("RMS direction
        error", "rad")``; units in the CF convention (``"1"`` for a pure number, ``""``
        for none, e.g. a flag or a count of things).

    Returns
    -------
    callable
        A decorator that records the description on the function and returns it.
    """
    table = {}
    for name, pair in described.items():
        if not (isinstance(pair, tuple) and len(pair) == 2
                and all(isinstance(v, str) for v in pair)):
            raise InputError(f"trial_outputs {name}: give a (long_name, units) pair of strings; "
                             f"got {pair!r}")
        table[name] = pair
    frozen = MappingProxyType(table)

    def mark(fn: Callable) -> Callable:
        setattr(fn, _OUTPUTS, frozen)
        return fn

    return mark


def declared_outputs(fn: Callable) -> Mapping[str, tuple[str, str]]:
    """``{name: (long_name, units)}`` of a trial's described outputs (empty when undeclared)."""
    return getattr(fn, _OUTPUTS, MappingProxyType({}))


def check_signature(trial: Callable, name: str) -> None:
    """Refuse a trial that cannot be called as ``trial(settings, rng=...)``.

    Vectorised trials take ``rngs=`` instead.  Checked before any trial runs.
    """
    keyword = "rngs" if is_vectorized(trial) else "rng"
    try:
        sig = inspect.signature(trial)
    except (TypeError, ValueError):  # no signature to read (some builtins): try at run time
        return
    try:
        sig.bind({}, **{keyword: None})
    except TypeError:
        raise InputError(f"trial {name} must accept (settings, *, {keyword}); "
                         f"its signature is {sig}") from None


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
        out = trial(dict(settings), rngs=rngs)
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
    return cell, trials, stack_outputs([trial(dict(settings), rng=r) for r in rngs])
