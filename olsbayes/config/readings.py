"""Reading numeric files: readings (``[data] file``, ``--data``), normals and positions.

Text files hold whitespace- or comma-separated numbers, one row per line, with
``#`` comments; ``.npy`` files hold one numeric array (no pickles, no archives).
Sizes are checked before anything is allocated: the file against
:data:`~olsbayes.config.schema.MAX_DATA_BYTES`, a ``.npy`` header's shape against
the bytes that follow it, the float array against the memory budget
(:mod:`olsbayes._budget`).  Error messages name the file, the line and field or
the dtype and shape -- never the file's contents, which may be anything the path
points at.
"""

from __future__ import annotations

import io
import math
import os
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .._budget import check_memory
from .._validation import DTYPE_KINDS, file_path
from ..errors import ConfigError
from .schema import MAX_DATA_BYTES

__all__ = ["read_readings", "MAX_LINE_CHARS"]

#: Longest line of a text file (characters): a row of a million readings fits.
MAX_LINE_CHARS = 1 << 25


def _lines(f: io.TextIOBase, where: str) -> Iterator[str]:
    """The lines of ``f`` with commas as blanks; at most MAX_DATA_BYTES characters in all."""
    total = 0
    while True:
        line = f.readline(MAX_LINE_CHARS + 1)
        if not line:
            return
        total += len(line)
        if len(line) > MAX_LINE_CHARS:
            raise ConfigError(f"{where} has a line longer than {MAX_LINE_CHARS} characters")
        if total > MAX_DATA_BYTES:
            raise ConfigError(f"{where} is larger than {MAX_DATA_BYTES} bytes")
        yield line.replace(",", " ")


def _locate(p: Path, where: str) -> ConfigError:
    """The first line and field that is not a number, or the first row of another length.

    The slow path of a failed parse: positions only, never the text found there.
    """
    width = None
    with open(p, encoding="utf-8") as f:
        for lineno, line in enumerate(_lines(f, where), start=1):
            fields = line.split("#", 1)[0].split()
            if not fields:
                continue
            for col, tok in enumerate(fields, start=1):
                try:
                    float(tok)
                    ok = "_" not in tok  # Python's float takes 1_0; numpy's parser does not
                except ValueError:
                    ok = False
                if not ok:
                    return ConfigError(f"{where}: line {lineno}, field {col} is not a number")
            if width is None:
                width = (lineno, len(fields))
            elif len(fields) != width[1]:
                return ConfigError(
                    f"{where} has rows of different lengths: line {lineno} holds "
                    f"{len(fields)} numbers, line {width[0]} holds {width[1]}")
    return ConfigError(f"{where} cannot be read as a table of numbers")


def _read_text(p: Path, where: str, size: int) -> np.ndarray:
    """A 2-D float table (rows, columns) from a text file."""
    check_memory(f"{where} ({size} bytes of text, up to {(size + 1) // 2} numbers)",
                  4.0 * (size + 1))
    try:
        with open(p, encoding="utf-8") as f, warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "input contained no data"
            return np.loadtxt(_lines(f, where), dtype=float, comments="#", ndmin=2)
    except UnicodeDecodeError:
        raise ConfigError(f"{where} is not UTF-8 text") from None
    except ValueError:
        raise _locate(p, where) from None


def _read_npy(p: Path, where: str, size: int) -> np.ndarray:
    """The array of a ``.npy`` file, its header checked before any allocation."""
    fmt = np.lib.format
    with open(p, "rb") as f:
        magic = f.read(6)
        if magic[:4] == b"PK\x03\x04":
            raise ConfigError(f"{where} is a .npz archive (zip), not a .npy array; save one "
                              "array with numpy.save")
        f.seek(0)
        try:
            version = fmt.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = fmt.read_array_header_1_0(f)
            elif version == (2, 0):
                shape, fortran, dtype = fmt.read_array_header_2_0(f)
            else:
                raise ConfigError(f"{where} is a .npy file of version {version}; versions "
                                  "1.0 and 2.0 (numpy.save of a numeric array) are read")
        except (ValueError, SyntaxError, TypeError, OverflowError):
            raise ConfigError(f"{where} is not a valid .npy file (bad magic string or "
                              "malformed header)") from None
        if dtype.fields is not None or dtype.subdtype is not None or dtype.kind not in "fiu":
            kind = "structured" if dtype.fields is not None else DTYPE_KINDS.get(
                dtype.kind, dtype.kind)
            raise ConfigError(f"{where} must hold real numbers (int or float); it holds "
                              f"{kind} values (dtype {dtype.str})")
        count = math.prod(shape)
        need, left = count * dtype.itemsize, size - f.tell()
        if len(shape) not in (1, 2) or count == 0:
            raise ConfigError(f"{where} must hold a non-empty 1-D or 2-D table of numbers; "
                              f"its header says shape {shape}")
        if need != left:
            raise ConfigError(f"{where}: its header says shape {shape} of {dtype.str} "
                              f"({need} bytes) but {left} bytes follow the header")
        check_memory(f"{where} of shape {shape} as float64", 8.0 * count)
        arr = np.fromfile(f, dtype=dtype, count=count)
    if arr.size != count:  # the file shrank while being read
        raise ConfigError(f"{where} ended before its {count} numbers")
    return arr.reshape(shape, order="F" if fortran else "C")


def read_readings(
    path: str | os.PathLike, n_sensors: int | None = None, name: str = "data file"
) -> np.ndarray:
    """Readings from a text (whitespace- or comma-separated, ``#`` comments) or .npy file.

    Returns shape (N,) for one row, (T, N) for T rows of N readings each.
    ConfigError when the file is missing, not a regular file, too large,
    unparsable, not real numbers, non-finite, empty or its rows do not hold
    ``n_sensors`` readings; the message gives positions, dtypes and shapes, never
    the file's contents.
    """
    p = file_path(name, path)
    where = f"{name} {str(p)!r}"
    try:
        if not p.is_file():
            raise ConfigError(f"{where} does not exist or is not a regular file")
        size = p.stat().st_size
        if size > MAX_DATA_BYTES:
            raise ConfigError(f"{where} is {size} bytes; at most {MAX_DATA_BYTES} accepted")
        if p.suffix.lower() == ".npz":
            raise ConfigError(f"{where} is a .npz archive; readings are read from one "
                              "array saved with numpy.save (.npy) or from text")
        if p.suffix.lower() == ".npy":
            arr = _read_npy(p, where, size)
        else:
            arr = _read_text(p, where, size)
            if arr.shape[0] == 1:
                arr = arr[0]
            elif arr.ndim == 2 and arr.shape[1] == 1 and n_sensors not in (None, 1):
                arr = arr[:, 0]  # one reading per line
    except OSError as exc:
        raise ConfigError(f"{where} cannot be read: {exc.strerror or type(exc).__name__}"
                          ) from None
    if arr.size == 0:
        raise ConfigError(f"{where} must hold a non-empty table of numbers; got shape "
                          f"{arr.shape}")
    arr = arr.astype(float, copy=False)
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(np.atleast_2d(arr)))[0]
        raise ConfigError(f"{where} holds nan or inf readings (first at row {bad[0] + 1}, "
                          f"column {bad[1] + 1})")
    if n_sensors is not None and arr.shape[-1] != n_sensors:
        raise ConfigError(
            f"{where} rows hold {arr.shape[-1]} readings; the sensor has {n_sensors} "
            "sub-sensors"
        )
    return arr
