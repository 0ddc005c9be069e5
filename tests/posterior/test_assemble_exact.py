"""The fast paths behind a posterior result give the numbers of their plain definitions."""

import numpy as np
import pytest

from olsbayes.circular import TWO_PI, wrap_angle
from olsbayes.exchange import best_permutation, pair_costs
from olsbayes.posterior import _labels


def _bits(a) -> np.ndarray:
    return np.asarray(a, dtype=float).view(np.int64)


def test_wrap_angle_is_the_floored_modulus_bit_for_bit():
    rng = np.random.default_rng(3)
    edges = np.pi + np.arange(-40, 41)[:, None] * TWO_PI + np.array([-1e-15, 0.0, 1e-15])
    x = np.concatenate([
        rng.uniform(-4, 4, 20000), rng.uniform(-1e3, 1e3, 20000), rng.normal(0, 1e-9, 2000),
        edges.ravel(), np.nextafter(edges, np.inf).ravel(), np.nextafter(edges, -np.inf).ravel(),
        [0.0, -0.0, np.pi, -np.pi, 1e300, -1e300, 5e-324, -5e-324, np.inf, -np.inf, np.nan]])
    with np.errstate(invalid="ignore"):
        plain = np.pi - np.mod(np.pi - x, TWO_PI)
        fast = wrap_angle(x)
        strided = wrap_angle(x.reshape(-1, 1)[::3, 0])
    assert np.array_equal(_bits(fast), _bits(plain))
    assert np.array_equal(_bits(strided), _bits(plain[::3]))
    assert np.array_equal(_bits(wrap_angle(x[:7].reshape(7, 1))), _bits(plain[:7].reshape(7, 1)))
    assert wrap_angle(3 * np.pi) == np.pi - np.mod(np.pi - 3 * np.pi, TWO_PI)
    assert np.ndim(wrap_angle(0.5)) == 0
    source = x[:100].copy()
    wrap_angle(source)
    assert np.array_equal(_bits(source), _bits(x[:100]), equal_nan=False)  # input untouched


@pytest.mark.parametrize("k", [2, 3])
def test_relabel_in_blocks_of_draws_matches_one_block(monkeypatch, k):
    rng = np.random.default_rng(k)
    n, w = 3000, 2
    centre = np.stack([np.linspace(-3, 3, k, endpoint=False), np.linspace(1, 2, k)], axis=1)
    blocks = centre + rng.normal(0, 0.6, (n, k, w))
    blocks = blocks[np.arange(n)[:, None], rng.permuted(np.tile(np.arange(k), (n, 1)), axis=1)]
    x = blocks.reshape(n // 30, 30, k * w)
    periodic = np.array([True, False])
    scale = rng.uniform(0.5, 2.0, (k, w))
    whole = best_permutation(pair_costs(blocks, centre, periodic, scale))
    monkeypatch.setattr(_labels, "_CHUNK", 37)
    assert np.array_equal(_labels._nearest(blocks, centre, periodic, scale), whole)
    small, perms_small = _labels.relabel(x, k, periodic, anchor=centre.ravel())
    monkeypatch.setattr(_labels, "_CHUNK", 10**9)
    big, perms_big = _labels.relabel(x, k, periodic, anchor=centre.ravel())
    assert np.array_equal(perms_small, perms_big)
    assert np.array_equal(_bits(small), _bits(big))
    assert np.array_equal(_labels._permuted(blocks, whole),
                          np.take_along_axis(blocks, whole[:, :, None], axis=1))


@pytest.mark.parametrize("k", [1, 2, 3])
def test_rhat_columns_on_demand_are_the_unwrapped_draws(k):
    import olsbayes as ob
    from olsbayes.circular import circular_mean, unwrap_around
    from olsbayes.posterior._rhat import _unwrapped_columns
    from olsbayes.priors import default_priors

    prior = default_priors(ob.Model(ob.Ring(30), sigma=0.01), k, i_max=2.0)
    rng = np.random.default_rng(k)
    for x in (rng.uniform(-np.pi, np.pi, (16, 300, 2 * k)),
              np.pi - np.abs(rng.normal(0, 0.3, (32, 200, 2 * k)))):  # around +-pi
        per = prior.periodic
        centre = np.zeros(per.size)
        centre[per] = circular_mean(x[..., per].reshape(-1, int(per.sum())), axis=0)
        whole, column = unwrap_around(x, centre, per), _unwrapped_columns(x, prior)
        for j in range(2 * k):
            assert np.array_equal(_bits(np.ascontiguousarray(column(j))),
                                  _bits(np.ascontiguousarray(whole[..., j])))


def _absorb_lag_by_lag(self, chain, start, stop):
    """The lag sums' plain definition: one product sum per lag."""
    from olsbayes._one import sum_products

    n_lag = self._lags.shape[0]
    lo = max(0, start - n_lag + 1)
    y = chain[lo:stop] - self._ref
    for lag in range(min(n_lag, stop)):
        first = max(start, lag) - lo
        if first < stop - lo:
            self._lags[lag] += sum_products("t...,t...->...", y[first - lag:stop - lo - lag],
                                            y[first:])


@pytest.mark.parametrize("walkers, n_params", [(32, 6), (8, 3), (16, 2)])
def test_autocorr_lag_sums_in_one_call_match_lag_by_lag(walkers, n_params):
    from olsbayes.posterior._run import AutocorrTime

    class LagByLag(AutocorrTime):
        _absorb = _absorb_lag_by_lag

    rng = np.random.default_rng(walkers)
    step = rng.normal(0, 0.05, (900, walkers, n_params))
    step[rng.uniform(size=(900, walkers)) < 0.6] = 0.0  # rejected proposals
    chain = np.cumsum(step, axis=0) + rng.normal(size=(walkers, n_params))
    fast, plain = AutocorrTime(chain[0], max_lag=8), LagByLag(chain[0], max_lag=8)
    for it in range(50, 901, 50):
        assert np.array_equal(_bits(fast.update(chain[:it])), _bits(plain.update(chain[:it])))
        assert np.array_equal(_bits(fast._lags), _bits(plain._lags))


def test_the_pointwise_likelihood_is_made_on_first_access_with_the_same_numbers(
        monkeypatch, tmp_path):
    import pickle

    import olsbayes as ob
    from olsbayes.posterior import _lazy
    from olsbayes.posterior._arviz import from_netcdf, to_netcdf

    model = ob.Model(ob.Ring(12), sigma=0.05)
    data = model.simulate(np.array([0.4, 1.0]), rng=5)
    opts = ob.posterior.SamplerOptions(n_steps=200, n_walkers=16)
    lazy = ob.posterior.sample(model, data, 1, start=np.array([0.4, 1.0]), options=opts,
                               rng=1, progress=False).idata

    class Eager:  # the values at once, as a plain array
        def __new__(cls, make, shape):
            return make()

    monkeypatch.setattr(_lazy, "Deferred", Eager)
    eager = ob.posterior.sample(model, data, 1, start=np.array([0.4, 1.0]), options=opts,
                                rng=1, progress=False).idata
    monkeypatch.undo()
    backend = lazy.log_likelihood["obs"].variable._data.array
    assert isinstance(backend, _lazy.DeferredArray) and backend.deferred._values is None
    ll, ref = lazy.log_likelihood, eager.log_likelihood
    assert ll["obs"].dims == ref["obs"].dims and ll["obs"].attrs == ref["obs"].attrs
    assert {k: v for k, v in ll.attrs.items() if not k.startswith("created")} == {
        k: v for k, v in ref.attrs.items() if not k.startswith("created")}
    assert all(ll[c].equals(ref[c]) for c in ref.coords)
    assert np.array_equal(_bits(ll["obs"].isel(sensor=[2, 5]).values),
                          _bits(ref["obs"].isel(sensor=[2, 5]).values))
    assert np.array_equal(_bits(ll["obs"].values), _bits(ref["obs"].values))
    again = pickle.loads(pickle.dumps(lazy))
    assert np.array_equal(_bits(again.log_likelihood["obs"].values), _bits(ref["obs"].values))
    back = from_netcdf(to_netcdf(lazy, tmp_path / "post.nc"))
    assert np.array_equal(_bits(back.log_likelihood["obs"].values), _bits(ref["obs"].values))


@pytest.mark.parametrize("inferred", [False, True])
def test_predictive_replicas_block_by_block_are_the_plain_expression(inferred):
    import olsbayes as ob
    from olsbayes.posterior._assemble import predictive_draws
    from olsbayes.priors import default_priors

    model = ob.Model(ob.Ring(30), sigma=0.01)
    prior = default_priors(model, 2, i_max=2.0, infer_sigma=inferred)
    rng = np.random.default_rng(2)
    x = np.concatenate([rng.uniform(-3, 3, (3, 700, 4)),
                        rng.uniform(0.005, 0.02, (3, 700, 1))], axis=-1)[..., :prior.n_params]
    mu = model.response(x[..., :4])
    sd = x[..., -1:] if inferred else model.sigma
    plain = mu + sd * np.random.default_rng(9).standard_normal(mu.shape)
    fast = predictive_draws(model, prior, x, np.random.default_rng(9), mu.copy())
    assert np.array_equal(_bits(fast), _bits(plain))
    assert np.array_equal(_bits(predictive_draws(model, prior, x, np.random.default_rng(9))),
                          _bits(plain))
