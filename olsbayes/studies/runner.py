"""``run_study``: a Monte Carlo sweep over a grid of settings, as an xarray Dataset."""

from __future__ import annotations

import hashlib
import json
import math
import os
import pickle
import sys
import types
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .._io import atomic_path
from .._validation import integer
from .._version import __version__
from ..errors import InputError
from ._work import check_signature, declared_settings, is_vectorized, run_chunk
from .checkpoint import Checkpoint, ChunkRecord, fingerprint_key
from .executors import make_backend
from .grid import Grid, check_fixed, check_known, make_grid, settings_json
from .seeds import study_entropy

__all__ = ["run_study", "trial_name"]


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


def _remaining(records: list[ChunkRecord], n_cells: int, n_trials: int) -> list[np.ndarray]:
    """Trial indices still to run, per cell; error on duplicates in the checkpoint."""
    done = np.zeros((n_cells, n_trials), dtype=np.int64)
    for rec in records:
        np.add.at(done[rec.cell], rec.trials, 1)
    if np.any(done > 1):
        cell, t = np.argwhere(done > 1)[0]
        raise InputError(f"checkpoint holds trial {t} of cell {cell} twice; it is corrupt")
    return [np.flatnonzero(done[c] == 0) for c in range(n_cells)]


def _chunks(todo: list[np.ndarray], size: int) -> list[tuple[int, np.ndarray]]:
    return [(c, idx[i:i + size]) for c, idx in enumerate(todo) for i in range(0, len(idx), size)]


def _assemble(records: list[ChunkRecord], grid: Grid, n_trials: int) -> dict[str, np.ndarray]:
    """Place every record's results at (cell, trial) in full arrays."""
    first = records[0].values
    shape = grid.shape + (n_trials,)
    full = {k: np.zeros(shape + v.shape[1:], dtype=v.dtype) for k, v in first.items()}
    for rec in records:
        if set(rec.values) != set(first):
            raise InputError("trial outputs must have the same names in every cell and chunk; "
                             f"got {sorted(first)} vs {sorted(rec.values)}")
        pos = np.unravel_index(rec.cell, grid.shape) if grid.names else ()
        for name, arr in rec.values.items():
            if arr.shape[1:] != first[name].shape[1:]:
                raise InputError(f"trial output {name!r} must have the same shape in every cell "
                                 f"and chunk; got {first[name].shape[1:]} vs {arr.shape[1:]}")
            full[name][pos + (rec.trials,)] = arr
    return full


def _dataset(full: dict, grid: Grid, fingerprint: dict) -> Any:
    import xarray as xr

    dims = grid.names + ("trial",)
    data_vars = {
        name: (dims + tuple(f"{name}_dim{i}" for i in range(arr.ndim - len(dims))), arr)
        for name, arr in full.items()
    }
    coords = dict(grid.coords())
    coords["trial"] = np.arange(fingerprint["n_trials"])
    attrs = {
        "seed": fingerprint["seed"],
        "olsbayes_version": fingerprint["olsbayes_version"],
        "trial_function": fingerprint["trial"],
        "vectorized": int(fingerprint["vectorized"]),
        "n_trials": fingerprint["n_trials"],
        "grid": json.dumps(fingerprint["grid"]),
        "fixed_settings": json.dumps(fingerprint["fixed"]),
        "study_key": fingerprint_key(fingerprint),
    }
    return xr.Dataset(data_vars, coords=coords, attrs=attrs)


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
        its parsed settings (e.g. ``estimator``) checked here, before any trial runs.
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
        Local pool size (default: usable cores).
    scheduler : str, optional
        Dask scheduler address, with ``executor="dask"``.
    checkpoint : path, optional
        Append-only checkpoint; an existing one made with the same settings is
        resumed (its recorded seed is used when ``rng`` is None), one made with
        other settings is refused with :class:`~olsbayes.errors.InputError`, and
        so is one that another running study holds (file lock).
    out : path, optional
        Write the dataset there as NetCDF (atomic write).
    rng : int, SeedSequence, Generator or None
        Root seed. Trial t of cell c uses ``SeedSequence(seed, spawn_key=(c, t))``,
        so results do not depend on the executor, workers or ``chunk_size``.
    chunk_size : int, optional
        Trials per task (all from one cell); default spreads the work in about
        eight tasks per worker (four on Dask, whose tasks cost more to dispatch),
        at most 1000 trials each.
    progress : bool
        Show a tqdm bar over trials (on stderr).

    Returns
    -------
    xarray.Dataset
        One variable per trial output, dims ``(*grid axes, "trial", <name>_dim0, ...)``;
        attrs ``seed`` (str), ``olsbayes_version``, ``trial_function``, ``grid`` and
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
    if not isinstance(progress, bool):
        raise InputError(f"progress must be True or False; got {progress!r}")
    if rng is None and checkpoint is not None and Path(checkpoint).is_file():
        rng = _seed_of(Path(checkpoint))
    entropy = study_entropy(rng)
    fp = _fingerprint(trial, g, fixed_s, n_trials, entropy)
    records: list[ChunkRecord] = []
    ckpt = Checkpoint.open(checkpoint, fp) if checkpoint is not None else None
    try:  # the checkpoint stays locked against a second study until this one ends
        if ckpt is not None:
            records = ckpt.records
        todo = _remaining(records, g.n_cells, n_trials)
        if any(len(t) for t in todo):
            records = _execute(trial, g, fixed_s, n_trials, entropy, todo, ckpt, records,
                               executor, workers, scheduler, chunk_size, progress)
    finally:
        if ckpt is not None:
            ckpt.close()
    ds = _dataset(_assemble(records, g, n_trials), g, fp)
    if out is not None:
        with atomic_path(out) as tmp:
            ds.to_netcdf(tmp, engine="h5netcdf")
    return ds


def _seed_of(path: Path) -> object:
    """The seed recorded in a checkpoint header (None if unreadable; Checkpoint.open reports)."""
    from .checkpoint import _read_frames

    try:
        frames, _, _ = _read_frames(path)
        return int(json.loads(frames[0][1])["fingerprint"]["seed"])
    except (OSError, IndexError, KeyError, ValueError, InputError):
        return None


def _execute(trial, g, fixed_s, n_trials, entropy, todo, ckpt, records, executor, workers,
             scheduler, chunk_size, progress) -> list[ChunkRecord]:
    from tqdm.auto import tqdm

    records = list(records)
    total = g.n_cells * n_trials
    n_todo = int(sum(len(t) for t in todo))
    backend = make_backend(executor, workers=workers, scheduler=scheduler)
    try:
        _check_picklable(trial, backend.name)
        size = chunk_size or max(1, min(1000, n_trials,
                                        math.ceil(n_todo / (backend.chunks_per_worker
                                                            * backend.n_workers))))
        queue = _chunks(todo, size)[::-1]
        window = max(2, 2 * backend.n_workers)
        pending: list = []
        where: dict[int, tuple[int, np.ndarray]] = {}  # id(future) -> (cell, trials)
        with tqdm(total=total, initial=total - n_todo, unit="trial", disable=not progress,
                  desc=f"study ({backend.name})", dynamic_ncols=True) as bar:
            while queue or pending:
                while queue and len(pending) < window:
                    cell, idx = queue.pop()
                    fut = backend.submit(run_chunk, trial, {**fixed_s, **g.cell(cell)},
                                         entropy, cell, idx)
                    where[id(fut)] = (cell, idx)
                    pending.append(fut)
                done, pending = backend.wait_first(pending)
                for fut in done:
                    records.append(_collect(fut, where.pop(id(fut)), g, ckpt, pending))
                    bar.update(len(records[-1].trials))
    finally:
        backend.close()
    return records


def _collect(fut: Any, chunk: tuple[int, np.ndarray], g: Grid, ckpt: Checkpoint | None,
             pending: list) -> ChunkRecord:
    try:
        cell, idx, values = fut.result()
    except Exception as exc:
        for other in pending:
            other.cancel()
        cell, idx = chunk
        if hasattr(exc, "add_note"):
            exc.add_note(f"olsbayes study: in trials {idx[0]}..{idx[-1]} of cell {cell} "
                         f"(settings {g.cell(cell)})")
        raise
    if ckpt is not None:
        ckpt.append(cell, idx, values)
    return ChunkRecord(int(cell), np.asarray(idx), values)
