"""Imaging: Gibbs along the precision's eigenvectors vs 2-D numerical integration."""

from __future__ import annotations

import numpy as np
import pytest
from reference.moments import batch_se, box_moments_2d

import olsbayes as ob
from olsbayes.imaging import ImageOptions
from olsbayes.imaging.eigen import eigen_gibbs


@pytest.mark.parametrize("case", ["correlated", "singular", "singular-coordinate-off"])
def test_eigen_gibbs_matches_2d_quadrature(case):
    if case == "correlated":  # strongly correlated, mean outside the box
        q = np.linalg.inv(np.array([[0.25, 0.2], [0.2, 0.25]]))
        b = q @ np.array([1.2, -0.3])
    else:  # rank-1 precision: the difference x1 - x2 is set by the box alone
        v = np.array([1.0, 1.0])
        q, b = 8.0 * np.outer(v, v), 8.0 * 0.9 * v
    lo, hi = np.zeros(2), np.ones(2)
    mean, cov = box_moments_2d(q, b, lo, hi)
    var = np.diag(cov)
    run = eigen_gibbs(q, b, lo, hi, np.full((8, 2), 0.5), 1500, rng=np.random.default_rng(17),
                      n_burn=20, coordinate=case != "singular-coordinate-off")
    x = np.moveaxis(run.samples, 1, 0)  # (S, C, 2)
    assert np.all((x >= 0) & (x <= 1))
    se = batch_se(x.mean(axis=1))
    np.testing.assert_array_less(np.abs(x.reshape(-1, 2).mean(axis=0) - mean), 5 * se)
    se2 = batch_se(((x - mean) ** 2).mean(axis=1))
    d2 = ((x - mean) ** 2).reshape(-1, 2).mean(axis=0)
    np.testing.assert_array_less(np.abs(d2 - var), 5 * se2)


def test_eigen_gibbs_nonnegative_1d_half_line():
    # one coordinate, flat prior on x >= 0: a half-normal-like truncation at 0
    m, s = -0.2, 0.5
    run = eigen_gibbs(np.array([[1 / s**2]]), np.array([m / s**2]), np.zeros(1),
                      np.full(1, np.inf), np.full((4, 1), 0.3), 3000, rng=np.random.default_rng(3),
                      n_burn=10)
    from scipy import stats

    ref = stats.truncnorm(-m / s, np.inf, m, s)
    x = np.moveaxis(run.samples[..., 0], 1, 0)
    assert abs(x.mean() - ref.mean()) < 5 * batch_se(x.mean(axis=1))


def test_the_eigen_sampler_is_not_offered():
    """Withdrawn from ImageOptions: it mixed worse than Gibbs on every scene measured."""
    with pytest.raises(ob.InputError, match="sampler 'eigen' is not offered: .*R-hat"):
        ImageOptions(sampler="eigen")
