"""Imaging: block-Gibbs sampler of the two-level posterior vs exact enumeration."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from reference.moments import batch_se

import olsbayes as ob
from olsbayes.imaging.binary import two_level_log_posterior
from olsbayes.imaging.binary_gibbs import credible_sets, two_level_gibbs


def _problem(k=7, n=5, seed=2):
    rng = np.random.default_rng(seed)
    a = np.abs(rng.normal(size=(n, k)))  # fewer readings than sources: ambiguous
    truth = (rng.random(k) < 0.5).astype(float)
    sigma = 1.5  # every bit uncertain: P(bright) in [0.01, 0.41] (exact)
    return a, a @ truth + sigma * rng.standard_normal(n), sigma


def _exact_p_bright(a, y, sigma, i_max, p):
    k = a.shape[1]
    states = np.array(list(itertools.product([0.0, 1.0], repeat=k)))
    lp = np.array([two_level_log_posterior(a, y, sigma, i_max * s, i_max, p) for s in states])
    w = np.exp(lp - lp.max())
    return (w / w.sum()) @ states, lp.max()


@pytest.mark.parametrize("width,p", [(1, 0.5), (3, 0.3)])
def test_block_gibbs_matches_enumeration(width, p):
    a, y, sigma = _problem()
    k, i_max = a.shape[1], 1.5
    groups = np.array([np.arange(j, j + width) % k for j in range(k)])
    exact, lp_max = _exact_p_bright(a, y, sigma, i_max, p)
    run = two_level_gibbs(a, y, sigma, i_max, np.zeros((8, k), dtype=bool), groups, 3000,
                          rng=np.random.default_rng(6), p_bright=p, n_burn=20)
    x = np.moveaxis(run.bits, 1, 0).astype(float)  # (S, C, K)
    se = batch_se(x.mean(axis=1))
    np.testing.assert_array_less(np.abs(run.p_bright - exact), 5 * se + 1e-12)
    assert run.best_log_posterior == pytest.approx(lp_max, abs=1e-9)  # 128 states: all visited
    lp = two_level_log_posterior(a, y, sigma, i_max * run.bits[2, -1], i_max, p)
    assert run.log_posterior[2, -1] == pytest.approx(lp, abs=1e-9)


def test_credible_sets_of_bits():
    dark, bright = credible_sets(np.array([0.02, 0.5, 0.95, 0.85]), 0.9)
    np.testing.assert_array_equal(dark, [True, True, False, True])
    np.testing.assert_array_equal(bright, [False, True, True, True])


def test_window_width_is_checked():
    a, y, sigma = _problem()
    with pytest.raises(ob.InputError, match="groups"):
        two_level_gibbs(a, y, sigma, 1.0, np.zeros((1, 7), dtype=bool),
                        np.zeros((1, 13), dtype=int), 4, rng=np.random.default_rng(0))
