"""The bytes of a study checkpoint: frames, chunk payloads, and a scan that survives damage.

A checkpoint is a sequence of frames ``MAGIC | kind (1 byte) | length (uint64 LE)
| crc32 (uint32 LE) | payload``.  Kinds: ``H`` the JSON header (first frame
only), ``C`` one finished chunk, ``P`` padding that covers a damaged region
(skipped when read).

A chunk payload is ``meta length (uint32 LE) | meta (JSON) | trial indices (int64,
T) | one raw C-order array per output | digest`` where the meta lists the cell,
T and each output's name, dtype and trailing shape, and the digest is a 16-byte
BLAKE2b of everything before it keyed with the study key.  Nothing is
compressed or unpickled: the meta fixes the byte size of every array, which must
add up to the payload's length exactly, so a frame can never make the reader
allocate more than the file holds.  The crc32 finds accidental damage; the keyed
digest ties a chunk to its study, so a frame copied from another checkpoint, or
edited and given a fresh crc32, is refused instead of read.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import math
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError

__all__ = ["MAGIC", "HEAD", "ChunkRecord", "frame", "padding", "encode_chunk", "decode_chunk",
           "scan"]

MAGIC = b"OLSB"
HEAD = struct.Struct("<4scQI")  # magic, kind, payload length, crc32
_KINDS = (b"H", b"C", b"P")
_META = struct.Struct("<I")
_DIGEST = 16
#: Output arrays may have at most this many trailing dimensions.
_MAX_TAIL_DIMS = 32


@dataclass(frozen=True)
class ChunkRecord:
    """One finished chunk: grid cell, trial indices (T,) and results {name: (T, ...)}."""

    cell: int
    trials: np.ndarray
    values: dict = field(repr=False)


def frame(kind: bytes, payload: bytes) -> bytes:
    """One frame of ``kind`` around ``payload``."""
    return HEAD.pack(MAGIC, kind, len(payload), zlib.crc32(payload)) + payload


def padding(size: int) -> bytes:
    """A padding frame of exactly ``size`` bytes (``size >= HEAD.size``)."""
    return frame(b"P", bytes(size - HEAD.size))


def _digest(key: str, data: bytes | memoryview) -> bytes:
    return hashlib.blake2b(data, key=bytes.fromhex(key), digest_size=_DIGEST).digest()


def encode_chunk(key: str, cell: int, trials: np.ndarray, values: dict) -> bytes:
    """Payload of one chunk frame of the study ``key`` (see the module docstring)."""
    trials = np.ascontiguousarray(trials, dtype="<i8")
    arrays = {str(k): np.ascontiguousarray(v) for k, v in values.items()}
    meta = {"cell": int(cell), "n": len(trials),
            "values": [[k, v.dtype.str, list(v.shape[1:])] for k, v in arrays.items()]}
    text = json.dumps(meta, separators=(",", ":")).encode()
    body = b"".join([_META.pack(len(text)), text, trials.tobytes(),
                     *(v.tobytes() for v in arrays.values())])
    return body + _digest(key, body)


class _Bad(Exception):
    """A chunk payload that passed its crc32 but is not a valid chunk of this study."""


def _meta(body: memoryview) -> tuple[dict, int]:
    if len(body) < _META.size:
        raise _Bad("it is too short")
    (n_meta,) = _META.unpack_from(body)
    if n_meta > len(body) - _META.size:
        raise _Bad("its meta data run past its end")
    try:
        meta = json.loads(bytes(body[_META.size:_META.size + n_meta]))
    except (UnicodeDecodeError, ValueError, RecursionError):
        raise _Bad("its meta data are not valid JSON") from None
    if not isinstance(meta, dict) or set(meta) != {"cell", "n", "values"}:
        raise _Bad("its meta data lack cell, n or values")
    return meta, _META.size + n_meta


def _int(meta: dict, key: str, low: int, high: int) -> int:
    value = meta[key]
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value < high:
        raise _Bad(f"its {key} {value!r} is outside [{low}, {high})")
    return value


def _layout(spec: object) -> tuple[str, np.dtype, tuple[int, ...]]:
    """(name, dtype, trailing shape) of one output, checked."""
    if not (isinstance(spec, list) and len(spec) == 3 and isinstance(spec[0], str)
            and isinstance(spec[1], str) and isinstance(spec[2], list)):
        raise _Bad("an output is not described as [name, dtype, shape]")
    name, dtype, tail = spec
    try:
        dt = np.dtype(dtype)
    except TypeError:
        raise _Bad(f"output {name!r} has an unknown dtype") from None
    if dt.kind not in "biuf" or dt.str != dtype or dt.itemsize > 16:
        raise _Bad(f"output {name!r} has dtype {dtype!r}, not a plain number type")
    if len(tail) > _MAX_TAIL_DIMS or not all(
            isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in tail):
        raise _Bad(f"output {name!r} has an invalid shape")
    return name, dt, tuple(tail)


def decode_chunk(payload: bytes | memoryview, key: str, n_cells: int,
                 n_trials: int) -> ChunkRecord:
    """The chunk in ``payload``, checked against the study (``key``, grid size, trials per cell).

    Raises
    ------
    InputError
        When the digest does not match (altered, or from another study) or the
        contents are not those of a chunk of this study: cell or trial index out
        of range, a trial twice, sizes that do not add up, a non-numeric dtype.
    """
    view = memoryview(payload)
    try:
        if len(view) < _DIGEST or not hmac.compare_digest(
                _digest(key, view[:-_DIGEST]), bytes(view[-_DIGEST:])):
            raise _Bad("its digest does not match this study (the frame was altered, "
                       "or comes from another study's checkpoint)")
        body = view[:-_DIGEST]
        meta, pos = _meta(body)
        cell = _int(meta, "cell", 0, n_cells)
        n = _int(meta, "n", 1, n_trials + 1)
        if not isinstance(meta["values"], list) or not meta["values"]:
            raise _Bad("it holds no outputs")
        layout = [_layout(spec) for spec in meta["values"]]
        if len({name for name, _, _ in layout}) != len(layout):
            raise _Bad("it names an output twice")
        sizes = [n * dt.itemsize * math.prod(tail) for _, dt, tail in layout]
        if pos + 8 * n + sum(sizes) != len(body):
            raise _Bad("its arrays do not fill it exactly")
        trials = np.frombuffer(body, "<i8", n, pos).astype(np.int64)
        if trials.min() < 0 or trials.max() >= n_trials or len(np.unique(trials)) != n:
            raise _Bad(f"its trial indices are outside [0, {n_trials}) or repeated")
        pos += 8 * n
        values = {}
        for (name, dt, tail), size in zip(layout, sizes):
            values[name] = np.frombuffer(body, dt, size // dt.itemsize, pos).reshape((n, *tail))
            pos += size
    except _Bad as exc:
        raise InputError(f"a chunk is not valid: {exc}") from None
    return ChunkRecord(cell, trials, values)


def _frame_at(buf: memoryview, pos: int) -> tuple[bytes, int] | None:
    """(kind, end) of a valid frame starting at ``pos``, else None."""
    if pos + HEAD.size > len(buf):
        return None
    magic, kind, length, crc = HEAD.unpack_from(buf, pos)
    end = pos + HEAD.size + length
    if magic != MAGIC or kind not in _KINDS or end > len(buf):
        return None
    payload = buf[pos + HEAD.size:end]
    if zlib.crc32(payload) != crc:
        return None
    if kind == b"P" and payload.tobytes().strip(b"\0"):  # padding is zeros: else a bad kind
        return None
    return kind, end


def _next_frame(buf: memoryview, raw: bytes | bytearray, start: int) -> int | None:
    """Offset of the next valid frame at or after ``start``, else None."""
    pos = raw.find(MAGIC, start)
    while pos != -1:
        if _frame_at(buf, pos) is not None:
            return pos
        pos = raw.find(MAGIC, pos + 1)
    return None


@dataclass(frozen=True)
class Scan:
    """What a checkpoint's bytes hold.

    Attributes
    ----------
    frames : list of (offset, kind, payload)
        Every valid frame, in file order (padding frames left out).
    damaged : list of (start, end)
        Byte ranges skipped between valid frames.
    end : int
        End of the last valid frame: what follows (up to ``size``) is a torn or
        damaged tail with no valid frame in it.
    size : int
        File size in bytes.
    """

    frames: list
    damaged: list
    end: int
    size: int


def scan(raw: bytes | bytearray) -> Scan:
    """Split ``raw`` (the file's bytes) into valid frames and damaged ranges.

    A frame that fails any check (magic, kind, length, crc32) is skipped by
    searching for the next position where a valid frame starts, so damage in
    the middle loses only the frames it touches.
    """
    buf = memoryview(raw)
    frames, damaged, pos = [], [], 0
    while pos < len(buf):
        found = _frame_at(buf, pos)
        if found is None:
            nxt = _next_frame(buf, raw, pos + 1)
            if nxt is None:
                break
            damaged.append((pos, nxt))
            pos = nxt
            continue
        kind, end = found
        if kind != b"P":
            frames.append((pos, kind, buf[pos + HEAD.size:end]))
        pos = end
    return Scan(frames, damaged, pos, len(buf))
