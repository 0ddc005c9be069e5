"""Reading configuration files: TOML parsing, ``--set`` overrides, validation."""

from __future__ import annotations

import os
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from .._validation import file_path
from ..errors import ConfigError
from .schema import (
    MAX_CONFIG_BYTES,
    Config,
    get_section,
    registered_sections,
    validate_section,
)

__all__ = ["parse_config", "load_config"]


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
    p = file_path("path", path)
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
