"""Vectorised R-hat and ESS: ArviZ's values, parameter by parameter, to rounding."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from olsbayes._mcmc_diagnostics import ess_bulk, ess_tail, normal_scores, rank_rhat
from olsbayes.posterior._arviz import _known_shapes, import_arviz


def _arviz(x):
    az = import_arviz()
    with _known_shapes():
        ds = az.convert_to_dataset(x)
    with np.errstate(invalid="ignore", divide="ignore"):  # constant draws: 0 / 0 inside
        return [np.asarray(f(ds, method=m)["x"].values, dtype=float)
                for f, m in ((az.rhat, "rank"), (az.ess, "bulk"), (az.ess, "tail"))]


def _draws(rng, chains, draws):
    """AR(1) chains of 10 parameters, and the awkward kinds a sampler gives."""
    phi = np.linspace(-0.5, 0.99, 10)
    x = np.empty((chains, draws, 10))
    x[:, 0] = rng.standard_normal((chains, 10))
    for t in range(1, draws):
        x[:, t] = phi * x[:, t - 1] + rng.standard_normal((chains, 10))
    x[:, :, 0] = np.maximum(x[:, :, 0], 0.0)  # piled up on a wall: ties
    x[:, :, 1] = 3.0  # constant
    x[0, :, 2] = 1.0  # constant in one chain
    x[:, :, 3] = np.round(x[:, :, 3])  # few distinct values
    x[:, :, 4] += 2.0 * np.arange(chains)[:, None]  # chains apart
    x[:, :, 5] = x[:, :, 5] > 0  # a 0/1 indicator
    return x


@pytest.mark.parametrize("chains,draws", [(4, 338), (4, 100), (3, 267), (2, 7), (5, 4),
                                          (1, 150), (8, 33)])
def test_rhat_and_ess_are_arviz_values(chains, draws, caplog):
    """Every parameter, every shape (odd lengths drop the middle draw when split; one
    chain has no R-hat): the same NaNs, and the values to rounding -- the ESS sums its
    autocorrelations in another order."""
    x = _draws(np.random.default_rng(chains * 1000 + draws), chains, draws)
    with caplog.at_level(logging.CRITICAL, logger="arviz"):  # one chain: arviz logs why
        want = _arviz(x)
    for got, ref in zip((rank_rhat(x), ess_bulk(x), ess_tail(x)), want):
        assert np.array_equal(np.isnan(got), np.isnan(ref))
        ok = np.isfinite(ref)
        np.testing.assert_allclose(got[ok], ref[ok], rtol=1e-10)


def test_too_short_or_nan_draws_give_nan():
    x = np.random.default_rng(0).standard_normal((4, 3, 2))
    assert np.isnan(rank_rhat(x)).all() and np.isnan(ess_bulk(x)).all()
    assert np.isnan(ess_tail(x)).all()
    y = np.random.default_rng(1).standard_normal((4, 50, 3))
    y[2, 7, 1] = np.nan
    for f in (rank_rhat, ess_bulk, ess_tail):
        out = f(y)
        assert np.isnan(out[1]) and np.isfinite(out[[0, 2]]).all()


def test_normal_scores_share_ties():
    """Equal draws share their average rank: the scores of scipy's rankdata."""
    from scipy.stats import norm, rankdata

    x = np.random.default_rng(2).integers(0, 5, (3, 8, 2)).astype(float)
    z = normal_scores(x)
    for j in range(2):
        r = rankdata(x[:, :, j], method="average")
        np.testing.assert_array_equal(z[:, :, j].ravel(), norm.ppf((r - 0.375) / (r.size + 0.25)))
