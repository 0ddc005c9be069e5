"""Append-only checkpoint of a study: one header, then one frame per finished chunk.

File layout: frames of ``MAGIC | kind (1 byte) | length (uint64 LE) | crc32
(uint32 LE) | payload``.  The first frame (kind ``H``) is a JSON header holding
the study's fingerprint (grid, fixed settings, trials per cell, seed, trial
function, package version) and its SHA-256; each later frame (kind ``C``) is an
``.npz`` archive (loaded with ``allow_pickle=False``) holding one chunk's cell
index, trial indices and result arrays.

A chunk frame is written with a single ``write`` on a file opened in append
mode and then ``fsync``-ed, so after ``kill -9`` the file ends either on a
complete frame or on a torn one; a torn or checksum-failing *last* frame is
dropped (those trials are simply run again), which is why no trial is ever lost
or counted twice.  The header is created through an atomic rename.  While a study
runs it holds an exclusive advisory lock (``flock``) on the file, so a second study
started on the same checkpoint is refused instead of running the same trials
again; the kernel drops the lock when the process dies, even by ``kill -9``.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import struct
import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._io import atomic_path
from ..errors import InputError

__all__ = ["Checkpoint", "ChunkRecord", "fingerprint_key"]

MAGIC = b"OLSB"
_HEAD = struct.Struct("<4scQI")  # magic, kind, payload length, crc32
FORMAT = "olsbayes-study-checkpoint/1"


def fingerprint_key(fingerprint: dict) -> str:
    """SHA-256 of the canonical JSON of a study fingerprint."""
    text = json.dumps(fingerprint, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True)
class ChunkRecord:
    """One finished chunk: grid cell, trial indices (T,) and results {name: (T, ...)}."""

    cell: int
    trials: np.ndarray
    values: dict = field(repr=False)


def _frame(kind: bytes, payload: bytes) -> bytes:
    return _HEAD.pack(MAGIC, kind, len(payload), zlib.crc32(payload)) + payload


def _encode_chunk(cell: int, trials: np.ndarray, values: dict) -> bytes:
    buf = io.BytesIO()
    arrays = {f"v:{k}": np.asarray(v) for k, v in values.items()}
    np.savez(buf, cell=np.int64(cell), trials=np.asarray(trials, np.int64), **arrays)
    return buf.getvalue()


def _decode_chunk(payload: bytes) -> ChunkRecord:
    with np.load(io.BytesIO(payload), allow_pickle=False) as z:
        values = {k[2:]: z[k] for k in z.files if k.startswith("v:")}
        return ChunkRecord(int(z["cell"]), z["trials"], values)


def _read_frames(path: Path) -> tuple[list[tuple[bytes, bytes]], int, int]:
    """Valid frames, byte offset where they end, total file size."""
    data = path.read_bytes()
    frames, pos = [], 0
    while pos + _HEAD.size <= len(data):
        magic, kind, length, crc = _HEAD.unpack_from(data, pos)
        end = pos + _HEAD.size + length
        if magic != MAGIC:
            break
        if end > len(data):  # torn tail
            break
        payload = data[pos + _HEAD.size:end]
        if zlib.crc32(payload) != crc:
            if end < len(data):
                raise InputError(
                    f"checkpoint {str(path)!r} is corrupt: frame at byte {pos} fails its "
                    "checksum and is followed by more data"
                )
            break
        frames.append((kind, payload))
        pos = end
    return frames, pos, len(data)


def _lock(path: Path) -> int | None:
    """Exclusive advisory lock on ``path``: the locked descriptor, or None.

    None where file locks are unavailable (no ``fcntl``, or a file system without
    locks: warns).
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not on POSIX
        return None
    fd = os.open(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise InputError(
            f"checkpoint {str(path)!r} is in use by another running study (it holds the "
            "file's lock); wait for that study to finish, or use another checkpoint path"
        ) from None
    except OSError as exc:  # e.g. ENOLCK on some network file systems
        os.close(fd)
        warnings.warn(f"checkpoint {str(path)!r}: cannot lock it ({exc.strerror}); make sure "
                      "no other study uses it at the same time", RuntimeWarning, stacklevel=4)
        return None
    return fd


class Checkpoint:
    """An open study checkpoint.

    Create or resume with :meth:`open`, release with :meth:`close` (also a context
    manager).
    """

    def __init__(self, path: Path, records: list[ChunkRecord], lock_fd: int | None = None):
        self.path = path
        self.records = records
        self._lock_fd = lock_fd

    def close(self) -> None:
        """Release the checkpoint's lock (appending is no longer allowed)."""
        if self._lock_fd is not None:
            os.close(self._lock_fd)  # closing the descriptor releases its flock
            self._lock_fd = None

    def __enter__(self) -> Checkpoint:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @classmethod
    def open(cls, path: str | os.PathLike, fingerprint: dict) -> Checkpoint:
        """Create ``path`` for ``fingerprint``, or resume it if it was made with the same one.

        Raises
        ------
        InputError
            When ``path`` holds a checkpoint of a study with other settings (the
            message lists the settings that differ), or is not a checkpoint.
        """
        path = Path(path)
        key = fingerprint_key(fingerprint)
        if not path.exists():
            header = {"format": FORMAT, "key": key, "fingerprint": fingerprint}
            with atomic_path(path) as tmp:
                tmp.write_bytes(_frame(b"H", json.dumps(header, sort_keys=True).encode()))
            return cls(path, [], _lock(path))
        if path.is_dir():
            raise InputError(f"checkpoint {str(path)!r} is a folder, not a file")
        fd = _lock(path)
        try:
            return cls._resume(path, key, fingerprint, fd)
        except BaseException:
            if fd is not None:
                os.close(fd)
            raise

    @classmethod
    def _resume(cls, path: Path, key: str, fingerprint: dict, fd: int | None) -> Checkpoint:
        frames, end, size = _read_frames(path)
        if not frames or frames[0][0] != b"H":
            raise InputError(f"checkpoint {str(path)!r} is not an olsbayes study checkpoint")
        header = json.loads(frames[0][1])
        if header.get("format") != FORMAT:
            raise InputError(
                f"checkpoint {str(path)!r} has format {header.get('format')!r}; "
                f"this version reads {FORMAT!r}"
            )
        if header.get("key") != key:
            old = header.get("fingerprint", {})
            keys = set(old) | set(fingerprint)
            diff = sorted(k for k in keys if old.get(k) != fingerprint.get(k))
            raise InputError(
                f"checkpoint {str(path)!r} was made by a study with other settings "
                f"(differing: {', '.join(diff) or 'fingerprint'}); refusing to resume. "
                "Use another checkpoint path or delete this file to start afresh."
            )
        if end < size:
            warnings.warn(
                f"checkpoint {str(path)!r}: dropping a torn last chunk ({size - end} bytes); "
                "its trials will run again",
                RuntimeWarning,
                stacklevel=4,
            )
            os.truncate(path, end)
        records = [_decode_chunk(p) for kind, p in frames[1:] if kind == b"C"]
        return cls(path, records, fd)

    def append(self, cell: int, trials: np.ndarray, values: dict) -> None:
        """Append one finished chunk durably (single write, then fsync)."""
        frame = _frame(b"C", _encode_chunk(cell, trials, values))
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)
        try:
            view = memoryview(frame)
            while view:
                n = os.write(fd, view)
                view = view[n:]
            os.fsync(fd)
        finally:
            os.close(fd)
        self.records.append(ChunkRecord(int(cell), np.asarray(trials, np.int64), values))
