"""TOML configuration files: a small schema registry, strict validation, builders.

A configuration file describes a sensor, a scene and (optionally) readings::

    [sensor]
    geometry = "ring"          # ring | sphere | plate | custom
    n = 30
    sigma = 0.01               # noise std of one sub-sensor (reading units)
    sensitivity = "cosine"     # cosine (alias costn) | cosine_power (then p = ...)

    [scene]
    directions = [0.37, -2.7716]   # ring: rad; sphere: [[lon, lat], ...]
    intensities = [1.0, 0.2]

    [data]
    simulate = true            # or: file = "readings.txt" (one or more rows of N readings)
    seed = 20260123

Every section is declared by a :class:`Section` of :class:`Field` objects in a
registry; other parts of the package (``image``, ``select``, ``study``,
``posterior`` ...) declare theirs with :func:`register_section` and then call
:func:`load_config` with the sections their command accepts.  Unknown sections
or keys, wrong types, non-finite or huge numbers and malformed TOML all raise
:class:`~olsbayes.errors.ConfigError` naming the key and the accepted keys.
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ConfigError, OlsBayesError

__all__ = [
    "Field",
    "Section",
    "Config",
    "register_section",
    "get_section",
    "registered_sections",
    "load_config",
    "parse_config",
    "read_readings",
    "MAX_ABS",
    "MAX_ELEMENTS",
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
    """

    name: str
    fields: Mapping[str, Field]
    doc: str = ""
    variant_key: str | None = None
    variants: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    common: tuple[str, ...] = ()

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
            raise ConfigError(f"{where} must have magnitudes <= {MAX_ABS:g}; got {_short(item)}")


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


def _validate_section(sec: Section, table: Any, base: Path) -> dict[str, Any]:
    if not isinstance(table, dict):
        raise ConfigError(f"[{sec.name}] must be a table; got {_short(table)}")
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


def _apply_overrides(doc: dict[str, Any], overrides: Mapping[str, Any]) -> None:
    for dotted, value in overrides.items():
        parts = str(dotted).split(".")
        if len(parts) != 2 or not all(parts):
            raise ConfigError(f"override key must look like section.key; got {dotted!r}")
        table = doc.setdefault(parts[0], {})
        if not isinstance(table, dict):
            raise ConfigError(f"override {dotted!r}: [{parts[0]}] is not a table")
        table[parts[1]] = value


def parse_config(
    text: str,
    sections: Iterable[str] | None = None,
    *,
    required: Iterable[str] = (),
    source: str = "<string>",
    base_dir: str | os.PathLike | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> Config:
    """Validate TOML ``text`` against the registered sections.

    Parameters
    ----------
    text : str
        TOML document.
    sections : iterable of str, optional
        Sections this caller accepts (default: every registered section).
    required : iterable of str
        Sections that must be present.
    source : str
        Name used in messages.
    base_dir : path, optional
        Folder for relative paths (default: the current folder).
    overrides : mapping, optional
        ``{"section.key": value}`` set on top of the document before validation
        (the CLI's ``--set``); values are Python values as TOML would give them.
    """
    names = tuple(sections) if sections is not None else registered_sections()
    allowed = {n: get_section(n) for n in names}
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: malformed TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{source}: malformed TOML: nested too deeply") from None
    _apply_overrides(doc, overrides or {})
    base = Path(base_dir) if base_dir is not None else Path(".")
    tables: dict[str, dict[str, Any]] = {}
    for name, table in doc.items():
        if name not in allowed:
            raise ConfigError(
                f"{source}: unknown section or key {name!r}; accepted sections: "
                f"{', '.join(f'[{n}]' for n in names) or '(none)'}"
            )
        try:
            tables[name] = _validate_section(allowed[name], table, base)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None
    for name in required:
        if name not in tables:
            raise ConfigError(f"{source}: section [{name}] is required but missing")
    return Config(tables=tables, source=source, base_dir=base)


def load_config(
    path: str | os.PathLike,
    sections: Iterable[str] | None = None,
    *,
    required: Iterable[str] = (),
    overrides: Mapping[str, Any] | None = None,
) -> Config:
    """Read and validate a TOML configuration file (see :func:`parse_config`).

    Relative paths inside the file are resolved against the file's folder.
    """
    p = Path(path)
    try:
        size = p.stat().st_size
        if not p.is_file():
            raise ConfigError(f"config {str(p)!r} is not a file")
        if size > MAX_CONFIG_BYTES:
            raise ConfigError(f"config {str(p)!r} is {size} bytes; at most {MAX_CONFIG_BYTES}")
        raw = p.read_bytes()
    except OSError as exc:
        raise ConfigError(f"config {str(p)!r} cannot be read: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError(f"config {str(p)!r} is not UTF-8 text") from None
    return parse_config(
        text, sections, required=required, source=str(p), base_dir=p.resolve().parent,
        overrides=overrides,
    )


def read_readings(
    path: str | os.PathLike, n_sensors: int | None = None, name: str = "data file"
) -> np.ndarray:
    """Readings from a text (whitespace- or comma-separated, ``#`` comments) or .npy file.

    Returns shape (N,) for one row, (T, N) for T rows of N readings each.
    ConfigError when the file is missing, unparsable, non-finite, empty or its
    rows do not hold ``n_sensors`` readings.
    """
    p = Path(path)
    try:
        if not p.is_file():
            raise ConfigError(f"{name} {str(p)!r} does not exist or is not a file")
        if p.stat().st_size > MAX_DATA_BYTES:
            raise ConfigError(f"{name} {str(p)!r} is larger than {MAX_DATA_BYTES} bytes")
        if p.suffix.lower() == ".npy":
            arr = np.load(p, allow_pickle=False)
        else:
            text = p.read_text(encoding="utf-8")
            rows = []
            for line in text.splitlines():
                line = line.split("#", 1)[0].replace(",", " ").strip()
                if line:
                    rows.append([float(tok) for tok in line.split()])
            if len({len(r) for r in rows}) > 1:
                raise ConfigError(f"{name} {str(p)!r} has rows of different lengths")
            arr = np.array(rows, dtype=float)
            if arr.ndim == 2 and arr.shape[0] == 1:
                arr = arr[0]
            elif arr.ndim == 2 and arr.shape[1] == 1 and n_sensors not in (None, 1):
                arr = arr[:, 0]  # one reading per line
    except OlsBayesError:
        raise
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{name} {str(p)!r} cannot be read as numbers: {exc}") from None
    arr = np.asarray(arr, dtype=float) if arr.dtype != object else arr
    if arr.dtype.kind not in "fiu" or arr.ndim not in (1, 2) or arr.size == 0:
        raise ConfigError(
            f"{name} {str(p)!r} must hold a non-empty table of numbers; got shape {arr.shape}"
        )
    arr = arr.astype(float)
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} {str(p)!r} holds nan or inf readings")
    if n_sensors is not None and arr.shape[-1] != n_sensors:
        raise ConfigError(
            f"{name} {str(p)!r} rows hold {arr.shape[-1]} readings; the sensor has "
            f"{n_sensors} sub-sensors"
        )
    return arr


# -- the foundation's sections -------------------------------------------------------
_PI = math.pi
register_section(Section(
    name="sensor",
    doc="sub-sensor array, angular sensitivity law and noise",
    variant_key="geometry",
    common=("sigma", "sensitivity", "p"),
    variants={
        "ring": ("n", "offset"),
        "sphere": ("layout", "n", "n_lat", "n_lon", "lat_max", "lon_min", "lon_max"),
        "plate": ("nx", "ny", "pitch"),
        "custom": ("normals", "normals_file", "positions", "positions_file"),
    },
    fields={
        "geometry": Field("str", required=True, choices=("ring", "sphere", "plate", "custom"),
                          doc="ring, sphere, plate or custom"),
        "sigma": Field("float", required=True, positive=True, doc="noise std of one sub-sensor"),
        "sensitivity": Field("str", default="cosine",
                             choices=("cosine", "costn", "cosine_power"),
                             doc="angular law"),
        "p": Field("float", low=1.0, high=64.0, doc="exponent of cosine_power"),
        "n": Field("int", low=3, high=1_000_000, doc="number of sub-sensors"),
        "offset": Field("float", default=0.0, doc="angle of the first ring normal (rad)"),
        "layout": Field("str", default="grid", choices=("grid", "fibonacci"), doc="sphere layout"),
        "n_lat": Field("int", low=1, high=10_000, doc="grid latitudes"),
        "n_lon": Field("int", low=1, high=10_000, doc="grid longitudes"),
        "lat_max": Field("float", default=_PI / 2.05, positive=True, high=_PI / 2,
                         doc="largest grid latitude (rad)"),
        "lon_min": Field("float", default=-_PI, low=-2 * _PI, high=2 * _PI, doc="rad"),
        "lon_max": Field("float", default=_PI, low=-2 * _PI, high=2 * _PI, doc="rad"),
        "nx": Field("int", low=1, high=10_000, doc="plate columns"),
        "ny": Field("int", low=1, high=10_000, doc="plate rows"),
        "pitch": Field("float", default=1.0, positive=True, doc="plate spacing"),
        "normals": Field("array", ndim=(2,), doc="inline normals, shape (N, 2) or (N, 3)"),
        "normals_file": Field("path", doc="text/.npy file of normals, one per row"),
        "positions": Field("array", ndim=(2,), doc="inline sub-sensor positions (N, 3)"),
        "positions_file": Field("path", doc="text/.npy file of positions (N, 3)"),
    },
))

register_section(Section(
    name="scene",
    doc="point sources: directions (or positions) and intensities",
    fields={
        "directions": Field("array", ndim=(1, 2), doc="ring angles (K,) or (lon, lat) (K, 2)"),
        "positions": Field("array", ndim=(2,), doc="near-source positions (K, 3)"),
        "intensities": Field("array", required=True, ndim=(1,), doc="intensities (K,) >= 0"),
        "angle_unit": Field("str", default="rad", choices=("rad", "deg"),
                            doc="unit of directions"),
    },
))

register_section(Section(
    name="data",
    doc="readings: a file, or a simulation of the scene",
    fields={
        "file": Field("path", doc="text/CSV/.npy file, one row of N readings per measurement"),
        "simulate": Field("bool", default=False, doc="simulate readings from [scene]"),
        "seed": Field("int", low=0, high=2**63 - 1, doc="seed of the simulation"),
        "repeats": Field("int", default=1, low=1, high=1_000_000, doc="rows to simulate"),
    },
))
