"""Reading configuration files and data files: TOML parsing, overrides, readings."""

from __future__ import annotations

import os
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, OlsBayesError
from .schema import (
    MAX_CONFIG_BYTES,
    MAX_DATA_BYTES,
    Config,
    get_section,
    registered_sections,
    validate_section,
)

__all__ = ["parse_config", "load_config", "read_readings"]


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
            tables[name] = validate_section(allowed[name], table, base)
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


