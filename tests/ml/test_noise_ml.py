"""ML fits under other noise models, nuisance terms and repeated frames.

Efficiencies are CRLB^2 / mean squared error over T trials; their sampling sd is
about sqrt(2 / T), so "efficiency >= 0.95" is checked as an estimate above
0.95 - 3 sqrt(2 / T).
"""

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.noise import GaussianPerSensor, GaussianUnknown, Poisson


def _efficiency(model, x, fits):
    bound = ob.crlb(model, model.unpack(x)).std
    err = np.asarray(fits.params) - x
    err[:, 0] = ob.wrap_angle(err[:, 0])
    return bound**2 / np.mean(err**2, axis=0)


def test_poisson_ml_is_efficient_at_100_counts_ring():
    """Poisson ML on a ring, >= 100 expected counts on every sub-sensor: efficiency >= 0.95."""
    t = 2000
    model = ob.Model(ob.Ring(30), noise=Poisson(exposure=10.0, dark=10.0))
    x = np.array([2 * np.pi / 30, 20.0])  # a source between horizons (no kink within 20 sd)
    counts = model.simulate(x, rng=11, size=t)
    assert counts.mean(axis=0).min() >= 90
    fits = ob.fit_ml(model, counts, 1)
    eff = _efficiency(model, x, fits)
    assert np.all(eff > 0.95 - 3 * np.sqrt(2 / t)), eff
    assert np.all(fits.converged)


def test_poisson_ml_is_efficient_on_a_sphere():
    """The same on a Fibonacci sphere: longitude, latitude and intensity."""
    t = 600
    model = ob.Model(ob.Sphere.fibonacci(40), noise=Poisson(exposure=5.0, dark=20.0))
    x = np.array([0.4, 0.3, 30.0])
    counts = model.simulate(x, rng=12, size=t)
    fits = ob.fit_ml(model, counts, 1)
    eff = _efficiency(model, x, fits)
    assert np.all(eff > 0.95 - 3 * np.sqrt(2 / t)), eff


def test_poisson_ml_beats_the_gaussian_model_on_counts():
    """At low counts the Poisson fit has a smaller error than a Gaussian fit of the same counts."""
    t = 1500
    model = ob.Model(ob.Ring(24), noise=Poisson(exposure=1.0, dark=0.2))
    x = np.array([np.pi / 24, 15.0])  # midway between two horizons
    counts = model.simulate(x, rng=13, size=t)
    pois = ob.fit_ml(model, counts, 1)
    gauss = ob.fit_ml(ob.Model(ob.Ring(24), float(np.sqrt(counts.mean()))), counts, 1,
                      warn=False)
    mse_p = np.mean(ob.wrap_angle(pois.params[:, 0] - x[0]) ** 2)
    mse_g = np.mean(ob.wrap_angle(gauss.params[:, 0] - x[0]) ** 2)
    assert mse_p < mse_g


def test_unknown_sigma_is_profiled_and_biased_low_by_p_over_n(rng):
    """sigma_hat^2 = RSS / N: E = sigma^2 (N - P) / N to O(1/N); estimates as for known sigma."""
    t, n, sigma = 4000, 40, 0.05
    model = ob.Model(ob.Ring(n), noise=GaussianUnknown(sigma))
    x = np.array([0.1, 1.0])
    data = model.simulate(x, rng=rng, size=t)
    fit = ob.fit_ml(model, data, 1)
    assert fit.extra_names == ("sigma",) and fit.extra.shape == (t, 1)
    s2 = fit.extra[:, 0] ** 2
    expect = sigma**2 * (n - 2) / n
    assert abs(s2.mean() - expect) < 4 * expect * np.sqrt(2 / (n - 2) / t)
    known = ob.fit_ml(ob.Model(ob.Ring(n), sigma), data, 1)
    np.testing.assert_array_equal(fit.params, known.params)
    # the Fisher sd of sigma: sigma / sqrt(2 N)
    np.testing.assert_allclose(fit.extra_std[:, 0], fit.extra[:, 0] / np.sqrt(2 * n),
                               rtol=1e-10)


def test_per_sensor_sigma_is_weighted_and_efficient():
    """Per-sensor sds (a factor 10 apart): weighted ML reaches its CRLB."""
    t, n = 1500, 30
    sig = np.where(np.arange(n) % 2 == 0, 0.01, 0.1)
    model = ob.Model(ob.Ring(n), noise=GaussianPerSensor(sig))
    x = np.array([0.2, 1.0])
    data = model.simulate(x, rng=14, size=t)
    fits = ob.fit_ml(model, data, 1)
    eff = _efficiency(model, x, fits)
    assert np.all(eff > 0.95 - 3 * np.sqrt(2 / t)), eff


def test_gaussian_frames_equal_the_mean_with_sigma_over_sqrt_f(rng):
    """F frames of known sigma fit as their mean with sigma / sqrt(F); log L over all frames."""
    model = ob.Model(ob.Ring(20), 0.05)
    x = np.array([0.5, 1.0, -2.0, 0.6])
    frames = model.simulate(x, rng=rng, n_frames=6)
    assert frames.shape == (6, 20)
    joint = ob.fit_ml(model, frames, 2, frames=True)
    mean = ob.fit_ml(model.with_sigma(0.05 / np.sqrt(6)), frames.mean(axis=0), 2)
    np.testing.assert_array_equal(joint.params, mean.params)
    np.testing.assert_array_equal(joint.cov, mean.cov)
    expect = sum(model.log_likelihood(joint.params, f) for f in frames)
    assert float(joint.log_likelihood) == pytest.approx(expect, rel=1e-12)


def test_poisson_frames_with_exposures_equal_the_summed_counts(rng):
    """Frames of exposures e_f carry the information of their summed counts at exposure sum e_f."""
    expo = np.array([0.5, 1.0, 2.5])
    model = ob.Model(ob.Ring(24), noise=Poisson(exposure=expo, dark=1.0))
    x = np.array([0.3, 40.0])
    counts = model.simulate(x, rng=rng, size=5)
    assert counts.shape == (5, 3, 24)
    joint = ob.fit_ml(model, counts, 1, frames=True)
    summed = ob.fit_ml(ob.Model(ob.Ring(24), noise=Poisson(expo.sum(), 1.0)),
                       counts.sum(axis=1), 1)
    np.testing.assert_allclose(joint.params, summed.params, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(joint.cov, summed.cov, rtol=1e-4)  # at estimates 1e-6 apart


def test_frames_argument_is_checked():
    model = ob.Model(ob.Ring(10), noise=Poisson(2.0))
    with pytest.raises(ob.InputError, match="frames must be True or False"):
        ob.fit_ml(model, np.ones(10), 1, frames="yes")
    with pytest.raises(ob.InputError, match=r"shape \(F, N\) or \(T, F, N\)"):
        ob.fit_ml(model, np.ones((2, 3, 4, 10)), 1, frames=True)
    with pytest.raises(ob.InputError, match="counts"):
        ob.fit_ml(model, -np.ones(10), 1)
    with pytest.raises(ob.InputError, match="ragged"):
        ob.fit_ml(model, [[1, 2, 3], [1, 2]], 1, frames=True)
