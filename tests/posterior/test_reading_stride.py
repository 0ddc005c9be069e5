"""A posterior's per-reading groups stay bounded: every s-th draw beyond READING_FLOATS."""

import math

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.posterior import _assemble
from olsbayes.posterior._arviz import from_netcdf, loo, to_netcdf
from olsbayes.posterior._assemble import READING_FLOATS, reading_stride
from olsbayes.posterior.sampler import _check_memory


def test_reading_stride_is_the_smallest_that_fits():
    for w in (8, 32, 64):
        for d in (1, 7, 1633, 5000):
            for n in (12, 1000, 30_000, 10**6, 2 * READING_FLOATS):
                s = reading_stride(w, d, n)
                kept = math.ceil(d / s)
                if w * n > READING_FLOATS:  # not even one draw fits: one per walker
                    assert kept == 1
                    continue
                assert w * kept * n <= READING_FLOATS
                assert s == 1 or w * math.ceil(d / (s - 1)) * n > READING_FLOATS


def test_memory_check_counts_the_bounded_groups_only():
    # 32 walkers x 5000 kept draws x 30,000 readings would be 38 GB per group
    _check_memory(32, 4, 30_000, 20_000)
    _check_memory(32, 4, 10**6, 20_000)
    with pytest.raises(ob.InputError, match="n_walkers=100000"):
        _check_memory(100_000, 4, 30, 20_000)  # the chain itself


@pytest.fixture(scope="module")
def runs():
    """One short run of a 12-ring with every draw in the per-reading groups, and one
    with room for 40 draws per walker there (the same seed).  The source sits 15 deg
    from the nearest horizons, so that no reading's log-likelihood is flat in most
    draws (ArviZ's Pareto fit then warns)."""
    model = ob.Model(ob.Ring(12), sigma=0.05)
    truth = np.array([np.pi / 12, 1.0])
    data = model.simulate(truth, rng=5)
    opts = ob.posterior.SamplerOptions(n_steps=400, n_walkers=16)

    def run():
        return ob.posterior.sample(model, data, 1, start=truth, options=opts, rng=1,
                                   progress=False)

    full = run()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(_assemble, "READING_FLOATS", 16 * 40 * 12)
        thinned = run()
    return model, full, thinned


def test_thinned_groups_hold_every_sth_draw_with_the_posteriors_labels(runs, tmp_path):
    model, full, thinned = runs
    post = thinned.idata.posterior
    d = post.sizes["draw"]
    s = thinned.idata.attrs["reading_stride"]
    assert full.idata.attrs["reading_stride"] == 1 and s == math.ceil(d / 40) > 1
    assert all(getattr(thinned.idata, g).attrs["reading_stride"] == s
               for g in thinned.idata.groups())
    # the posterior itself does not change
    assert full.idata.posterior.equals(post)
    labels = post["draw"].values[::s]
    for group in ("posterior_predictive", "log_likelihood"):
        obs = getattr(thinned.idata, group)["obs"]
        assert obs.dims == ("chain", "draw", "sensor") and obs.shape == (16, labels.size, 12)
        assert np.array_equal(obs["draw"].values, labels)
    # each kept row is the log-likelihood of the posterior's draw of that label
    ll = thinned.idata.log_likelihood["obs"].values.sum(-1)
    stats = thinned.idata.sample_stats.sel(draw=labels)
    np.testing.assert_allclose(ll, stats["lp"].values - stats["log_prior"].values, rtol=1e-10)
    np.testing.assert_array_equal(thinned.idata.log_likelihood["obs"].values,
                                  full.idata.log_likelihood["obs"].sel(draw=labels).values)
    back = from_netcdf(to_netcdf(thinned.idata, tmp_path / "thinned.nc"))
    assert np.array_equal(back.posterior_predictive["draw"].values, labels)
    assert back.attrs["reading_stride"] == s


def test_loo_and_the_model_check_read_the_thinned_groups(runs):
    import arviz as az

    _, full, thinned = runs
    labels = thinned.idata.log_likelihood["draw"].values
    # the LOO of the full run's draws of the same labels: the posterior's relative ESS
    # taken at those draws too
    same = az.InferenceData(posterior=full.idata.posterior.sel(draw=labels),
                            log_likelihood=full.idata.log_likelihood.sel(draw=labels))
    a, b = loo(same), loo(thinned.idata)
    assert b["n_samples"] == 16 * labels.size
    assert b["elpd_loo"] == pytest.approx(a["elpd_loo"], rel=1e-12, abs=1e-12)
    assert b["p_loo"] == pytest.approx(a["p_loo"], rel=1e-12, abs=1e-12)
    check = thinned.model_check()
    assert check.n_draws == 16 * labels.size and 0.0 <= check.ppp <= 1.0
