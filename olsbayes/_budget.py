"""The memory budget: sizes that drive memory are checked before anything is allocated.

Every public entry point whose memory grows with a user's number -- sub-sensors,
data rows, grid points, walkers times steps, the rows a file claims -- estimates
the bytes of its largest arrays from the sizes alone and calls
:func:`check_memory` first, so that a typo (``n_walkers = 10**8``) is one clear
:class:`~olsbayes.errors.InputError` naming the estimate and the limit rather
than minutes of swapping or a ``MemoryError`` deep inside numpy.

The limit is :data:`DEFAULT_LIMIT` unless the environment variable
``OLSBAYES_MEMORY_LIMIT`` says otherwise (bytes, or a number with a unit: ``512MB``,
``16GB``, ``2GiB``); it is read at each check, so a running program can change it.
"""

from __future__ import annotations

import os
import re

from .errors import InputError

__all__ = ["DEFAULT_LIMIT", "ENV_VAR", "SENSOR_BYTES", "memory_limit", "check_memory",
           "check_sensors", "format_bytes"]

#: Bytes one call may plan to allocate for its largest arrays, by default (4 GiB).
DEFAULT_LIMIT = 4 * 2**30
#: Environment variable that overrides :data:`DEFAULT_LIMIT`.
ENV_VAR = "OLSBAYES_MEMORY_LIMIT"

#: Bytes an array and a model keep per sub-sensor (normals, positions, angles, copies).
SENSOR_BYTES = 96

_UNITS = {"": 1, "b": 1, "kb": 10**3, "mb": 10**6, "gb": 10**9, "tb": 10**12,
          "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40}
_PATTERN = re.compile(r"^\s*([0-9]+(?:\.[0-9]*)?(?:e[0-9]+)?)\s*([a-z]*)\s*$", re.IGNORECASE)


def memory_limit() -> int:
    """The memory budget in bytes: ``OLSBAYES_MEMORY_LIMIT`` if set, else :data:`DEFAULT_LIMIT`."""
    raw = os.environ.get(ENV_VAR)
    if raw is None or not raw.strip():
        return DEFAULT_LIMIT
    m = _PATTERN.match(raw)
    if m is None or m.group(2).lower() not in _UNITS:
        raise InputError(f"{ENV_VAR} must be a number of bytes, optionally with a unit "
                         f"(kB, MB, GB, TB, KiB, MiB, GiB, TiB), e.g. 16GB; got {raw[:40]!r}")
    value = float(m.group(1)) * _UNITS[m.group(2).lower()]
    if not value >= 1:
        raise InputError(f"{ENV_VAR} must be at least 1 byte; got {raw[:40]!r}")
    return int(min(value, 2**62))


def format_bytes(n: float) -> str:
    """``n`` bytes as a short human-readable size (``3.9 GB``)."""
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{int(n)} B"


def check_memory(what: str, nbytes: float) -> None:
    """Raise :class:`~olsbayes.errors.InputError` when ``nbytes`` exceeds the budget.

    Parameters
    ----------
    what : str
        The sizes that make the estimate, as the user gave them, e.g.
        ``"n_walkers=100000000 x 20000 steps x 5 parameters"``.
    nbytes : float
        Estimated bytes of the arrays those sizes allocate (may exceed any int).
    """
    limit = memory_limit()
    if nbytes > limit:
        raise InputError(
            f"{what} needs ~{format_bytes(nbytes)} of memory; the limit is "
            f"{format_bytes(limit)} (raise it with the environment variable {ENV_VAR}, "
            "e.g. OLSBAYES_MEMORY_LIMIT=16GB)"
        )


def check_sensors(what: str, n: int) -> None:
    """:func:`check_memory` of an array of ``n`` sub-sensors (``what`` names the sizes)."""
    check_memory(what, float(n) * SENSOR_BYTES)
