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


class _Chain:
    """A stand-in for emcee's sampler: a stored chain (steps, walkers, P)."""

    def __init__(self, chain):
        self.chain = chain

    def get_chain(self):
        return self.chain

    def get_log_prob(self):
        return -np.sum(self.chain**2, axis=-1)


def test_label_switches_are_relabelled_before_the_rhat_decision():
    """Walkers whose two sources swap for a stretch of steps fail on their raw draws
    and pass once relabelled: the thinned screen sees the switches."""
    import olsbayes as ob
    from olsbayes.posterior._logpost import LogPosterior
    from olsbayes.posterior._rhat import RhatCheck
    from olsbayes.priors import default_priors

    model = ob.Model(ob.Ring(30), sigma=0.01)
    prior = default_priors(model, 2, i_max=2.0)
    rng = np.random.default_rng(3)
    centre = np.array([0.5, 1.0, 2.5, 0.6])
    chain = centre + 0.01 * rng.standard_normal((2000, 32, 4))
    swapped = chain.copy()
    swapped[900:1500, :16] = chain[900:1500, :16][..., [2, 3, 0, 1]]
    logpost = LogPosterior(model, np.zeros(30), prior, np.zeros(4))
    plain = RhatCheck(_Chain(chain), logpost, 1.01)
    assert plain(5.0, 2000)
    check = RhatCheck(_Chain(swapped), logpost, 1.01)
    assert not check.below(logpost.to_params(swapped[25:].swapaxes(0, 1)))  # raw draws fail
    assert check(5.0, 2000)  # relabelled, they pass
