"""Study checkpoints under attack: concurrent starters, damaged bytes, edited files.

The promise tested here: a resumed study keeps every valid trial of its
checkpoint, runs again exactly the trials of damaged frames, and never returns
a value that differs from an uninterrupted run; what it cannot trust (an edited
or mixed-up file) it refuses with one clear error.
"""

from __future__ import annotations

import io
import json
import multiprocessing
import os
import queue
import struct
import tempfile
import time
import tracemalloc
import warnings
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest
import tqdm.auto  # noqa: F401 - imported once here, not in every forked starter
import xarray  # noqa: F401

from olsbayes import InputError
from olsbayes.studies import run_study, vectorized
from olsbayes.studies._frames import HEAD, MAGIC, encode_chunk, frame, scan
from olsbayes.studies.checkpoint import read_chunks

GRID = {"a": [1, 2]}
N_TRIALS, CHUNK = 24, 3
CALLS: list[int] = []  # trials run by `cheap` in this process (serial executor)


@vectorized
def cheap(settings, rngs):
    """A fast trial with two outputs of different dtypes and shapes."""
    CALLS.append(len(rngs))
    return {"x": np.array([r.random() for r in rngs]) * settings["a"],
            "v": np.array([r.integers(0, 100, 3) for r in rngs])}


def held(settings, rng):
    """Waits until the file ``settings["go"]`` exists: the study holds its checkpoint till then."""
    deadline = time.monotonic() + 30
    while not os.path.exists(settings["go"]) and time.monotonic() < deadline:
        time.sleep(0.002)
    return {"x": rng.random()}


def _study(ckpt, **kw):
    kw.setdefault("chunk_size", CHUNK)
    return run_study(cheap, GRID, N_TRIALS, executor="serial", rng=5, checkpoint=ckpt,
                     progress=False, **kw)


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    """(reference dataset, bytes of its complete checkpoint, [(start, end, n_trials)] of chunks)."""
    path = tmp_path_factory.mktemp("ref") / "ref.ckpt"
    ref = _study(path)
    data = path.read_bytes()
    found = scan(data)
    chunks = [(pos, pos + HEAD.size + len(p), None) for pos, kind, p in found.frames[1:]]
    sizes = [len(rec.trials) for rec in read_chunks(path)]
    return ref, data, [(a, b, n) for (a, b, _), n in zip(chunks, sizes)]


def _resume(path):
    """Resume ``path``: (dataset or the InputError, trials run, warnings)."""
    CALLS.clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            ds = _study(path)
        except InputError as exc:
            ds = exc
    return ds, sum(CALLS), [str(w.message) for w in caught]


# -- concurrent starters ---------------------------------------------------------
def _start(path, go, barrier, results):
    barrier.wait()
    try:
        run_study(held, {}, 4, fixed={"go": str(go)}, executor="serial", rng=1,
                  checkpoint=path, progress=False)
        results.put("ran")
    except InputError as exc:
        results.put(str(exc))


def test_two_simultaneous_starters_exactly_one_runs(tmp_path):
    """Both start at once on a fresh path; the runner's trials wait until the other has answered."""
    run_study(held, {}, 1, fixed={"go": "/"}, executor="serial", rng=1, progress=False)  # warm
    ctx = multiprocessing.get_context("fork")
    outcomes = []
    for i in range(50):
        path, go = tmp_path / f"race{i}.ckpt", tmp_path / f"go{i}"
        barrier, results = ctx.Barrier(2), ctx.Queue()
        procs = [ctx.Process(target=_start, args=(path, go, barrier, results))
                 for _ in range(2)]
        for p in procs:
            p.start()
        try:
            first = results.get(timeout=20)  # the refused starter answers at once
        except queue.Empty:
            first = "no starter was refused"
        go.touch()
        second = results.get(timeout=60)
        for p in procs:
            p.join(60)
        trials = sorted(int(t) for rec in read_chunks(path) for t in rec.trials)
        ok = ("in use by another running study" in first and second == "ran"
              and trials == [0, 1, 2, 3])
        outcomes.append(True if ok else (first, second, trials))
    assert outcomes == [True] * 50


# -- damage ------------------------------------------------------------------------
@pytest.mark.parametrize("what", ["magic", "length"])
def test_damaged_middle_frame_loses_only_its_trials(pristine, tmp_path, what):
    ref, data, chunks = pristine
    start, end, n = chunks[5]
    bad = bytearray(data)
    if what == "magic":
        bad[start] ^= 0x20
    else:  # the length field claims more than the frame holds
        struct.pack_into("<Q", bad, start + 5, end - start + 1000)
    path = tmp_path / "c.ckpt"
    path.write_bytes(bad)
    ds, ran, warned = _resume(path)
    assert ds.identical(ref) and ran == n  # the other 15 chunks kept: nothing else ran
    assert len(warned) == 1 and f"bytes {start}-{end}" in warned[0]
    lost = read_chunks(tmp_path / "c.ckpt")  # healed: the rerun trials were appended
    assert sorted((r.cell, int(t)) for r in lost for t in r.trials) == [
        (c, t) for c in range(2) for t in range(N_TRIALS)]
    ds, ran, warned = _resume(path)  # the damage is now padding: silent, nothing to run
    assert ds.identical(ref) and ran == 0 and warned == []


def test_damaged_frame_names_the_lost_trials(pristine, tmp_path):
    ref, data, chunks = pristine
    start, end, n = chunks[9]  # chunks are written in order: cell 1, trials 3-5
    bad = bytearray(data)
    bad[start + 30] ^= 1
    path = tmp_path / "c.ckpt"
    path.write_bytes(bad)
    ds, ran, warned = _resume(path)
    assert ds.identical(ref) and ran == n
    assert "a=2: trials 3-5" in warned[0]


def _damage(data: bytes, rng: np.random.Generator, chunks: list) -> tuple[bytes, set, str]:
    """Random damage: (new bytes, indices of the chunks it destroys, kind of damage)."""
    bad = bytearray(data)
    kind = ["flip", "flips", "truncate", "flip+truncate", "duplicate", "zeros"][
        rng.integers(6)]
    hit: set[int] = set()
    touched: list[int] = []
    if kind in ("flip", "flips", "flip+truncate"):
        n_flips = 1 if kind != "flips" else int(rng.integers(2, 5))
        for pos in rng.choice(len(bad), n_flips, replace=False):
            bad[pos] ^= int(rng.integers(1, 256))
            touched.append(int(pos))
    if kind == "zeros":
        a = int(rng.integers(0, len(bad) - 1))
        b = min(len(bad), a + int(rng.integers(1, 200)))
        if any(bad[a:b]):
            bad[a:b] = bytes(b - a)
            touched += [p for p in range(a, b) if data[p]]
    cut = len(bad)
    if kind in ("truncate", "flip+truncate"):
        cut = int(rng.integers(0, len(bad)))
        del bad[cut:]
    for i, (a, b, _) in enumerate(chunks):
        if b > cut or any(a <= p < b for p in touched):
            hit.add(i)
    if kind == "duplicate":
        i = int(rng.integers(len(chunks)))
        a, b, _ = chunks[i]
        bad[b:b] = data[a:b]
    return bytes(bad), hit, kind


@pytest.fixture
def fast_dir(tmp_path):
    """A folder in memory where there is one (fsync costs nothing there), else ``tmp_path``."""
    shm = Path("/dev/shm")
    if not (shm.is_dir() and os.access(shm, os.W_OK)):
        yield tmp_path
        return
    with tempfile.TemporaryDirectory(dir=shm) as d:
        yield Path(d)


def test_fault_injection_keeps_every_valid_trial_and_reruns_every_lost_one(pristine, fast_dir):
    ref, data, chunks = pristine
    tmp_path = fast_dir
    header_end = chunks[0][0]
    rng = np.random.default_rng(2024)
    tally = {"identical": 0, "refused": 0}
    for seed in range(240):
        bad, hit, kind = _damage(data, rng, chunks)
        path = tmp_path / f"f{seed}.ckpt"
        path.write_bytes(bad)
        ds, ran, warned = _resume(path)
        header_hit = bad[:header_end] != data[:header_end]
        if isinstance(ds, InputError):  # only a damaged header may stop a resume
            assert header_hit, (seed, kind, ds)
            assert ("damaged header" in str(ds) if hit != set(range(len(chunks))) else
                    "not an olsbayes study checkpoint" in str(ds)), (seed, kind, ds)
            tally["refused"] += 1
            continue
        assert ds.identical(ref), (seed, kind)  # never a wrong value
        expected = N_TRIALS * 2 if len(bad) < header_end else sum(chunks[i][2] for i in hit)
        assert ran == expected, (seed, kind, ran, expected, warned)
        assert (kind == "duplicate") == any("recorded twice" in w for w in warned), (seed, warned)
        tally["identical"] += 1
    assert tally["identical"] >= 200 and tally["refused"] >= 1, tally


# -- edited files (valid crc32) -------------------------------------------------------
def _with_chunk(data: bytes, chunks: list, i: int, payload: bytes) -> bytes:
    """``data`` with chunk ``i`` replaced by a frame of ``payload`` (fresh, valid crc32)."""
    a, b, _ = chunks[i]
    return data[:a] + frame(b"C", payload) + data[b:]


def _key(data: bytes) -> str:
    return json.loads(bytes(scan(data).frames[0][2]))["key"]


def _npz_bomb() -> bytes:
    """A small deflated .npz claiming a GB-sized array (the old chunk encoding)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        with z.open("v:x.npy", "w", force_zip64=True) as f:
            f.write(b"\x93NUMPY\x01\x00v\x00{'descr': '<f8', 'fortran_order': False, "
                    b"'shape': (134217728,), }" + b" " * 49 + b"\n")
            zero = bytes(1 << 20)
            for _ in range(64):
                f.write(zero)
    return buf.getvalue()


def test_edited_checkpoints_are_refused_with_a_clear_error(pristine, tmp_path):
    ref, data, chunks = pristine
    key = _key(data)
    rec = read_chunks_of(data)[4]
    x, v = rec.values["x"], rec.values["v"]
    edits = {
        # relabelled trials with a fresh crc32 but the old digest
        "relabel": _with_chunk(data, chunks, 4, _relabel(data, chunks, 4)),
        # a chunk of another study (other key)
        "other study": _with_chunk(data, chunks, 4, encode_chunk("ab" * 32, rec.cell, rec.trials,
                                                                  rec.values)),
        # well-signed but wrong contents (as if our own writer had a bug)
        "trial out of range": _with_chunk(data, chunks, 4, encode_chunk(
            key, rec.cell, rec.trials + 100, rec.values)),
        "cell out of range": _with_chunk(data, chunks, 4, encode_chunk(key, 7, rec.trials,
                                                                        rec.values)),
        "trial twice": _with_chunk(data, chunks, 4, encode_chunk(
            key, rec.cell, np.array([0, 0, 1]), rec.values)),
        "other shape": _with_chunk(data, chunks, 4, encode_chunk(
            key, rec.cell, rec.trials, {"x": x, "v": v[:, :2]})),
        "other names": _with_chunk(data, chunks, 4, encode_chunk(
            key, rec.cell, rec.trials, {"x": x, "w": v})),
        "complex": _with_chunk(data, chunks, 4, encode_chunk(
            key, rec.cell, rec.trials, {"x": x.astype(complex), "v": v})),
        "conflicting duplicate": data + frame(b"C", encode_chunk(
            key, rec.cell, rec.trials, {"x": x + 1, "v": v})),
        "inflating npz": _with_chunk(data, chunks, 4, _npz_bomb()),
        "huge claimed shape": _with_chunk(data, chunks, 4, _huge_claim(key)),
        "header key": _edit_header(data, lambda h: {**h, "key": "0" * 64}),
        "header junk": _edit_header(data, lambda h: [1, 2]),
    }
    messages = {
        "relabel": "digest does not match", "other study": "digest does not match",
        "trial out of range": "trial indices are outside [0, 24)",
        "cell out of range": "cell 7 is outside [0, 2)", "trial twice": "or repeated",
        "other shape": "must have the same shape", "other names": "the same names",
        "complex": "not a plain number type",
        "conflicting duplicate": "recorded twice with different results",
        "inflating npz": "digest does not match", "huge claimed shape": "do not fill it exactly",
        "header key": "key does not match its settings", "header junk": "unreadable header",
    }
    for name, bad in edits.items():
        path = tmp_path / "e.ckpt"
        path.write_bytes(bad)
        tracemalloc.start()
        ds, ran, _ = _resume(path)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert isinstance(ds, InputError), name
        assert messages[name] in str(ds) and len(str(ds).splitlines()) == 1, (name, str(ds))
        assert ran == 0, name
        assert peak < 50e6, (name, peak)  # nothing inflated, nothing allocated as claimed


def read_chunks_of(data: bytes):
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "x.ckpt"
        p.write_bytes(data)
        return read_chunks(p)


def _relabel(data: bytes, chunks: list, i: int) -> bytes:
    """Chunk ``i``'s payload with its first trial index changed (digest left as it was)."""
    a, b, _ = chunks[i]
    payload = bytearray(data[a + HEAD.size:b])
    (n_meta,) = struct.unpack_from("<I", payload)
    first = 4 + n_meta
    struct.pack_into("<q", payload, first, 23)
    return bytes(payload)


def _huge_claim(key: str) -> bytes:
    """A small chunk whose meta claims a (10**9,) float array."""
    import hashlib

    meta = json.dumps({"cell": 0, "n": 1, "values": [["x", "<f8", [10**9]]]}).encode()
    body = struct.pack("<I", len(meta)) + meta + struct.pack("<q", 0) + bytes(64)
    return body + hashlib.blake2b(body, key=bytes.fromhex(key), digest_size=16).digest()


def _edit_header(data: bytes, edit) -> bytes:
    found = scan(data)
    header = json.loads(bytes(found.frames[0][2]))
    end = HEAD.size + len(found.frames[0][2])
    return frame(b"H", json.dumps(edit(header)).encode()) + data[end:]


def test_special_and_foreign_files_are_refused(tmp_path):
    import os

    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for path, message in [(fifo, "not a regular file"), (tmp_path, "is a folder"),
                          ("/dev/zero", "not a regular file")]:
        with pytest.raises(InputError, match=message):
            _study(path)
    old = tmp_path / "old.ckpt"  # a checkpoint of the previous format
    header = {"format": "olsbayes-study-checkpoint/1", "key": "0", "fingerprint": {}}
    payload = json.dumps(header).encode()
    old.write_bytes(struct.pack("<4scQI", MAGIC, b"H", len(payload), zlib.crc32(payload))
                    + payload)
    with pytest.raises(InputError, match="has format 'olsbayes-study-checkpoint/1'"):
        _study(old)
    empty = tmp_path / "empty.ckpt"  # left empty (e.g. a crash): started afresh
    empty.write_bytes(b"")
    ref = _study(tmp_path / "fresh.ckpt")
    assert _study(empty).identical(ref)
