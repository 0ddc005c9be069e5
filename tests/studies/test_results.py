"""The chunks a study hands out: every trial not done once, shrinking towards the end."""

import numpy as np
import pytest

from olsbayes.studies._frames import ChunkRecord
from olsbayes.studies.results import Results

N_CELLS, N_TRIALS, SIZE = 3, 997, 100
DONE = np.arange(10, 400)  # trials of cell 1 a checkpoint already holds


def _results(resumed: bool) -> Results:
    res = Results(N_CELLS, N_TRIALS, limit=10**9)
    if resumed:
        res.add(ChunkRecord(1, DONE, {"x": np.zeros(DONE.size)}))
    return res


@pytest.mark.parametrize("resumed", [False, True])
@pytest.mark.parametrize("workers", [1, 2, 5])
def test_todo_hands_out_each_trial_not_done_once_and_shrinks_at_the_end(workers, resumed):
    res = _results(resumed)
    chunks = list(res.todo(SIZE, workers))
    for cell in range(N_CELLS):
        got = np.concatenate([idx for c, idx in chunks if c == cell])
        want = np.arange(N_TRIALS)
        if resumed and cell == 1:
            want = np.setdiff1d(want, DONE)
        np.testing.assert_array_equal(got, want)  # each once, in order, cell by cell
    left, floor = res.n_todo, -(-SIZE // 8)
    for k, (cell, idx) in enumerate(chunks):
        cell_end = k + 1 == len(chunks) or chunks[k + 1][0] != cell
        if workers == 1:
            assert idx.size == SIZE or cell_end
        else:  # guided: at most ceil(left / (2 workers)), at least the floor
            assert idx.size <= max(floor, -(-left // (2 * workers)))
            assert idx.size >= floor or cell_end
        assert idx.size <= SIZE
        left -= idx.size
    if workers > 1:
        assert chunks[-2][1].size == floor < SIZE  # the last full chunks are small


def test_todo_of_one_worker_is_the_fixed_chunking():
    res = _results(False)
    sizes = [idx.size for _, idx in res.todo(SIZE)]
    assert sizes == ([SIZE] * 9 + [N_TRIALS - 9 * SIZE]) * N_CELLS
