"""Shared pieces of the subcommands: parser class, config loading, output.

A subcommand module ``olsbayes/cli/<name>.py`` exposes ``register(subparsers)``
and ``run(args) -> int``.  Typical ``register``::

    def register(subparsers):
        p = add_command(subparsers, "crlb", help="...", description=__doc__)
        add_config_args(p)          # CONFIG positional + --set section.key=value
        add_json_arg(p)             # --json
        p.set_defaults(run=run)

and ``run`` loads the configuration with :func:`load_cli_config`, prints with
:func:`emit` and returns 0.  Raise :class:`~olsbayes.errors.OlsBayesError`
(InputError / ConfigError) for anything the user got wrong: ``main`` turns it
into one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from .._io import atomic_path, ensure_dir, write_target, write_text_atomic
from ..config import Config, load_config, parse_config
from ..errors import InputError

__all__ = [
    "OneLineParser",
    "add_command",
    "add_config_args",
    "add_json_arg",
    "add_seed_arg",
    "add_quiet_arg",
    "load_cli_config",
    "emit",
    "jsonable",
    "format_table",
    "DEFAULT_CONFIG",
    "write_output",
    "readings_text",
    "write_readings",
    "output_file",
    "output_dir",
]

#: The default scene (Fig. 3 of the paper): ring N = 30, sigma = 0.01, two
#: sources pi apart with intensities 1.0 and 0.2.  Used by ``demo`` and by any
#: subcommand run without a CONFIG file.
DEFAULT_CONFIG = """\
# olsbayes configuration: the default scene (Fig. 3 of the paper)
[sensor]
geometry = "ring"        # ring | sphere | plate | custom
n = 30                   # sub-sensors, normals at offset + 2*pi*k/n
offset = 0.0             # rad
sigma = 0.01             # noise std of one sub-sensor (reading units)
sensitivity = "cosine"   # cosine (costn) | cosine_power (with p = ...)

[scene]
directions = [0.37, -2.7715926535897933]   # rad, pi apart
intensities = [1.0, 0.2]

[data]
simulate = true
seed = 20260123
"""


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line on stderr, exit status 2.

    The line starts ``olsbayes: error:`` for every subcommand (the subcommand is
    named after it), like the errors of a run.
    """

    def error(self, message: str) -> NoReturn:
        top, _, sub = self.prog.partition(" ")
        where = f"{sub}: " if sub else ""
        text = " ".join(str(message).split())
        self.exit(2, f"{top}: error: {where}{text} (see `{self.prog} --help`)\n")


def add_command(subparsers: Any, name: str, **kwargs: Any) -> argparse.ArgumentParser:
    """Add a subcommand parser with the package's formatting defaults."""
    kwargs.setdefault("formatter_class", argparse.RawDescriptionHelpFormatter)
    return subparsers.add_parser(name, **kwargs)


def add_config_args(parser: argparse.ArgumentParser, required: bool = False) -> None:
    """CONFIG positional (optional unless ``required``) and repeatable ``--set``."""
    parser.add_argument(
        "config", nargs=None if required else "?", metavar="CONFIG",
        help="TOML file describing [sensor], [scene], [data] ..." + (
            "" if required
            else " (default: the built-in Fig. 3 scene; see `olsbayes demo --print-config`)"
        ),
    )
    parser.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
        help="override one config value, TOML syntax for VALUE (e.g. --set sensor.sigma=0.02)",
    )


def add_json_arg(parser: argparse.ArgumentParser) -> None:
    """``--json``: machine-readable output on stdout."""
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object on stdout instead of tables")


def add_quiet_arg(parser: argparse.ArgumentParser) -> None:
    """``--quiet``: no progress bars or status lines on stderr (warnings still print)."""
    parser.add_argument("--quiet", action="store_true",
                        help="no progress bars or status lines on stderr while long steps "
                             "run (warnings and errors are still printed)")


def add_seed_arg(parser: argparse.ArgumentParser, help: str = "random seed (>= 0)") -> None:
    """``--seed`` (a non-negative integer)."""
    parser.add_argument("--seed", type=_seed, default=None, help=help)


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer; got {text!r}") from None
    if value < 0 or value >= 2**63:
        raise argparse.ArgumentTypeError(f"must be in [0, 2**63); got {value}")
    return value


def _parse_override(item: str) -> tuple[str, Any]:
    key, sep, raw = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise InputError(f"--set must look like section.key=value; got {item!r}")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()  # an unquoted string, e.g. --set sensor.geometry=sphere
    except RecursionError:
        raise InputError(f"--set {key}: value is nested too deeply") from None
    return key, value


def load_cli_config(
    args: argparse.Namespace,
    sections: Iterable[str] = ("sensor", "scene", "data"),
    required: Iterable[str] = ("sensor",),
) -> Config:
    """The command's configuration: CONFIG (or the default scene) plus ``--set``."""
    overrides = dict(_parse_override(s) for s in getattr(args, "overrides", []) or [])
    path = getattr(args, "config", None)
    if path is None:
        return parse_config(DEFAULT_CONFIG, sections, required=required,
                            source="<default config>", overrides=overrides)
    return load_config(path, sections, required=required, overrides=overrides)


def jsonable(obj: Any) -> Any:
    """Convert numpy values, paths and dataclass-like mappings for :func:`json.dumps`.

    Non-finite floats (an infinite CRLB) become ``null``: strict JSON has no inf.
    """
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind == "f":  # vectorised: non-finite entries to None
            out = obj.astype(object)
            out[~np.isfinite(obj)] = None
            return out.tolist()
        if obj.dtype.kind in "biu":
            return obj.tolist()
        return jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer, int)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        x = float(obj)
        return x if math.isfinite(x) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def emit(args: argparse.Namespace, payload: Mapping[str, Any], text: str) -> None:
    """Print ``payload`` as one JSON object (``--json``) or ``text`` otherwise.

    The JSON object also holds ``"warnings"``: the package warnings the command
    raised so far (``category`` and ``message``; also printed on stderr).
    """
    if getattr(args, "json", False):
        payload = {**payload, "warnings": list(getattr(args, "warnings_seen", []))}
        sys.stdout.write(json.dumps(jsonable(payload), allow_nan=False))  # C encoder
        sys.stdout.write("\n")
    else:
        sys.stdout.write(text.rstrip("\n") + "\n")


def _cell(v: Any, digits: int) -> str:
    if isinstance(v, (float, np.floating)):
        x = float(v)
        return "inf" if x == math.inf else f"{x:.{digits}g}" if math.isfinite(x) else str(x)
    return str(v)


def format_table(header: list[str], rows: list[list[Any]], digits: int = 5) -> str:
    """A plain aligned text table (floats to ``digits`` significant digits)."""
    cells = [header] + [[_cell(v, digits) for v in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    lines = ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def write_output(path: str | Path, text: str | bytes, name: str = "--out") -> Path:
    """Write ``text`` (or bytes) atomically; InputError (not a traceback) when it cannot be."""
    p = Path(path)
    write_target(p, name)  # a folder, FIFO or device is refused before anything is written
    try:
        if isinstance(text, str):
            return write_text_atomic(p, text)
        with atomic_path(p) as tmp:
            tmp.write_bytes(text)
        return p
    except OSError as exc:
        raise InputError(f"{name} {str(p)!r} cannot be written: {exc.strerror or exc}") from None


def readings_text(readings: np.ndarray, header: str = "") -> str:
    """Readings as text: one row per measurement, full float precision."""
    buf = io.StringIO()
    np.savetxt(buf, np.atleast_2d(readings), fmt="%.17g", header=header)
    return buf.getvalue()


def write_readings(path: str | Path, readings: np.ndarray, header: str,
                   name: str = "--out") -> Path:
    """Readings (T, N) to ``path``: a ``.npy`` array for a ``.npy`` name, else text.

    What the readers of ``--data`` take back (they tell the two by the suffix): one
    row is read back as one measurement (N,) from either.  The text carries
    ``header`` as a ``#`` comment, the array only the numbers.
    Atomic (:func:`write_output`).
    """
    if Path(path).suffix.lower() != ".npy":
        return write_output(path, readings_text(readings, header), name)
    rows = np.atleast_2d(np.asarray(readings, dtype=float))
    buf = io.BytesIO()  # np.save would add ".npy" to the temporary file's name
    np.save(buf, rows[0] if rows.shape[0] == 1 else rows, allow_pickle=False)
    return write_output(path, buf.getvalue(), name)


def output_file(path: str | Path, name: str = "--out") -> Path:
    """Check, before any work, that ``path`` can take a result file.

    A regular file, a symbolic link to one, or a new name in a folder that exists
    or can be created; InputError for a folder, FIFO, device or socket.
    """
    real, _ = write_target(path, name)
    ensure_dir(real.parent if str(real.parent) else Path("."), f"folder of {name}")
    return Path(path)


def output_dir(path: str | Path, name: str = "--out") -> Path:
    """Create (if needed) and check a writable output folder."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"{name} {str(p)!r} exists and is not a folder")
    return ensure_dir(p, name)
