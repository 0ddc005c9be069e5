"""Checkpoints of a long emcee run: the chain so far and the ensemble's random state, on disk.

A run given ``checkpoint=PATH`` writes an ``.npz`` file every
:data:`SAVE_EVERY` seconds, when it stops (converged or at its step limit) and
when it is interrupted: the chain, the log-posterior values and acceptance counts,
the random state of the ensemble as of the last step written, the run's seed and a
key naming the problem (readings, model, prior, number of walkers and the
moves).  The same call again continues from the last step written, with the same
random stream and the same convergence checks (replayed on the chain read back),
so its draws equal those of a run never interrupted; only the wall time and the
count of evaluations cover the last process alone.  The stopping settings may
differ (e.g. a larger ``max_steps`` continues a run that stopped at its limit); a
file of another problem (readings, model, prior, walkers, moves) is refused.
The file holds numbers only and is read with ``allow_pickle=False``.

emcee's own ``HDFBackend`` writes every step to its file (a file open per step,
which costs more than a step of these posteriors); the chain here lives in
memory and reaches the disk every :data:`SAVE_EVERY` seconds.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import time
from pathlib import Path

import numpy as np

from .._io import atomic_path, write_target
from .._provenance import data_sha256
from ..errors import InputError

__all__ = ["ChainCheckpoint", "SAVE_EVERY"]

#: Seconds between two writes of a checkpoint during a run.
SAVE_EVERY = 60.0
#: Format tag stored in the file.
FORMAT = "olsbayes-emcee-checkpoint-1"


def problem_key(model: object, data: np.ndarray, prior: object, n_walkers: int,
                options: object) -> str:
    """SHA-256 naming what a chain depends on: readings, model, prior, walkers, moves.

    Not the seed (stored beside it) nor the stopping and post-processing settings:
    a stored chain may be continued with another step limit or stopping rule.
    """
    moves = options.moves
    if not isinstance(moves, str):  # emcee Move objects: their classes and weights
        items = moves if isinstance(moves, (list, tuple)) else [moves]
        moves = [repr([type(m[0] if isinstance(m, tuple) else m).__name__,
                       m[1] if isinstance(m, tuple) else 1.0]) for m in items]
    text = json.dumps([repr(model), data_sha256(data), repr(prior), int(n_walkers),
                       moves, bool(options.use_likelihood)])
    return hashlib.sha256(text.encode()).hexdigest()


class ChainCheckpoint:
    """The checkpoint file of one emcee run (see the module notes).

    Parameters
    ----------
    path : path
        The ``.npz`` file (created with its folder; a folder, FIFO or device is refused).
    key : str
        :func:`problem_key` of the run.
    """

    def __init__(self, path: str | os.PathLike, key: str):
        self.path = Path(path)
        write_target(self.path, "checkpoint")
        self.key = key
        self._saved_at = time.monotonic()
        self._state: tuple | None = None  # (iteration, random state, accepted) at the last step
        self._stored = self._read()

    def _read(self) -> dict | None:
        if not self.path.exists():
            return None
        try:
            with np.load(self.path, allow_pickle=False) as f:
                stored = {name: f[name] for name in f.files}
        except (OSError, ValueError) as exc:
            raise InputError(f"checkpoint {str(self.path)!r} is not an olsbayes posterior "
                             f"checkpoint: {exc}") from None
        if str(stored.get("format", "")) != FORMAT:
            raise InputError(f"checkpoint {str(self.path)!r} is not an olsbayes posterior "
                             "checkpoint")
        if str(stored["key"]) != self.key:
            raise InputError(
                f"checkpoint {str(self.path)!r} belongs to another run (other readings, "
                "model, prior, walkers or moves): delete it or give another path")
        return stored

    @property
    def seed(self) -> int | None:
        """The seed recorded in the file (None: no file yet, or a run seeded by a Generator)."""
        if self._stored is None or int(self._stored["seed"]) < 0:
            return None
        return int(self._stored["seed"])

    def check_seed(self, seed: int | None) -> None:
        """Refuse a file written with another seed than ``seed`` (None: any)."""
        if self.seed is not None and seed is not None and seed != self.seed:
            raise InputError(f"checkpoint {str(self.path)!r} was written with seed "
                             f"{self.seed}, not {seed}: give rng={self.seed} (or None) to "
                             "resume it, or delete it")

    def restore(self, sampler) -> int:
        """Load the stored steps into ``sampler``'s (empty) backend; the number of steps."""
        if self._stored is None:
            return 0
        from emcee.state import State

        chain, log_prob = self._stored["chain"], self._stored["log_prob"]
        n = chain.shape[0]
        if chain.shape[1:] != (sampler.nwalkers, sampler.ndim):
            raise InputError(f"checkpoint {str(self.path)!r} holds {chain.shape[1]} walkers x "
                             f"{chain.shape[2]} parameters; this run has {sampler.nwalkers} x "
                             f"{sampler.ndim}")
        state = _random_state(self._stored)
        backend = sampler.backend
        backend.reset(sampler.nwalkers, sampler.ndim)
        backend.grow(n, None)
        zero = np.zeros(sampler.nwalkers, dtype=bool)
        for i in range(n):  # the public API; the acceptance totals ride on the first step
            accepted = self._stored["accepted"] if i == 0 else zero
            backend.save_step(State(chain[i], log_prob=log_prob[i], random_state=state),
                              accepted)
        self._state = (n, state, np.array(self._stored["accepted"]))
        return n

    def seen(self, sampler, seed: int | None) -> None:
        """Record the state after a step; :meth:`write` when :data:`SAVE_EVERY` has passed."""
        self._state = (sampler.iteration, sampler.random_state,
                       np.array(sampler.backend.accepted))
        if time.monotonic() - self._saved_at >= SAVE_EVERY:
            self.write(sampler, seed)

    def write(self, sampler, seed: int | None) -> None:
        """Write the steps up to the last one recorded by :meth:`seen` (atomically)."""
        if self._state is None:
            return
        n, state, accepted = self._state
        name, keys, pos, has_gauss, cached = state
        arrays = {
            "format": np.array(FORMAT), "key": np.array(self.key),
            "seed": np.array(-1 if seed is None else seed, dtype=np.int64),
            "chain": sampler.get_chain()[:n], "log_prob": sampler.get_log_prob()[:n],
            "accepted": accepted,
            "rs_name": np.array(name), "rs_keys": np.asarray(keys, dtype=np.uint32),
            "rs_pos": np.array(pos, dtype=np.int64),
            "rs_has_gauss": np.array(has_gauss, dtype=np.int64),
            "rs_cached": np.array(cached, dtype=float),
        }
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        with atomic_path(self.path) as tmp:
            tmp.write_bytes(buf.getvalue())
        self._saved_at = time.monotonic()


def _random_state(stored: dict) -> tuple:
    """The ``numpy.random.RandomState`` state tuple stored in a checkpoint."""
    return (str(stored["rs_name"]), np.asarray(stored["rs_keys"], dtype=np.uint32),
            int(stored["rs_pos"]), int(stored["rs_has_gauss"]), float(stored["rs_cached"]))
