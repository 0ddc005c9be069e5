"""A study's results, filled in chunk by chunk within a memory budget.

Nothing proportional to the number of trials is allocated before the first
chunk's results arrive: a fresh study hands out its chunks as index ranges.
The first chunk fixes the outputs' names, dtypes and shapes, hence the exact
size of the result arrays; they (and a one-byte-per-trial record of which trials
are done) are allocated then, if they fit in the budget.  Before any trial runs,
:func:`check_budget` refuses a study that cannot fit even if each trial
returned a single number.
"""

from __future__ import annotations

import math
import numbers
import os
import warnings
from collections.abc import Callable, Iterator

import numpy as np

from ..errors import InputError
from ._frames import ChunkRecord

__all__ = ["Results", "memory_limit", "check_budget", "MIN_BYTES_PER_TRIAL"]

#: Bytes per trial that any study needs: one 8-byte number and one byte of bookkeeping.
MIN_BYTES_PER_TRIAL = 9
_GB = 1e9
#: Default budget: half the physical memory, at most this many bytes.
_DEFAULT_CAP = 4 * _GB
_RAISE = "raise it with max_memory_gb= (in a study config: [study] max_memory_gb)"


def _num(n: int) -> str:
    """``1000000000`` as ``1e9``, small numbers as they are."""
    if n < 100_000:
        return str(n)
    text = f"{n:.3g}"
    return text.replace("e+0", "e").replace("e+", "e")


def memory_limit(max_memory_gb: object = None) -> int:
    """The budget in bytes: ``max_memory_gb`` GB; by default half the memory, at most 4 GB."""
    if max_memory_gb is None:
        try:
            phys = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (AttributeError, OSError, ValueError):  # pragma: no cover - not POSIX
            phys = 2 * _DEFAULT_CAP
        return int(min(_DEFAULT_CAP, phys / 2))
    if isinstance(max_memory_gb, bool) or not isinstance(max_memory_gb, numbers.Real) \
            or not 0 < float(max_memory_gb) <= 1e6:
        raise InputError(f"max_memory_gb must be a number in (0, 1e6]; got {max_memory_gb!r}")
    return int(max_memory_gb * _GB)


def check_budget(n_trials: int, n_cells: int, limit: int) -> None:
    """Refuse, before any work, a study whose results cannot fit in ``limit`` bytes."""
    need = n_trials * n_cells * MIN_BYTES_PER_TRIAL
    if need > limit:
        raise InputError(
            f"n_trials={_num(n_trials)} at {_num(n_cells)} grid cell(s) needs at least "
            f"~{need / _GB:.3g} GB for its results and bookkeeping ({MIN_BYTES_PER_TRIAL} bytes "
            f"per trial); the limit is {limit / _GB:.3g} GB; {_RAISE}"
        )


def _ranges(idx: np.ndarray, most: int = 4) -> str:
    """``[0, 1, 2, 5]`` as ``"0-2, 5"`` (the first ``most`` runs)."""
    breaks = np.flatnonzero(np.diff(idx) != 1)
    starts = np.r_[idx[:1], idx[breaks + 1]]
    ends = np.r_[idx[breaks], idx[-1:]]
    runs = [f"{a}" if a == b else f"{a}-{b}" for a, b in zip(starts[:most], ends[:most])]
    return ", ".join(runs) + (f" and {len(starts) - most} more runs" if len(starts) > most else "")


class Results:
    """Result arrays ``{name: (n_cells, n_trials, ...)}`` and which trials are done.

    Parameters
    ----------
    n_cells, n_trials : int
        Grid cells and trials per cell.
    limit : int
        Budget in bytes for the result arrays and the done-record.
    """

    def __init__(self, n_cells: int, n_trials: int, limit: int):
        self.n_cells, self.n_trials, self.limit = n_cells, n_trials, limit
        self.arrays: dict[str, np.ndarray] | None = None
        self._done: np.ndarray | None = None
        self.n_done = 0

    @property
    def n_todo(self) -> int:
        """Trials not done yet."""
        return self.n_cells * self.n_trials - self.n_done

    def check(self, rec: ChunkRecord) -> None:
        """Refuse a chunk whose outputs differ in names or shapes from the first one's."""
        if self.arrays is None:
            return
        if set(rec.values) != set(self.arrays):
            raise InputError("trial outputs must have the same names in every cell and chunk; "
                             f"got {sorted(self.arrays)} vs {sorted(rec.values)}")
        for name, arr in rec.values.items():
            if arr.shape[1:] != self.arrays[name].shape[2:]:
                raise InputError(f"trial output {name!r} must have the same shape in every cell "
                                 f"and chunk; got {self.arrays[name].shape[2:]} vs "
                                 f"{arr.shape[1:]}")

    def _allocate(self, rec: ChunkRecord) -> None:
        per_trial = 1 + sum(a.dtype.itemsize * math.prod(a.shape[1:]) for a in rec.values.values())
        total = self.n_cells * self.n_trials
        if total * per_trial > self.limit:
            raise InputError(
                f"the results of this study need ~{total * per_trial / _GB:.3g} GB "
                f"({_num(self.n_cells)} cell(s) x {_num(self.n_trials)} trials x {per_trial} "
                f"bytes per trial); the limit is {self.limit / _GB:.3g} GB; {_RAISE}"
            )
        self._done = np.zeros((self.n_cells, self.n_trials), bool)
        self.arrays = {k: np.zeros((self.n_cells, self.n_trials) + v.shape[1:], v.dtype)
                       for k, v in rec.values.items()}

    def add(self, rec: ChunkRecord) -> None:
        """Place one chunk's results; a trial given twice must have the same results."""
        self.check(rec)
        if self.arrays is None:
            self._allocate(rec)
        trials = np.asarray(rec.trials)
        seen = self._done[rec.cell, trials]
        if seen.any():
            for name, arr in rec.values.items():
                if not np.array_equal(self.arrays[name][rec.cell, trials[seen]], arr[seen],
                                      equal_nan=True):
                    raise InputError(f"trial {trials[seen][0]} of cell {rec.cell} is recorded "
                                     f"twice with different results ({name!r})")
            warnings.warn(f"trials {_ranges(np.sort(trials[seen]))} of cell {rec.cell} are "
                          "recorded twice with the same results; one copy is used",
                          RuntimeWarning, stacklevel=3)
            trials, rec = trials[~seen], ChunkRecord(rec.cell, trials[~seen],
                                                      {k: v[~seen] for k, v in rec.values.items()})
        for name, arr in rec.values.items():
            full = self.arrays[name]
            if not np.can_cast(arr.dtype, full.dtype, "safe"):
                full = self.arrays[name] = full.astype(np.result_type(full, arr))
            full[rec.cell, trials] = arr
        self._done[rec.cell, trials] = True
        self.n_done += len(trials)

    def todo(self, size: int, workers: int = 1) -> Iterator[tuple[int, np.ndarray]]:
        """Chunks (cell, trial indices) of at most ``size`` trials not done, cell by cell.

        With ``workers`` > 1 the chunks shrink towards the end of the study (guided
        self-scheduling): a chunk holds at most ``ceil(R / (2 workers))`` of the
        ``R`` trials not yet handed out, and at least ``ceil(size / 8)``, so the
        workers finish within about a small chunk of each other instead of one
        waiting up to a whole chunk for the other.  Which trials run where never
        changes a trial's result.
        """
        left = self.n_todo  # not yet handed out
        floor = -(-size // 8)
        for cell in range(self.n_cells):
            idx = None if self._done is None else np.flatnonzero(~self._done[cell])
            count = self.n_trials if idx is None else len(idx)
            i = 0
            while i < count:
                n = size if workers <= 1 else min(size, max(floor, -(-left // (2 * workers))))
                n = min(n, count - i)
                yield cell, np.arange(i, i + n) if idx is None else idx[i:i + n]
                i, left = i + n, left - n

    def missing(self, label: Callable[[int], str], most: int = 4) -> str:
        """The trials not done, as ``"<cell label>: trials 3-7, 9; ..."``."""
        if self._done is None:
            return "all"
        parts = [f"{label(c)}: trials {_ranges(np.flatnonzero(~self._done[c]))}"
                 for c in range(self.n_cells) if not self._done[c].all()]
        more = f"; and {len(parts) - most} more cells" if len(parts) > most else ""
        return "; ".join(parts[:most]) + more
