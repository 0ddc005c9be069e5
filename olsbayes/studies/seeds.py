"""Per-trial random streams that do not depend on how the work is split.

Trial ``t`` of grid cell ``c`` draws from the Generator of
``SeedSequence(entropy, spawn_key=(c, t))`` -- exactly the child that
``SeedSequence(entropy).spawn(n_cells)[c].spawn(n_trials)[t]`` would give -- so
its numbers are the same on any executor, with any number of workers and any
chunking, and a resumed study continues each trial's own stream.
"""

from __future__ import annotations

import numbers

import numpy as np

from .._validation import _short
from ..errors import InputError

__all__ = ["study_entropy", "trial_seed", "trial_rngs"]

#: Bits of entropy drawn for a fresh study (rng=None) or from a user Generator.
ENTROPY_BITS = 128


def study_entropy(rng: object) -> int:
    """The root entropy (a non-negative int) of a study.

    Parameters
    ----------
    rng : int, SeedSequence, Generator or None
        An integer seed is used as is; a SeedSequence contributes its entropy (it
        must not be a spawned child); a Generator has 128 bits drawn from it; None
        draws fresh entropy from the operating system.
    """
    if isinstance(rng, bool):
        raise InputError(f"rng must be a non-negative integer seed, a SeedSequence, "
                         f"a numpy Generator or None; got {rng!r}")
    if isinstance(rng, numbers.Integral):
        if int(rng) < 0:
            raise InputError(f"rng seed must be >= 0; got {int(rng)}")
        return int(rng)
    if isinstance(rng, np.random.SeedSequence):
        if rng.spawn_key:
            raise InputError(
                f"rng must be a root SeedSequence (empty spawn_key); got spawn_key {rng.spawn_key}"
            )
        ent = rng.entropy
        if not isinstance(ent, numbers.Integral):
            raise InputError("rng SeedSequence must have integer entropy; got a sequence")
        return int(ent)
    if isinstance(rng, np.random.Generator):
        words = rng.integers(0, 2**32, size=ENTROPY_BITS // 32, dtype=np.uint64)
        return int(sum(int(w) << (32 * i) for i, w in enumerate(words)))
    if rng is None:
        return int(np.random.SeedSequence().entropy)
    raise InputError(
        "rng must be a non-negative integer seed, a SeedSequence, a numpy Generator "
        f"or None; got {_short(rng)}"
    )


def trial_seed(entropy: int, cell: int, trial: int) -> np.random.SeedSequence:
    """The SeedSequence of trial ``trial`` in grid cell ``cell``."""
    return np.random.SeedSequence(entropy, spawn_key=(int(cell), int(trial)))


def trial_rngs(entropy: int, cell: int, trials: np.ndarray) -> list[np.random.Generator]:
    """One independent Generator per trial index in ``trials`` (same order)."""
    return [np.random.default_rng(trial_seed(entropy, cell, t)) for t in trials]
