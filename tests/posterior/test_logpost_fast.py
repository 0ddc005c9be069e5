"""The one-pass log posterior of the default problem equals the general path to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from olsbayes import Model, Ring, Sphere
from olsbayes.posterior._logpost import LogPosterior, cut_shift
from olsbayes.posterior._rhat import average_ranks, rank_rhat
from olsbayes.priors import default_priors


def _general(lp: LogPosterior, z: np.ndarray) -> np.ndarray:
    """:meth:`LogPosterior.__call__` through split() only (the general path)."""
    prior, like = lp.split(z)
    out = prior + like
    return np.where(np.isnan(out), -np.inf, out)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_flat_gaussian_path_equals_the_general_path(k):
    model = Model(Ring(30), 0.01)
    rng = np.random.default_rng(k)
    truth = np.stack([rng.uniform(-np.pi, np.pi, k), rng.uniform(0.3, 1.0, k)], 1).ravel()
    data = model.simulate(truth, rng=rng)
    prior = default_priors(model, k, data=data)
    x = truth + 0.05 * rng.standard_normal((16, truth.size))
    lp = LogPosterior(model, data, prior, cut_shift(prior, x))
    assert lp._flat
    z = lp.to_sampler(x)
    assert np.array_equal(lp(z), _general(lp, z))
    z[3, 1] = -1.0  # a negative intensity: outside the support
    z[5, 0] = np.nan
    out = lp(z)
    assert np.array_equal(out, _general(lp, z))
    assert out[3] == -np.inf and out[5] == -np.inf and np.isfinite(np.delete(out, [3, 5])).all()
    assert lp.n_calls == 2


def test_other_problems_keep_the_general_path():
    """Non-flat priors (sphere latitudes) and prior-only runs do not take the short path."""
    model = Model(Sphere.grid(6, 8), 0.01)
    truth = np.array([0.3, 0.2, 1.0])
    data = model.simulate(truth, rng=1)
    prior = default_priors(model, 1, data=data)
    assert not LogPosterior(model, data, prior, cut_shift(prior, None))._flat
    ring = Model(Ring(30), 0.01)
    ring_prior = default_priors(ring, 1, i_max=2.0)
    lp = LogPosterior(ring, ring.simulate(np.array([0.3, 1.0]), rng=1), ring_prior,
                      cut_shift(ring_prior, None), use_likelihood=False)
    assert not lp._flat


def test_rank_rhat_on_runs_of_repeated_draws_equals_ranking_every_draw():
    """Chains with rejected proposals (runs of equal draws): the same R-hat as direct ranks."""
    from scipy.special import ndtri

    rng = np.random.default_rng(3)
    for accept in (0.1, 0.3, 0.9):
        steps = rng.standard_normal((8, 400)) * (rng.random((8, 400)) < accept)
        x = np.round(steps.cumsum(axis=1), 2)
        half = x.shape[1] // 2

        def direct(split):
            rank = average_ranks(split.ravel())
            z = ndtri((rank - 0.375) / (rank.size + 0.25)).reshape(split.shape)
            n = z.shape[1]
            between = n * np.var(z.mean(axis=1), ddof=1)
            within = np.mean(np.var(z, axis=1, ddof=1))
            return float(np.sqrt((between / within + n - 1) / n))

        split = np.concatenate([x[:, :half], x[:, -half:]])
        expected = max(direct(split), direct(np.abs(split - np.median(split))))
        assert rank_rhat(x) == expected


def test_vector_sampler_gives_stock_emcee_chains():
    """The sampler's one-conversion log-probabilities leave emcee's chains as they were."""
    import emcee

    from olsbayes.posterior import SamplerOptions
    from olsbayes.posterior._run import make_sampler

    model = Model(Ring(30), 0.01)
    truth = np.array([0.3, 1.0, 2.4, 0.7])
    data = model.simulate(truth, rng=7)
    prior = default_priors(model, 2, data=data)
    x = truth + 1e-3 * np.random.default_rng(8).standard_normal((16, truth.size))
    lp = LogPosterior(model, data, prior, cut_shift(prior, x))
    z = lp.to_sampler(x)
    ours = make_sampler(lp, 16, SamplerOptions(), np.random.default_rng(9))
    stock = emcee.EnsembleSampler(16, z.shape[1], lp, vectorize=True,
                                  moves=emcee.moves.DEMove())
    stock.random_state = np.random.RandomState(
        int(np.random.default_rng(9).integers(2**32))).get_state()
    for sampler in (ours, stock):
        sampler.run_mcmc(z, 200, progress=False)
    assert type(ours) is not emcee.EnsembleSampler
    assert np.array_equal(ours.get_chain(), stock.get_chain())
    assert np.array_equal(ours.get_log_prob(), stock.get_log_prob())
    with pytest.raises(ValueError, match="infinite"):
        ours.compute_log_prob(np.full((16, z.shape[1]), np.inf))
