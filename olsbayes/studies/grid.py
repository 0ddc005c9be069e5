"""Settings grids: validation, the cartesian cells, and a study's fingerprint.

A setting value is a plain scalar (number, string or bool) or a *record*: an
immutable, hashable object with a canonical ``label`` (the dataset coordinate)
and a ``to_json()`` form (the fingerprint), such as
:class:`~olsbayes.studies.estimator_spec.Estimator`.  A trial turns other
spellings into records through the parsers it declares with
:func:`~olsbayes.studies.trial_settings`.
"""

from __future__ import annotations

import difflib
import itertools
import json
import math
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from .._validation import _short
from ..errors import InputError

__all__ = [
    "Grid",
    "Setting",
    "SettingRecord",
    "make_grid",
    "check_fixed",
    "check_known",
    "settings_json",
    "RESERVED",
]

#: Names a grid axis or a fixed setting may not take (dataset dimensions).
RESERVED = ("trial",)

Parsers = Mapping[str, Callable[[object, str], object]]


@runtime_checkable
class SettingRecord(Protocol):
    """A setting value other than a scalar: frozen, hashable, picklable, labelled."""

    @property
    def label(self) -> str:
        """Canonical text, equal for equal records (the dataset coordinate)."""

    def to_json(self) -> Any:
        """JSON form (part of the study's fingerprint)."""


def _scalar(name: str, value: object) -> Any:
    """A plain Python scalar usable as a coordinate and in JSON, or a record."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool | str | SettingRecord):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        x = float(value)
        if not np.isfinite(x):
            raise InputError(f"{name} must be finite; got {x!r}")
        return x
    raise InputError(f"{name} must be a number, a string or a bool; got {_short(value)}")


@dataclass(frozen=True)
class Setting:
    """The kind and accepted range of one setting of a trial (see ``trial_settings``).

    Calling it checks one grid or fixed value and returns it unchanged, so it
    serves as that setting's parser.

    Parameters
    ----------
    kind : {"int", "float", "bool", "str"}
        Accepted type; "float" also accepts integers.
    low, high : float, optional
        Inclusive bounds of a number.
    positive : bool
        Require a number > 0.
    """

    kind: str
    low: float | None = None
    high: float | None = None
    positive: bool = False

    def __post_init__(self) -> None:
        if self.kind not in ("int", "float", "bool", "str"):
            raise ValueError(f"Setting kind must be int, float, bool or str; got {self.kind!r}")

    def describe(self) -> str:
        """The accepted values in words, e.g. ``"an integer in [3, 10000]"``."""
        if self.kind in ("bool", "str"):
            return {"bool": "true or false", "str": "a string"}[self.kind]
        lo = "(0" if self.positive and (self.low is None or self.low <= 0) else (
            "(-inf" if self.low is None else f"[{self.low:g}")
        hi = "inf)" if self.high is None else f"{self.high:g}]"
        return f"{'an integer' if self.kind == 'int' else 'a number'} in {lo}, {hi}"

    def __call__(self, value: object, where: str) -> Any:
        """``value`` if it is of this kind and in range, else InputError naming ``where``."""
        if isinstance(value, np.generic):
            value = value.item()
        kinds = {"int": numbers.Integral, "float": numbers.Real, "bool": bool, "str": str}
        ok = isinstance(value, kinds[self.kind]) and (
            self.kind == "bool" or not isinstance(value, bool))
        if ok and self.kind in ("int", "float"):
            x = float(value) if abs(value) < 1e300 else math.inf
            ok = (math.isfinite(x) and (self.low is None or x >= self.low)
                  and (self.high is None or x <= self.high) and (not self.positive or x > 0))
        if not ok:
            raise InputError(f"{where} must be {self.describe()}; got {_short(value)}")
        return value


def _value(where: str, value: object, parser: Callable | None) -> Any:
    """``value`` through the trial's parser for its setting (if any), then checked."""
    return _scalar(where, parser(value, where) if parser is not None else value)


def _json(value: object) -> Any:
    return value.to_json() if isinstance(value, SettingRecord) else value


def settings_json(settings: Mapping) -> dict:
    """JSON form of checked fixed settings (records as their ``to_json()``)."""
    return {k: [_json(x) for x in v] if isinstance(v, list) else _json(v)
            for k, v in settings.items()}


def _check_name(what: str, key: object) -> str:
    if not isinstance(key, str) or not key.isidentifier() or key in RESERVED:
        raise InputError(
            f"{what} names must be Python identifiers other than {RESERVED}; got {key!r}"
        )
    return key


@dataclass(frozen=True)
class Grid:
    """Validated setting axes, in the user's order.

    Attributes
    ----------
    names : tuple of str
        Axis names (dataset dimensions).
    values : tuple of tuple
        Values of each axis: plain Python scalars or records.
    """

    names: tuple[str, ...]
    values: tuple[tuple, ...]

    @property
    def shape(self) -> tuple[int, ...]:
        """Length of each axis."""
        return tuple(len(v) for v in self.values)

    @property
    def n_cells(self) -> int:
        """Number of setting combinations (1 for an empty grid)."""
        return math.prod(self.shape)

    def cell(self, index: int) -> dict:
        """Settings of cell ``index`` (row-major order over the axes)."""
        idx = np.unravel_index(index, self.shape) if self.names else ()
        return {n: v[i] for n, v, i in zip(self.names, self.values, idx)}

    def cells(self) -> list[dict]:
        """All cells in row-major order."""
        return [dict(zip(self.names, combo)) for combo in itertools.product(*self.values)]

    def coords(self) -> dict[str, np.ndarray]:
        """Coordinate arrays for an xarray Dataset (records by their labels)."""
        return {n: np.asarray([v.label if isinstance(v, SettingRecord) else v for v in vals])
                for n, vals in zip(self.names, self.values)}

    def to_json(self) -> list:
        """JSON-able form (ordered list of [name, values])."""
        return [[n, [_json(x) for x in v]] for n, v in zip(self.names, self.values)]


def make_grid(grid: object, parsers: Parsers | None = None) -> Grid:
    """Validate ``grid``: a mapping ``{name: 1-D sequence of values}`` (may be empty).

    ``parsers[name](value, where)`` turns each value of axis ``name`` into a scalar
    or a record first (see :func:`~olsbayes.studies.trial_settings`).
    """
    if not isinstance(grid, Mapping):
        raise InputError(f"grid must be a dict of setting axes {{name: [values]}}; "
                         f"got {_short(grid)}")
    parsers = parsers or {}
    names, values = [], []
    for key, axis in grid.items():
        name = _check_name("grid axis", key)
        if isinstance(axis, str | bytes | Mapping) or not hasattr(axis, "__iter__"):
            raise InputError(f"grid[{name!r}] must be a list of values; got {_short(axis)}")
        items = np.asarray(axis).tolist() if isinstance(axis, np.ndarray) else list(axis)
        vals = tuple(_value(f"grid[{name!r}][{i}]", v, parsers.get(name))
                     for i, v in enumerate(items))
        if not vals:
            raise InputError(f"grid[{name!r}] must hold at least one value; got none")
        kinds = {type(v) if not isinstance(v, int | float) or isinstance(v, bool) else float
                 for v in vals}
        if len(kinds) > 1:
            types = sorted(k.__name__ for k in kinds)
            raise InputError(f"grid[{name!r}] mixes value types {types}; use one type per axis")
        shown = [v.label if isinstance(v, SettingRecord) else v for v in vals]
        if len(set(shown)) != len(shown):
            raise InputError(f"grid[{name!r}] has repeated values {shown}")
        names.append(name)
        values.append(vals)
    return Grid(tuple(names), tuple(values))


def check_fixed(fixed: object, grid: Grid, parsers: Parsers | None = None) -> dict:
    """Validate fixed (non-swept) settings: scalars, records or lists of scalars.

    A setting with a parser (see :func:`make_grid`) is parsed as one value.
    """
    if fixed is None:
        return {}
    if not isinstance(fixed, Mapping):
        raise InputError(f"fixed must be a dict of settings; got {_short(fixed)}")
    parsers = parsers or {}
    out = {}
    for key, value in fixed.items():
        name = _check_name("fixed setting", key)
        if name in grid.names:
            raise InputError(f"setting {name!r} is both a grid axis and fixed; keep one")
        if name in parsers:
            out[name] = _value(f"fixed[{name!r}]", value, parsers[name])
        elif isinstance(value, list | tuple | np.ndarray):
            items = value.tolist() if isinstance(value, np.ndarray) else value
            out[name] = [_scalar(f"fixed[{name!r}][{i}]", v) for i, v in enumerate(items)]
        else:
            out[name] = _scalar(f"fixed[{name!r}]", value)
    json.dumps(settings_json(out))  # keeps the fingerprint well defined
    return out


def check_known(names: object, known: frozenset[str] | None, trial: str) -> None:
    """Refuse settings that ``trial`` does not read (``known`` None: not declared)."""
    if known is None:
        return
    for name in names:
        if name not in known:
            close = difflib.get_close_matches(name, sorted(known), n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise InputError(f"setting {name!r} is not read by trial {trial}; {hint}accepted "
                             f"settings: {', '.join(sorted(known))}")
