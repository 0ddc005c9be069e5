"""Exact reference posterior of ring sources (olsbayes.studies.sbc_exact) against brute-force
quadrature, and its own calibration."""

from __future__ import annotations

import numpy as np
import pytest

from olsbayes import InputError, Model, Ring
from olsbayes.studies.sbc_exact import exact_ring_posterior, sbc_exact, weighted_cdf

MODEL = Model(Ring(16), 0.05)
I_MAX = 2.0


def _grid_posterior(data, axes):
    """Posterior on a product grid of (theta_0, I_0[, theta_1, I_1]) by brute force."""
    g = [MODEL.response(np.stack([ax, np.ones_like(ax)], -1)) for ax in axes[::2]]
    mu = g[0][:, None, :] * axes[1][None, :, None]  # (n_theta, n_I, N)
    if len(axes) == 4:
        mu1 = g[1][:, None, :] * axes[3][None, :, None]
        mu = mu[:, :, None, None, :] + mu1[None, None]
    logp = -0.5 * np.sum((data - mu) ** 2, axis=-1) / MODEL.sigma**2
    p = np.exp(logp - logp.max())
    return p / p.sum()


def _marginal_cdf(p, axes, value):
    """Grid CDF at ``value``; exact for the midpoint rule when values are cell edges."""
    out = []
    for d, ax in enumerate(axes):
        marg = p.sum(axis=tuple(i for i in range(p.ndim) if i != d))
        out.append(marg[ax < value[d]].sum())
    return np.array(out)


def _edges(axes, frac):
    """A cell edge (midpoint between grid nodes) at about ``frac`` along each axis."""
    return np.array([0.5 * (ax[int(frac * len(ax))] + ax[int(frac * len(ax)) - 1]) for ax in axes])


def test_one_dim_source_matches_quadrature():
    # dim source: the intensity prior's edge at 0 matters, the direction is broad
    rng = np.random.default_rng(3)
    truth = np.array([0.7, 0.03])
    data = MODEL.simulate(truth, rng=rng)
    draws, w = exact_ring_posterior(MODEL, data, 1, I_MAX, rng=rng, n_grid=1024, per_cell=8)
    axes = [np.linspace(-np.pi, np.pi, 2000, endpoint=False), np.linspace(0.0005, 0.5995, 600)]
    p = _grid_posterior(data, axes)
    assert np.all((draws[w > 0, 1] >= 0) & (draws[w > 0, 1] <= I_MAX))
    probe = _edges(axes, 0.1)
    probe[0] = 0.5 * (axes[0][1500] + axes[0][1501])
    ess = 1 / np.sum(w * w)
    tol = 4 * np.sqrt(0.25 / ess) + 2e-3  # 4 MC sd + grid error
    np.testing.assert_allclose(weighted_cdf(draws, w, probe), _marginal_cdf(p, axes, probe),
                               atol=tol)


def test_two_sources_match_quadrature():
    # a close pair (0.6 rad): the Fisher volume sqrt(det) varies across the posterior
    rng = np.random.default_rng(1)
    truth = np.array([0.0, 1.0, 0.6, 0.8])
    data = MODEL.simulate(truth, rng=rng)
    draws, w = exact_ring_posterior(MODEL, data, 2, I_MAX, rng=rng, n_grid=512, per_cell=16)
    mean = w @ draws
    sd = np.sqrt(w @ (draws - mean) ** 2)
    assert np.all((draws[w > 0][:, 1::2] >= 0) & (draws[w > 0][:, 1::2] <= I_MAX))
    axes = [np.linspace(m - 6 * s, m + 6 * s, 36) for m, s in zip(mean, sd)]
    p = _grid_posterior(data, axes)
    probe = _edges(axes, 0.55)
    ess = 1 / np.sum(w * w)
    tol = 4 * np.sqrt(0.25 / ess) + 0.005  # 4 MC sd + midpoint-rule error of 36 nodes
    np.testing.assert_allclose(weighted_cdf(draws, w, probe), _marginal_cdf(p, axes, probe),
                               atol=tol)


def test_sbc_exact_is_calibrated():
    """CDF of the truth under the exact posterior is uniform: 90 % coverage within 3 se."""
    settings = {"n_sensors": 16, "sigma": 0.05, "n_sources": 2, "i_max": I_MAX, "n_grid": 192}
    seeds = np.random.SeedSequence(11).spawn(100)
    cdf = np.array([sbc_exact(settings, rng=np.random.default_rng(s))["cdf"] for s in seeds])
    cover = np.mean((cdf > 0.05) & (cdf < 0.95), axis=0)
    assert np.all(np.abs(cover - 0.9) < 3 * np.sqrt(0.09 / len(seeds))), cover


def test_bad_input():
    with pytest.raises(InputError, match="n_sources"):
        exact_ring_posterior(MODEL, np.zeros(16), 3, I_MAX)
