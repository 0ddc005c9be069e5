"""Schema of configuration sections: fields, sections, the registry, validation."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError

__all__ = [
    "Field",
    "Section",
    "Config",
    "register_section",
    "get_section",
    "registered_sections",
    "validate_section",
    "MAX_ABS",
    "MAX_ELEMENTS",
    "MAX_CONFIG_BYTES",
    "MAX_DATA_BYTES",
]

#: Largest magnitude accepted for any number in a configuration file.
MAX_ABS = 1e12
#: Largest number of elements accepted for an array (inline or from a file).
MAX_ELEMENTS = 2_000_000
#: Largest configuration file accepted (bytes).
MAX_CONFIG_BYTES = 4 * 1024 * 1024
#: Largest data file accepted (bytes).
MAX_DATA_BYTES = 256 * 1024 * 1024

_KINDS = ("int", "float", "bool", "str", "array", "path")


@dataclass(frozen=True)
class Field:
    """One key of a section.

    Parameters
    ----------
    kind : {"int", "float", "bool", "str", "array", "path"}
        TOML type accepted; "float" also accepts TOML integers; "array" is a
        (nested) list of numbers; "path" is a string resolved against the
        configuration file's folder.
    required : bool
        Whether the key must be present.
    default : object
        Value used when the key is absent and not required.
    low, high : float, optional
        Inclusive bounds of an int or float.
    positive : bool
        Require a number > 0 (strict lower bound).
    choices : tuple of str, optional
        Accepted values of a str (compared case-insensitively, returned lower-case).
    ndim : tuple of int, optional
        Accepted numbers of dimensions of an array.
    doc : str
        One line for ``--help`` and error messages.
    """

    kind: str
    required: bool = False
    default: Any = None
    low: float | None = None
    high: float | None = None
    positive: bool = False
    choices: tuple[str, ...] | None = None
    ndim: tuple[int, ...] | None = None
    doc: str = ""

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise ValueError(f"Field kind must be one of {_KINDS}; got {self.kind!r}")


@dataclass(frozen=True)
class Section:
    """A ``[name]`` table: its fields and, optionally, variants.

    Parameters
    ----------
    name : str
        Table name in the TOML file.
    fields : mapping of str to Field
        Every key the section may hold.
    doc : str
        One line describing the section.
    variant_key : str, optional
        A str field whose value selects which other keys are accepted
        (e.g. ``geometry`` in ``[sensor]``).
    variants : mapping of str to tuple of str
        For each value of ``variant_key``, the keys accepted besides ``common``.
    common : tuple of str
        Keys accepted for every variant (``variant_key`` is always accepted).
    free : bool
        A table of free keys (``fields`` empty), returned as TOML gave it for its
        consumer to check, e.g. the setting axes of a study's ``[grid]``.
    """

    name: str
    fields: Mapping[str, Field]
    doc: str = ""
    variant_key: str | None = None
    variants: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    common: tuple[str, ...] = ()
    free: bool = False

    def accepted(self, variant: str | None = None) -> tuple[str, ...]:
        """Keys accepted for ``variant`` (all keys when the section has no variants)."""
        if self.variant_key is None or variant is None:
            return tuple(self.fields)
        keys = (self.variant_key,) + tuple(self.common) + tuple(self.variants[variant])
        return tuple(dict.fromkeys(keys))


_REGISTRY: dict[str, Section] = {}


def register_section(section: Section, *, replace: bool = False) -> Section:
    """Add ``section`` to the registry so :func:`load_config` can accept it.

    Raises ``ValueError`` if a section of that name exists and ``replace`` is False
    (a programming error, not a user error).
    """
    if not isinstance(section, Section):
        raise TypeError(f"section must be a Section; got {type(section).__name__}")
    if section.name in _REGISTRY and not replace and _REGISTRY[section.name] != section:
        raise ValueError(f"config section [{section.name}] is already registered")
    if section.variant_key is not None:
        keys = set(section.fields)
        for name in (section.variant_key, *section.common, *sum(section.variants.values(), ())):
            if name not in keys:
                raise ValueError(f"section [{section.name}] variant key {name!r} has no Field")
    _REGISTRY[section.name] = section
    return section


def get_section(name: str) -> Section:
    """The registered :class:`Section` called ``name``."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ConfigError(
            f"unknown config section [{name}]; registered: {', '.join(sorted(_REGISTRY))}"
        ) from None


def registered_sections() -> tuple[str, ...]:
    """Names of all registered sections."""
    return tuple(sorted(_REGISTRY))


@dataclass(frozen=True)
class Config:
    """A validated configuration.

    Attributes
    ----------
    tables : mapping of str to mapping
        Validated sections present in the file, defaults filled in; arrays are
        float ndarrays, paths are absolute :class:`~pathlib.Path` objects.
    source : str
        Where the configuration came from (a path or ``"<string>"``), for messages.
    base_dir : Path
        Folder against which relative paths were resolved.
    """

    tables: Mapping[str, Mapping[str, Any]]
    source: str = "<string>"
    base_dir: Path = Path(".")

    def __contains__(self, name: object) -> bool:
        return name in self.tables

    def section(self, name: str) -> Mapping[str, Any]:
        """The validated ``[name]`` table; ConfigError if absent."""
        if name not in self.tables:
            raise ConfigError(f"{self.source}: section [{name}] is required but missing")
        return self.tables[name]

    def get(self, name: str) -> Mapping[str, Any] | None:
        """The validated ``[name]`` table or None."""
        return self.tables.get(name)


# -- value checks ------------------------------------------------------------------
def _where(section: str, key: str) -> str:
    return f"[{section}] {key}"


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _check_number(where: str, value: Any, f: Field) -> float | int:
    if f.kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where} must be an integer; got {_short(value)}")
        x: float | int = value
    else:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where} must be a number; got {_short(value)}")
        if isinstance(value, int) and abs(value) > MAX_ABS:
            raise ConfigError(f"{where} must have magnitude <= {MAX_ABS:g}; got {value}")
        x = float(value)
        if not math.isfinite(x):
            raise ConfigError(f"{where} must be finite; got {x!r}")
    if abs(x) > MAX_ABS:
        raise ConfigError(f"{where} must have magnitude <= {MAX_ABS:g}; got {x!r}")
    lo = f.low if f.low is not None else -math.inf
    hi = f.high if f.high is not None else math.inf
    if x < lo or x > hi or (f.positive and x <= 0):
        left = "(0" if f.positive and lo <= 0 else f"[{lo:g}"
        raise ConfigError(f"{where} must be in {left}, {hi:g}]; got {x!r}")
    return x


def _check_nested(where: str, value: Any, depth: int = 0) -> None:
    if depth > 4:
        raise ConfigError(f"{where} is nested too deeply (at most 4 levels of lists)")
    for item in value:
        if isinstance(item, list):
            _check_nested(where, item, depth + 1)
        elif isinstance(item, bool) or not isinstance(item, (int, float)):
            raise ConfigError(f"{where} must hold numbers only; got {_short(item)}")
        elif isinstance(item, int) and abs(item) > MAX_ABS:
            raise ConfigError(
                f"{where} must have magnitudes <= {MAX_ABS:g}; got {_short(item)}"
            )


def _check_array(where: str, value: Any, f: Field) -> np.ndarray:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value]
    if not isinstance(value, list):
        raise ConfigError(f"{where} must be a list of numbers; got {_short(value)}")
    _check_nested(where, value)
    try:
        arr = np.asarray(value, dtype=float)
    except (ValueError, OverflowError):
        raise ConfigError(
            f"{where} must be a rectangular list of numbers; got a ragged list"
        ) from None
    if arr.size > MAX_ELEMENTS:
        raise ConfigError(f"{where} has {arr.size} numbers; at most {MAX_ELEMENTS} accepted")
    if f.ndim is not None and arr.ndim not in f.ndim and arr.size:
        raise ConfigError(
            f"{where} must have {' or '.join(map(str, f.ndim))} dimension(s); got shape {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{where} must be finite (no nan or inf); got {_short(value)}")
    if arr.size and np.abs(arr).max() > MAX_ABS:
        raise ConfigError(f"{where} must have magnitudes <= {MAX_ABS:g}")
    return arr


def _check_value(section: str, key: str, value: Any, f: Field, base: Path) -> Any:
    where = _where(section, key)
    if f.kind in ("int", "float"):
        return _check_number(where, value, f)
    if f.kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{where} must be true or false; got {_short(value)}")
        return value
    if f.kind == "array":
        return _check_array(where, value, f)
    if not isinstance(value, str):
        raise ConfigError(f"{where} must be a string; got {_short(value)}")
    if f.kind == "path":
        if not value or "\x00" in value:
            raise ConfigError(f"{where} must be a non-empty file path; got {_short(value)}")
        p = Path(value).expanduser()
        return p if p.is_absolute() else (base / p)
    if f.choices is not None:
        low = value.lower().replace("-", "_")
        if low not in f.choices:
            raise ConfigError(f"{where} must be one of {', '.join(f.choices)}; got {value!r}")
        return low
    return value


def validate_section(sec: Section, table: Any, base: Path) -> dict[str, Any]:
    """Check one TOML table against ``sec``; defaults filled in, values converted."""
    if not isinstance(table, dict):
        raise ConfigError(f"[{sec.name}] must be a table; got {_short(table)}")
    if sec.free:
        return dict(table)
    variant = None
    if sec.variant_key is not None:
        if sec.variant_key not in table:
            raise ConfigError(
                f"[{sec.name}] {sec.variant_key} is required; one of {', '.join(sec.variants)}"
            )
        variant = _check_value(sec.name, sec.variant_key, table[sec.variant_key],
                               sec.fields[sec.variant_key], base)
    accepted = sec.accepted(variant)
    for key in table:
        if key not in accepted:
            what = f" for {sec.variant_key} = {variant!r}" if variant else ""
            raise ConfigError(
                f"unknown key {key!r} in [{sec.name}]{what}; accepted keys: {', '.join(accepted)}"
            )
    out: dict[str, Any] = {}
    for key in accepted:
        f = sec.fields[key]
        if key in table:
            out[key] = _check_value(sec.name, key, table[key], f, base)
        elif f.required:
            raise ConfigError(f"[{sec.name}] {key} is required ({f.doc or f.kind})")
        elif f.default is not None:
            out[key] = f.default
    return out


