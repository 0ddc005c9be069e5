"""``run_study``: a Monte Carlo sweep over a grid of settings, as an xarray Dataset."""

from __future__ import annotations

import hashlib
import math
import os
import pickle
import sys
import tempfile
import threading
import types
import warnings
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._io import atomic_path, ensure_dir
from .._validation import _short, flag, integer
from .._version import __version__
from ..errors import InputError
from . import executors
from ._output import dataset_seed, first_dataset, seed_attrs, study_dataset
from ._work import (
    check_signature,
    declared_outputs,
    declared_settings,
    is_vectorized,
    run_chunk,
)
from .checkpoint import Checkpoint, ChunkRecord, recorded_seed
from .grid import Grid, check_fixed, check_known, make_grid, settings_json
from .results import Results, check_budget, memory_limit
from .seeds import study_entropy

__all__ = ["run_study", "trial_name", "dataset_seed", "seed_attrs"]


def trial_name(trial: Callable) -> str:
    """``module:qualname`` of a trial function (part of a study's fingerprint)."""
    return f"{getattr(trial, '__module__', '?')}:{getattr(trial, '__qualname__', repr(trial))}"


def _code_hash(trial: Callable) -> str:
    """Hash of the trial function's own bytecode and constants (not of its callees)."""
    code = getattr(trial, "__code__", None)
    if code is None:
        return ""
    h = hashlib.sha256()

    def feed(c: types.CodeType) -> None:
        h.update(c.co_code)
        h.update(repr(c.co_names).encode())
        for const in c.co_consts:  # nested functions: their code, not their address
            feed(const) if isinstance(const, types.CodeType) else h.update(repr(const).encode())

    feed(code)
    return h.hexdigest()[:16]


def _fingerprint(trial: Callable, grid: Grid, fixed: dict, n_trials: int, entropy: int) -> dict:
    return {
        "trial": trial_name(trial),
        "trial_code": _code_hash(trial),
        "vectorized": is_vectorized(trial),
        "grid": grid.to_json(),
        "fixed": settings_json(fixed),
        "n_trials": n_trials,
        "seed": str(entropy),
        "olsbayes_version": __version__,
    }


def _check_picklable(trial: Callable, backend_name: str) -> None:
    if backend_name in ("serial", "threads"):
        return
    main = sys.modules.get("__main__")
    main_file = getattr(main, "__file__", None)
    if getattr(trial, "__module__", None) == "__main__" and not (
        main_file and os.path.isfile(main_file)
    ):
        raise InputError(
            f"trial {trial_name(trial)} is defined in an interactive session, which "
            f"{backend_name} workers cannot import: put it in a module (a .py file) or use "
            "executor='serial' or 'threads'"
        )
    try:
        pickle.dumps(trial)
    except Exception as exc:  # noqa: BLE001 - any pickling failure means the same thing
        raise InputError(
            f"trial {trial_name(trial)} cannot be sent to {backend_name} workers: define it at "
            f"module level in an importable module ({type(exc).__name__}: {exc})"
        ) from None


@dataclass(frozen=True)
class _Study:
    """What every chunk needs: the trial, its settings, the seed and the study's size."""

    trial: Callable
    grid: Grid
    fixed: dict
    n_trials: int
    entropy: int


def _writable(path: object, name: str) -> Path:
    """``path`` as a Path, refused before any work if a file cannot be written there.

    Creates the file's folder if needed, and checks by creating (and removing) a
    temporary file in it that a file can be written there.
    """
    try:
        p = Path(path)  # type: ignore[arg-type]
        if "\0" in str(p) or not str(p):
            raise ValueError("empty, or holds a NUL byte")
        is_dir, exists, is_file = p.is_dir(), p.exists(), p.is_file()
    except (TypeError, ValueError, OSError) as exc:
        raise InputError(f"{name} must be a file path; got {_short(path)} ({exc})") from None
    if is_dir:
        raise InputError(f"{name} {str(p)!r} is a folder; give a file name")
    if exists and not is_file:
        raise InputError(f"{name} {str(p)!r} is not a regular file (a device, FIFO or "
                         "socket); give a file name")
    folder = ensure_dir(p.parent, f"folder of {name}")
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise InputError(f"{name} {str(p)!r} cannot be written: {exc.strerror or exc}") from None
    return p


def run_study(
    trial: Callable,
    grid: Mapping,
    n_trials: int,
    *,
    fixed: Mapping | None = None,
    executor: object = "processes",
    workers: int | None = None,
    scheduler: str | None = None,
    checkpoint: str | os.PathLike | None = None,
    out: str | os.PathLike | None = None,
    rng: object = None,
    chunk_size: int | None = None,
    progress: bool = True,
    max_memory_gb: float | None = None,
) -> Any:
    """Run ``n_trials`` Monte Carlo trials at every point of ``grid``.

    Parameters
    ----------
    trial : callable
        ``trial(settings, *, rng) -> {name: number or fixed-shape array}``, a module-level
        function (picklable); or one marked with :func:`olsbayes.studies.vectorized`,
        ``trial(settings, *, rngs) -> {name: array (T, ...)}`` for a chunk of T trials.
        ``settings`` is ``{**fixed, **cell}``.  A trial that declares its settings
        with :func:`olsbayes.studies.trial_settings` gets other settings refused and
        its parsed settings (e.g. ``estimator``, ranges) checked here, before any
        trial runs.
    grid : dict
        ``{axis name: list of values}`` (numbers, strings, bools or records such as
        :class:`~olsbayes.studies.Estimator`, whose ``label`` becomes the
        coordinate); may be empty.
    n_trials : int
        Trials per grid cell (>= 1).
    fixed : dict, optional
        Settings shared by all cells (scalars or lists), recorded in the result.
    executor : str, distributed.Client or Executor-like
        ``"processes"`` (default), ``"serial"``, ``"threads"``, ``"dask"`` or an object;
        see :func:`olsbayes.studies.executors.make_backend`.
    workers : int, optional
        Local pool size (>= 1; default: usable cores).
    scheduler : str, optional
        Dask scheduler address, with ``executor="dask"``.
    checkpoint : path, optional
        Append-only checkpoint (created with its folder if absent); one made with
        the same settings is resumed (its recorded seed is used when ``rng`` is
        None), one made with other settings is refused with
        :class:`~olsbayes.errors.InputError`, and so is one that another running
        study holds (file lock).  Damaged frames are skipped with a warning and
        their trials run again.
    out : path, optional
        Write the dataset there as NetCDF (atomic write); checked before any
        trial runs.
    rng : int, SeedSequence, Generator or None
        Root seed. Trial t of cell c uses ``SeedSequence(seed, spawn_key=(c, t))``,
        so results do not depend on the executor, workers or ``chunk_size``.
    chunk_size : int, optional
        Trials per task (all from one cell); default spreads the work in about
        eight tasks per worker (four on Dask, whose tasks cost more to dispatch),
        at most 1000 trials each.
    progress : bool
        Show a tqdm bar over trials (on stderr).
    max_memory_gb : float, optional
        Memory budget (GB) of the result arrays (default: half the physical
        memory, at most 4 GB).  A study that needs more is refused before any
        trial runs when even one number per trial would not fit, else as soon
        as the first chunk tells the size of a trial's outputs.

    Returns
    -------
    xarray.Dataset
        One variable per trial output, dims ``(*grid axes, "trial", <name>_dim0, ...)``,
        each with ``long_name`` and ``units`` attributes as the trial describes them
        (:func:`~olsbayes.studies.trial_outputs`; ``long_name`` = its name otherwise);
        attrs ``seed`` (numeric: see :func:`seed_attrs`, :func:`dataset_seed`) and
        ``seed_decimal``, ``olsbayes_version``, ``trial_function``, ``grid`` and
        ``fixed_settings`` (JSON), ``n_trials``, ``study_key``.
    """
    if not callable(trial):
        raise InputError(f"trial must be a function (settings, *, rng) -> dict; got {trial!r}")
    check_signature(trial, trial_name(trial))
    known, parsers = declared_settings(trial)
    g = make_grid(grid, parsers)
    fixed_s = check_fixed(fixed, g, parsers)
    check_known([*g.names, *fixed_s], known, trial_name(trial))
    n_trials = integer("n_trials", n_trials, low=1)
    if chunk_size is not None:
        chunk_size = integer("chunk_size", chunk_size, low=1)
    if workers is not None:
        workers = integer("workers", workers, low=1)
    flag("progress", progress)
    executors.check_script_guard(executor, scheduler)  # before any file is touched
    limit = memory_limit(max_memory_gb)
    check_budget(n_trials, g.n_cells, limit)
    out = None if out is None else _writable(out, "out")
    if checkpoint is not None:
        checkpoint = _writable(checkpoint, "checkpoint")
        if rng is None:
            rng = recorded_seed(checkpoint)
    study = _Study(trial, g, fixed_s, n_trials, study_entropy(rng))
    fp = _fingerprint(trial, g, fixed_s, n_trials, study.entropy)
    results = Results(g.n_cells, n_trials, limit)
    ckpt = Checkpoint.open(checkpoint, fp, max_bytes=limit) if checkpoint is not None else None
    try:  # the checkpoint stays locked against a second study until this one ends
        if ckpt is not None:
            _resume(ckpt, results, g)
        if results.n_todo:
            _execute(study, results, ckpt, (executor, workers, scheduler), chunk_size, progress)
    finally:
        if ckpt is not None:
            ckpt.close()
    shape = g.shape + (n_trials,)
    full = {k: v.reshape(shape + v.shape[2:]) for k, v in results.arrays.items()}
    ds = study_dataset(full, g, fp, declared_outputs(trial))
    if out is not None:
        with atomic_path(out) as tmp:
            ds.to_netcdf(tmp, engine="h5netcdf")
    return ds


def _resume(ckpt: Checkpoint, results: Results, g: Grid) -> None:
    """Take the checkpoint's chunks; warn about the trials of damaged frames."""
    for rec in ckpt.records:
        results.add(rec)
    ckpt.records.clear()
    if ckpt.damaged:
        where = ", ".join(f"{a}-{b}" for a, b in ckpt.damaged)
        cells = results.missing(lambda c: ", ".join(
            f"{k}={getattr(v, 'label', v)}" for k, v in g.cell(c).items()) or "the study")
        warnings.warn(f"checkpoint {str(ckpt.path)!r}: skipped damaged frames at bytes "
                      f"{where}; the trials they held are among those not in the checkpoint, "
                      f"which run again: {cells}", RuntimeWarning, stacklevel=3)


def _execute(study: _Study, results: Results, ckpt: Checkpoint | None, where: tuple,
             chunk_size: int | None, progress: bool) -> None:
    """Run every trial not done, on the backend of ``where`` = (executor, workers, scheduler)."""
    from tqdm.auto import tqdm

    total = study.grid.n_cells * study.n_trials
    n_todo = results.n_todo
    executor, workers, scheduler = where
    if not isinstance(executor, str) or executor in ("threads", "processes", "dask"):
        # xarray's first Dataset while the workers start and run, not after the last chunk
        threading.Thread(target=first_dataset, name="olsbayes-study-xarray", daemon=True).start()
    backend = executors.make_backend(executor, workers=workers, scheduler=scheduler,
                                     start_delay=executors.POOL_START_DELAY)
    try:
        _check_picklable(study.trial, backend.name)
        size = chunk_size or max(1, min(1000, study.n_trials,
                                        math.ceil(n_todo / (backend.chunks_per_worker
                                                            * backend.n_workers))))
        queue = results.todo(size, 1 if chunk_size else backend.n_workers)  # shrinking at the end
        window = max(2, 2 * backend.n_workers)
        pending: list = []
        chunks: dict[int, tuple[int, np.ndarray]] = {}  # id(future) -> (cell, trials)
        with tqdm(total=total, initial=total - n_todo, unit="trial", disable=not progress,
                  desc=f"study ({backend.name})", dynamic_ncols=True) as bar:
            nxt = next(queue, None)
            while nxt is not None or pending:
                while nxt is not None and len(pending) < window:
                    # while this process works alone, a chunk for each worker at once:
                    # the chunk size of a serial study (results do not depend on it)
                    (cell, idx), nxt = _take(queue, nxt, backend.n_workers
                                             if backend.alone and not chunk_size else 1)
                    fut = backend.submit(run_chunk, study.trial,
                                         {**study.fixed, **study.grid.cell(cell)},
                                         study.entropy, cell, idx)
                    chunks[id(fut)] = (cell, idx)
                    pending.append(fut)
                done, pending = backend.wait_first(pending)
                for fut in done:
                    bar.update(_collect(fut, chunks.pop(id(fut)), study.grid, ckpt, results,
                                        pending))
    finally:
        backend.close()


def _take(queue: Iterator, nxt: tuple, n: int) -> tuple[tuple[int, np.ndarray], Any]:
    """Up to ``n`` queued chunks of one cell, joined, starting with ``nxt``; and the next."""
    cell, idx = nxt
    parts = [idx]
    nxt = next(queue, None)
    while len(parts) < n and nxt is not None and nxt[0] == cell:
        parts.append(nxt[1])
        nxt = next(queue, None)
    return (cell, parts[0] if len(parts) == 1 else np.concatenate(parts)), nxt


def _collect(fut: Any, chunk: tuple[int, np.ndarray], g: Grid, ckpt: Checkpoint | None,
             results: Results, pending: list) -> int:
    """Check, checkpoint and store one finished chunk; return its number of trials."""
    try:
        cell, idx, values = fut.result()
        rec = ChunkRecord(int(cell), np.asarray(idx), values)
        results.check(rec)  # a chunk unlike the others never reaches the checkpoint
        if ckpt is not None:
            ckpt.append(cell, idx, values)
        results.add(rec)
    except Exception as exc:
        for other in pending:
            other.cancel()
        cell, idx = chunk
        if hasattr(exc, "add_note"):
            exc.add_note(f"olsbayes study: in trials {idx[0]}..{idx[-1]} of cell {cell} "
                         f"(settings {g.cell(cell)})")
        raise
    return len(idx)
