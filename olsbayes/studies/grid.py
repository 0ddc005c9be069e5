"""Settings grids: validation, the cartesian cells, and a study's fingerprint."""

from __future__ import annotations

import itertools
import json
import numbers
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .._validation import _short
from ..errors import InputError

__all__ = ["Grid", "make_grid", "check_fixed", "RESERVED"]

#: Names a grid axis or a fixed setting may not take (dataset dimensions).
RESERVED = ("trial",)


def _scalar(name: str, value: object) -> int | float | str | bool:
    """A plain Python scalar usable as a coordinate and in JSON."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool | str):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        x = float(value)
        if not np.isfinite(x):
            raise InputError(f"{name} must be finite; got {x!r}")
        return x
    raise InputError(f"{name} must be a number, a string or a bool; got {_short(value)}")


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
        Plain Python values of each axis.
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
        return int(np.prod(self.shape, dtype=int))

    def cell(self, index: int) -> dict:
        """Settings of cell ``index`` (row-major order over the axes)."""
        idx = np.unravel_index(index, self.shape) if self.names else ()
        return {n: v[i] for n, v, i in zip(self.names, self.values, idx)}

    def cells(self) -> list[dict]:
        """All cells in row-major order."""
        return [dict(zip(self.names, combo)) for combo in itertools.product(*self.values)]

    def coords(self) -> dict[str, np.ndarray]:
        """Coordinate arrays for an xarray Dataset."""
        return {n: np.asarray(v) for n, v in zip(self.names, self.values)}

    def to_json(self) -> list:
        """JSON-able form (ordered list of [name, values])."""
        return [[n, list(v)] for n, v in zip(self.names, self.values)]


def make_grid(grid: object) -> Grid:
    """Validate ``grid``: a mapping ``{name: 1-D sequence of values}`` (may be empty)."""
    if not isinstance(grid, Mapping):
        raise InputError(f"grid must be a dict of setting axes {{name: [values]}}; "
                         f"got {_short(grid)}")
    names, values = [], []
    for key, axis in grid.items():
        name = _check_name("grid axis", key)
        if isinstance(axis, str | bytes) or not hasattr(axis, "__iter__"):
            raise InputError(f"grid[{name!r}] must be a list of values; got {_short(axis)}")
        vals = tuple(_scalar(f"grid[{name!r}] values", v) for v in np.asarray(axis).tolist()) \
            if isinstance(axis, np.ndarray) else tuple(_scalar(f"grid[{name!r}] values", v)
                                                       for v in axis)
        if not vals:
            raise InputError(f"grid[{name!r}] must hold at least one value; got none")
        kinds = {type(v) if not isinstance(v, int | float) or isinstance(v, bool) else float
                 for v in vals}
        if len(kinds) > 1:
            types = sorted(k.__name__ for k in kinds)
            raise InputError(f"grid[{name!r}] mixes value types {types}; use one type per axis")
        if len(set(vals)) != len(vals):
            raise InputError(f"grid[{name!r}] has repeated values {list(vals)}")
        names.append(name)
        values.append(vals)
    return Grid(tuple(names), tuple(values))


def check_fixed(fixed: object, grid: Grid) -> dict:
    """Validate fixed (non-swept) settings: scalars or lists of scalars, JSON-able."""
    if fixed is None:
        return {}
    if not isinstance(fixed, Mapping):
        raise InputError(f"fixed must be a dict of settings; got {_short(fixed)}")
    out = {}
    for key, value in fixed.items():
        name = _check_name("fixed setting", key)
        if name in grid.names:
            raise InputError(f"setting {name!r} is both a grid axis and fixed; keep one")
        if isinstance(value, list | tuple | np.ndarray):
            out[name] = [_scalar(f"fixed[{name!r}]", v) for v in np.asarray(value).tolist()]
        else:
            out[name] = _scalar(f"fixed[{name!r}]", value)
    json.dumps(out)  # guaranteed by _scalar; keeps the fingerprint well defined
    return out
