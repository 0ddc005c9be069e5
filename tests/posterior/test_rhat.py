"""The stopping rule's R-hat: ArviZ's rank-normalised split R-hat in plain numpy."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import rankdata

from olsbayes.posterior._arviz import rhat_array
from olsbayes.posterior._rhat import average_ranks, rank_rhat


def _emcee_like(rng, w, d):
    """Random-walk chains with offsets and repeated values (rejected proposals)."""
    x = np.cumsum(rng.standard_normal((w, d)), axis=1) * rng.uniform(0.01, 1.0)
    x += rng.standard_normal((w, 1)) * rng.uniform(0.0, 1.0)
    stay = rng.uniform(size=(w, d)) < 0.6
    for t in range(1, d):
        x[stay[:, t], t] = x[stay[:, t], t - 1]
    return x


@pytest.mark.parametrize("seed", range(6))
def test_rank_rhat_equals_arviz_with_ties(seed):
    rng = np.random.default_rng(seed)
    x = _emcee_like(rng, int(rng.integers(2, 40)), int(rng.integers(4, 1500)))
    assert np.array_equal(average_ranks(x.ravel()), rankdata(x.ravel()))
    assert rank_rhat(x) == pytest.approx(float(rhat_array(x[..., None])[0]), rel=1e-12)


def test_rank_rhat_is_nan_where_arviz_gives_no_value():
    x = np.random.default_rng(0).standard_normal((4, 100))
    assert np.isnan(rank_rhat(x[:1]))  # one chain
    assert np.isnan(rank_rhat(x[:, :3]))  # three draws
    x[2, 5] = np.nan
    assert np.isnan(rank_rhat(x))
