"""Imaging: Gibbs along the precision's eigenvectors vs 2-D numerical integration."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate

import olsbayes as ob
from olsbayes.imaging import ImageOptions, design_matrix, image
from olsbayes.imaging.eigen import eigen_gibbs


def _batch_se(draws: np.ndarray, n_batches: int = 20) -> np.ndarray:
    """Monte Carlo standard error of the mean by batch means; draws (S, ...)."""
    s = draws.shape[0] - draws.shape[0] % n_batches
    means = draws[:s].reshape((n_batches, -1) + draws.shape[1:]).mean(axis=1)
    return means.std(axis=0, ddof=1) / np.sqrt(n_batches)


def _box_moments_2d(q, b, lo, hi):
    """Mean and second central moments of exp(-x'Qx/2 + b'x) on a 2-D box by quadrature."""
    def dens(x2, x1):
        x = np.array([x1, x2])
        return np.exp(-0.5 * x @ q @ x + b @ x)
    opts = dict(epsabs=1e-12, epsrel=1e-10)

    def mom(f):
        return integrate.dblquad(lambda u, v: f(v, u) * dens(u, v), lo[0], hi[0], lo[1], hi[1],
                                 **opts)[0]
    z = mom(lambda x1, x2: 1.0)
    mean = np.array([mom(lambda x1, x2: x1), mom(lambda x1, x2: x2)]) / z
    var = np.array([mom(lambda x1, x2: (x1 - mean[0]) ** 2),
                    mom(lambda x1, x2: (x2 - mean[1]) ** 2)]) / z
    return mean, var


@pytest.mark.parametrize("case", ["correlated", "singular", "singular-coordinate-off"])
def test_eigen_gibbs_matches_2d_quadrature(case):
    if case == "correlated":  # strongly correlated, mean outside the box
        q = np.linalg.inv(np.array([[0.25, 0.2], [0.2, 0.25]]))
        b = q @ np.array([1.2, -0.3])
    else:  # rank-1 precision: the difference x1 - x2 is set by the box alone
        v = np.array([1.0, 1.0])
        q, b = 8.0 * np.outer(v, v), 8.0 * 0.9 * v
    lo, hi = np.zeros(2), np.ones(2)
    mean, var = _box_moments_2d(q, b, lo, hi)
    run = eigen_gibbs(q, b, lo, hi, np.full((8, 2), 0.5), 1500, rng=np.random.default_rng(17),
                      n_burn=20, coordinate=case != "singular-coordinate-off")
    x = np.moveaxis(run.samples, 1, 0)  # (S, C, 2)
    assert np.all((x >= 0) & (x <= 1))
    se = _batch_se(x.mean(axis=1))
    np.testing.assert_array_less(np.abs(x.reshape(-1, 2).mean(axis=0) - mean), 5 * se)
    se2 = _batch_se(((x - mean) ** 2).mean(axis=1))
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
    assert abs(x.mean() - ref.mean()) < 5 * _batch_se(x.mean(axis=1))


def test_image_with_the_eigen_sampler(ring_problem_eigen):
    model, dirs, y = ring_problem_eigen
    res = image(model, y, dirs, "bounded", rng=4,
                options=ImageOptions(sampler="eigen", n_samples=300, n_burn=20))
    ref = image(model, y, dirs, "bounded", rng=5,
                options=ImageOptions(sampler="hmc", n_samples=300, n_burn=20))
    assert res.sampler == "eigen" and res.samples.shape == (4, 300, 2) and res.rhat < 1.05
    # both means are Monte Carlo estimates: 5 sd of their difference, by batch means
    # over the pooled (draws, chains) of each run (autocorrelation included)
    se = np.hypot(*(_batch_se(np.moveaxis(r.samples, 1, 0).reshape(-1, 2)) for r in (res, ref)))
    np.testing.assert_array_less(np.abs(res.mean - ref.mean), 5 * se)


@pytest.fixture
def ring_problem_eigen():
    model = ob.Model(ob.Ring(8), sigma=0.3)
    dirs = np.array([0.3, 2.0])
    a = design_matrix(model, dirs)
    y = a @ np.array([0.6, 0.2]) + model.sigma * np.random.default_rng(3).standard_normal(8)
    return model, dirs, y
