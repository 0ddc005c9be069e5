"""Append-only checkpoint of a study: one header, then one frame per finished chunk.

The bytes are described in :mod:`olsbayes.studies._frames`: a JSON header
holding the study's fingerprint (grid, fixed settings, trials per cell, seed,
trial function, package version) and its SHA-256 (the study key), then one
frame per finished chunk, each with a crc32 and a digest keyed with the study key.

A new checkpoint appears complete and locked: its header is written to a
temporary file whose descriptor holds an exclusive ``flock``, and that file is
hard-linked to the path, which fails if the path exists (an exclusive create).
An existing file is opened and locked on the same descriptor before it is read,
and only the lock's holder decides from its contents whether to resume or, for
a file left empty, to write the header.  Of two studies started together on one
path, one runs and the other is refused ("in use by another running study"); the
kernel drops the lock when its holder dies, even by ``kill -9``.

A chunk is appended with a single ``pwrite`` and an ``fsync``, so a killed study
leaves the file ending on a complete frame or a torn one.  On resume a torn end
is cut off, and a damaged frame anywhere else (a flipped byte, a bad length) is
skipped -- every valid frame after it is kept -- and overwritten with padding;
the trials of lost frames simply run again.  A frame whose crc32 holds but whose
digest or contents do not (an edited file, a frame from another study, a trial
index out of range) is refused with :class:`~olsbayes.errors.InputError`.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import tempfile
import warnings
import zlib
from pathlib import Path

import numpy as np

from .._io import _UMASK
from ..errors import InputError
from ._frames import (
    HEAD,
    MAGIC,
    ChunkRecord,
    Scan,
    decode_chunk,
    encode_chunk,
    frame,
    padding,
    scan,
)

__all__ = ["Checkpoint", "ChunkRecord", "fingerprint_key", "recorded_seed", "read_chunks",
           "FORMAT"]

FORMAT = "olsbayes-study-checkpoint/2"
#: Largest header frame read (bytes): a fingerprint is a few kB.
_MAX_HEADER = 64 * 1024 * 1024


def fingerprint_key(fingerprint: dict) -> str:
    """SHA-256 of the canonical JSON of a study fingerprint."""
    text = json.dumps(fingerprint, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def study_size(fingerprint: dict) -> tuple[int, int]:
    """(grid cells, trials per cell) of a study fingerprint."""
    n_cells = 1
    for _, values in fingerprint["grid"]:
        n_cells *= len(values)
    return n_cells, int(fingerprint["n_trials"])


def _open(path: Path, flags: int) -> int:
    """A descriptor on the regular file ``path`` (never blocks on a FIFO)."""
    try:
        fd = os.open(path, flags | os.O_NONBLOCK | os.O_CLOEXEC, 0o666)
    except OSError as exc:
        raise InputError(f"checkpoint {str(path)!r} cannot be opened: "
                         f"{exc.strerror or exc}") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise InputError(f"checkpoint {str(path)!r} is not a regular file")
    return fd


def _lock(fd: int, path: Path) -> None:
    """Take an exclusive advisory lock on ``fd`` or raise (closing ``fd``).

    Where file locks are unavailable (no ``fcntl``, or a file system without
    locks) it warns and goes on unlocked.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not on POSIX
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise InputError(
            f"checkpoint {str(path)!r} is in use by another running study (it holds the "
            "file's lock); wait for that study to finish, or use another checkpoint path"
        ) from None
    except OSError as exc:  # e.g. ENOLCK on some network file systems
        warnings.warn(f"checkpoint {str(path)!r}: cannot lock it ({exc.strerror}); make sure "
                      "no other study uses it at the same time", RuntimeWarning, stacklevel=4)


def _read_all(fd: int, size: int) -> bytearray:
    buf = bytearray(size)
    view, pos = memoryview(buf), 0
    while pos < size:
        n = os.preadv(fd, [view[pos:]], pos)
        if n == 0:
            break
        pos += n
    del view
    return buf[:pos] if pos < size else buf


def _header(raw: bytes | memoryview, path: Path) -> dict:
    """The header's JSON, checked for shape and self-consistency."""
    try:
        header = json.loads(bytes(raw))
    except (UnicodeDecodeError, ValueError, RecursionError):
        header = None
    if not isinstance(header, dict) or not isinstance(header.get("fingerprint"), dict):
        raise InputError(f"checkpoint {str(path)!r} has an unreadable header")
    if header.get("format") != FORMAT:
        raise InputError(f"checkpoint {str(path)!r} has format {header.get('format')!r}; this "
                         f"version reads {FORMAT!r}: finish that study with the olsbayes "
                         "version that made it, or delete the file to start afresh")
    if header.get("key") != fingerprint_key(header["fingerprint"]):
        raise InputError(f"checkpoint {str(path)!r} has a header whose key does not match its "
                         "settings: the file was altered; delete it to start afresh")
    return header


def recorded_seed(path: str | os.PathLike) -> int | None:
    """The seed in the header of the checkpoint at ``path``; None when there is none to read."""
    try:
        fd = _open(Path(path), os.O_RDONLY)
    except InputError:
        return None
    try:
        head = os.pread(fd, HEAD.size, 0)
        if len(head) < HEAD.size:
            return None
        magic, kind, length, crc = HEAD.unpack(head)
        if magic != MAGIC or kind != b"H" or length > _MAX_HEADER:
            return None
        payload = os.pread(fd, length, HEAD.size)
        if zlib.crc32(payload) != crc:
            return None
        return int(_header(payload, Path(path))["fingerprint"]["seed"])
    except (OSError, KeyError, TypeError, ValueError):
        return None
    finally:
        os.close(fd)


def read_chunks(path: str | os.PathLike) -> list[ChunkRecord]:
    """The valid chunks of the checkpoint at ``path``, read without locking or repairing it.

    For inspection: damaged frames are left out; a file whose header or chunks
    are not valid raises :class:`~olsbayes.errors.InputError`.
    """
    p = Path(path)
    fd = _open(p, os.O_RDONLY)
    try:
        found = scan(_read_all(fd, os.fstat(fd).st_size))
    finally:
        os.close(fd)
    if not found.frames or found.frames[0][:2] != (0, b"H"):
        raise InputError(f"checkpoint {str(p)!r} has no valid header")
    header = _header(found.frames[0][2], p)
    n_cells, n_trials = study_size(header["fingerprint"])
    return [decode_chunk(payload, header["key"], n_cells, n_trials)
            for _, kind, payload in found.frames[1:] if kind == b"C"]


class Checkpoint:
    """An open, locked study checkpoint.

    Create or resume with :meth:`open`, release with :meth:`close` (also a context
    manager).

    Attributes
    ----------
    path : Path
        The file.
    records : list of ChunkRecord
        The valid chunks read on resume, in file order.
    damaged : list of (int, int)
        Byte ranges of damaged frames skipped on resume (now padding).
    """

    def __init__(self, path: Path, fd: int, key: str, end: int,
                 records: list[ChunkRecord], damaged: list[tuple[int, int]]):
        self.path, self.records, self.damaged = path, records, damaged
        self._fd, self._key, self._end = fd, key, end

    def close(self) -> None:
        """Release the checkpoint's lock (appending is no longer allowed)."""
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor releases its flock
            self._fd = None

    def __enter__(self) -> Checkpoint:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @classmethod
    def open(cls, path: str | os.PathLike, fingerprint: dict, *,
             max_bytes: int | None = None) -> Checkpoint:
        """Create ``path`` for ``fingerprint``, or resume it if it was made with the same one.

        Parameters
        ----------
        path : path
            The checkpoint file; its folder must exist.
        fingerprint : dict
            The study's settings (see :func:`fingerprint_key`).
        max_bytes : int, optional
            Refuse a file larger than this (it is read into memory on resume).

        Raises
        ------
        InputError
            When ``path`` is held by another running study, holds a checkpoint of
            a study with other settings (the message lists the settings that
            differ), is not a checkpoint, is not a regular file, or holds chunks
            that are not valid chunks of this study.
        """
        path = Path(path)
        key = fingerprint_key(fingerprint)
        header = frame(b"H", json.dumps({"format": FORMAT, "key": key, "fingerprint": fingerprint},
                                        sort_keys=True).encode())
        fd = None if os.path.lexists(path) else _create(path, header)
        if fd is not None:
            return cls(path, fd, key, len(header), [], [])
        fd = _open(path, os.O_RDWR | os.O_CREAT)
        _lock(fd, path)
        try:
            size = os.fstat(fd).st_size
            if max_bytes is not None and size > max_bytes:
                raise InputError(f"checkpoint {str(path)!r} holds {size / 1e9:.3g} GB, more "
                                 f"than the memory limit of {max_bytes / 1e9:.3g} GB")
            raw = _read_all(fd, size)
            found = scan(raw)
            if not found.frames and _torn_header(raw):  # left empty, or torn while created
                end = _write(fd, header, 0)
                os.ftruncate(fd, end)
                return cls(path, fd, key, end, [], [])
            return cls._resume(path, fd, found, key, fingerprint)
        except BaseException:
            os.close(fd)
            raise

    @classmethod
    def _resume(cls, path: Path, fd: int, found: Scan, key: str,
                fingerprint: dict) -> Checkpoint:
        frames = found.frames
        if not frames or frames[0][0] != 0 or frames[0][1] != b"H":
            if any(kind == b"C" for _, kind, _ in frames):
                raise InputError(f"checkpoint {str(path)!r} has a damaged header, so the "
                                 "settings of its trials cannot be checked; delete it to "
                                 "start afresh")
            raise InputError(f"checkpoint {str(path)!r} is not an olsbayes study checkpoint")
        header = _header(frames[0][2], path)
        if header["key"] != key:
            old = header["fingerprint"]
            diff = sorted(k for k in set(old) | set(fingerprint)
                          if old.get(k) != fingerprint.get(k))
            raise InputError(
                f"checkpoint {str(path)!r} was made by a study with other settings "
                f"(differing: {', '.join(diff) or 'fingerprint'}); refusing to resume. "
                "Use another checkpoint path or delete this file to start afresh."
            )
        n_cells, n_trials = study_size(fingerprint)
        records = []
        for pos, kind, payload in frames[1:]:
            if kind != b"C":  # a header anywhere else: a chunk whose kind byte was damaged
                found.damaged.append((pos, pos + HEAD.size + len(payload)))
                continue
            try:
                records.append(decode_chunk(payload, key, n_cells, n_trials))
            except InputError as exc:
                raise InputError(f"checkpoint {str(path)!r}, frame at byte {pos}: {exc}; "
                                 "delete the file to start afresh") from None
        found.damaged.sort()
        _heal(fd, path, found)
        return cls(path, fd, key, found.end, records, found.damaged)

    def append(self, cell: int, trials: np.ndarray, values: dict) -> None:
        """Append one finished chunk durably (single write, then fsync)."""
        if self._fd is None:
            raise InputError(f"checkpoint {str(self.path)!r} is closed")
        data = frame(b"C", encode_chunk(self._key, cell, trials, values))
        self._end = _write(self._fd, data, self._end)
        self.records.append(ChunkRecord(int(cell), np.asarray(trials, np.int64), values))


def _create(path: Path, header: bytes) -> int | None:
    """Publish a new checkpoint at ``path`` already holding its header and locked.

    The header is written to a temporary file whose descriptor is locked, then
    hard-linked to ``path``, which fails if ``path`` exists: the file never
    appears empty or unlocked.  Returns the locked descriptor, or None when
    ``path`` appeared meanwhile or the file system has no hard links (then the
    caller opens ``path`` and decides under its lock).
    """
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".new", dir=path.parent)
    except OSError as exc:
        raise InputError(f"checkpoint {str(path)!r} cannot be created: "
                         f"{exc.strerror or exc}") from None
    try:
        _lock(fd, path)
        _write(fd, header, 0)
        os.fchmod(fd, 0o666 & ~_UMASK)
        os.link(tmp, path)
    except OSError:
        os.close(fd)
        return None
    except BaseException:
        os.close(fd)
        raise
    finally:
        os.unlink(tmp)
    return fd


def _torn_header(raw: bytearray) -> bool:
    """True for an empty file, or a prefix of a header frame (a creation cut short)."""
    head = bytes(raw[:HEAD.size])
    if len(head) < HEAD.size:
        return MAGIC.startswith(head[:4]) and head[4:5] in (b"", b"H")
    magic, kind, length, _ = HEAD.unpack(head)
    return magic == MAGIC and kind == b"H" and HEAD.size + length > len(raw)


def _write(fd: int, data: bytes, at: int) -> int:
    """Write ``data`` at byte ``at`` and fsync; return the end offset."""
    view = memoryview(data)
    pos = at
    while view:
        n = os.pwrite(fd, view, pos)
        view, pos = view[n:], pos + n
    os.fsync(fd)
    return pos


def _heal(fd: int, path: Path, found) -> None:
    """Cut off a torn end; cover damaged frames with padding (their trials run again)."""
    if found.end < found.size:
        warnings.warn(f"checkpoint {str(path)!r}: dropping a torn last chunk "
                      f"({found.size - found.end} bytes); its trials will run again",
                      RuntimeWarning, stacklevel=5)
        os.ftruncate(fd, found.end)
        os.fsync(fd)
    for start, end in found.damaged:
        if end - start >= HEAD.size:
            _write(fd, padding(end - start), start)
