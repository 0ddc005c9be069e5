"""Where a result came from: package version, seed, data hash, command line.

Every saved result and report carries these facts, so a number can be traced to
the run that made it and the run repeated:

* ``olsbayes_version`` -- the package version;
* ``seed`` -- the integer seed of the run's random streams (for a
  ``SeedSequence``, its entropy, with its ``spawn_key`` recorded too), or None
  when a ``Generator`` was passed (its state is not a seed);
* ``data_sha256`` -- SHA-256 of the readings as little-endian float64 bytes
  (the same readings give the same hash whatever file they came from);
* ``command`` -- the command line of the process (``sys.argv``, shell-quoted);
* ``created`` -- UTC time stamp (ISO 8601).
"""

from __future__ import annotations

import datetime
import hashlib
import os
import secrets
import shlex
import sys
from pathlib import Path

import numpy as np

__all__ = ["provenance", "data_sha256", "file_sha256", "draw_seed", "seed_of"]


def draw_seed() -> int:
    """A fresh seed in [0, 2**63) from the operating system's entropy.

    Used when a run is given no seed, so that the seed actually used can be
    recorded (and printed) and the run repeated.
    """
    return secrets.randbits(63)


def seed_of(rng: object) -> int | None:
    """The integer seed of an ``rng`` argument (a SeedSequence's entropy), else None."""
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        return int(rng)
    if isinstance(rng, np.random.SeedSequence) and isinstance(rng.entropy, int):
        return int(rng.entropy)
    return None


def data_sha256(data: object) -> str:
    """SHA-256 (hex) of readings as contiguous little-endian float64 bytes."""
    arr = np.ascontiguousarray(np.asarray(data, dtype="<f8"))
    return hashlib.sha256(arr.tobytes()).hexdigest()


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 (hex) of a file's bytes."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def provenance(*, seed: object = None, data: object = None) -> dict[str, object]:
    """The provenance record of a run (see the module notes); JSON-ready.

    Parameters
    ----------
    seed : int, SeedSequence or Generator, optional
        The run's seed (None or a Generator: not known).
    data : array_like, optional
        The readings analysed; their hash is recorded.
    """
    from ._version import __version__

    key = getattr(seed, "spawn_key", ())
    return {
        "olsbayes_version": __version__,
        "seed": seed_of(seed),
        "spawn_key": " ".join(map(str, key)) if key else None,
        "data_sha256": None if data is None else data_sha256(data),
        "command": shlex.join(sys.argv),
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }
