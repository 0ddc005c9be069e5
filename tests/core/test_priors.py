"""Priors: the shared 1-D interface, the joint scene prior, priors on K."""

import numpy as np
import pytest
from scipy import integrate, stats

from olsbayes import InputError, Model, Plate, Ring, Sphere
from olsbayes.priors import (
    CircularUniform,
    Exponential,
    HalfNormal,
    LogUniform,
    PoissonCount,
    ScenePrior,
    SinLatitude,
    Uniform,
    UniformCount,
    default_priors,
)

ALL_PRIORS = [
    Uniform(-1.5, 2.0),
    LogUniform(1e-3, 10.0),
    HalfNormal(0.7),
    Exponential(2.5),
    CircularUniform(),
    SinLatitude(),
]


@pytest.mark.parametrize("prior", ALL_PRIORS, ids=lambda p: type(p).__name__)
def test_every_prior_class(prior):
    u = np.linspace(1e-6, 1 - 1e-6, 2001)
    x = prior.ppf(u)
    # cdf inverts ppf, and the support bounds every draw
    np.testing.assert_allclose(prior.cdf(x), u, rtol=0, atol=1e-12)
    assert np.all((x >= prior.lower) & (x <= prior.upper))
    # normalisation by quadrature over the support
    total, err = integrate.quad(prior.prob, prior.lower, prior.upper, limit=200)
    assert abs(total - 1.0) < 1e-8 + 10 * err
    # cdf is the integral of the density
    mid = prior.ppf(0.3)
    part, _ = integrate.quad(prior.prob, prior.lower, mid, limit=200)
    assert abs(part - 0.3) < 1e-8
    # -inf outside the support (periodic priors wrap instead), NaN never a density
    if not prior.periodic:
        below, above = prior.lower - 1.0, prior.upper + 1.0
        assert prior.log_prob(below) == -np.inf
        assert np.isinf(above) or prior.log_prob(above) == -np.inf
    else:
        assert prior.log_prob(7.0) == prior.log_prob(7.0 - 2 * np.pi)
    assert prior.log_prob(np.nan) == -np.inf
    # scipy counterpart agrees in density, cdf and quantiles
    ref = prior.to_scipy()
    if ref is not None:
        np.testing.assert_allclose(prior.log_prob(x), ref.logpdf(x), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(prior.cdf(x), ref.cdf(x), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(x, ref.ppf(u), rtol=1e-9, atol=1e-12)
    # draws follow the cdf (KS at a fixed seed), and the seed fixes the draws
    draws = prior.sample(4000, rng=1)
    assert stats.kstest(draws, prior.cdf).pvalue > 1e-3
    np.testing.assert_array_equal(draws, prior.sample(4000, rng=np.random.default_rng(1)))
    assert np.ndim(prior.sample(rng=3)) == 0
    assert prior.sample((2, 3), rng=3).shape == (2, 3)


def test_sin_latitude_is_isotropic():
    lat = SinLatitude().sample(5000, rng=4)
    assert stats.kstest(np.sin(lat), stats.uniform(-1, 2).cdf).pvalue > 1e-3


def test_prior_argument_errors():
    for bad in (lambda: Uniform(1.0, 1.0), lambda: LogUniform(0.0, 1.0),
                lambda: HalfNormal(-1.0), lambda: Exponential(np.inf),
                lambda: Uniform(np.nan, 1.0)):
        with pytest.raises(InputError):
            bad()


def test_count_priors():
    poi = PoissonCount(1.5, k_max=4)
    ref = stats.poisson(1.5).pmf(np.arange(5))
    np.testing.assert_allclose(poi.pmf(np.arange(5)), ref / ref.sum(), rtol=1e-12)
    assert poi.log_prob(5) == -np.inf and poi.log_prob(-1) == -np.inf
    uni = UniformCount(3)
    np.testing.assert_allclose(uni.pmf([0, 1, 2, 3]), 0.25)
    assert UniformCount(3, k_min=1).pmf(0) == 0.0
    draws = poi.sample(20000, rng=2)
    counts = np.bincount(draws, minlength=5)
    assert stats.chisquare(counts, 20000 * ref / ref.sum()).pvalue > 1e-3
    with pytest.raises(InputError):
        poi.log_prob(1.5)


def test_scene_prior_ring_layout_and_transforms():
    model = Model(Ring(12), sigma=0.1)
    prior = default_priors(model, 2, i_max=3.0)
    assert prior.n_params == 4 and prior.param_names == ["theta[0]", "I[0]", "theta[1]", "I[1]"]
    assert prior.periodic_indices == [0, 2]
    u = np.random.default_rng(0).random((5, 3, 4))
    x = prior.ppf(u)
    np.testing.assert_allclose(prior.cdf(x), u, atol=1e-12)
    expected = 2 * (-np.log(2 * np.pi) - np.log(3.0))
    np.testing.assert_allclose(prior.log_prob(x), expected)
    bad = x.copy()
    bad[0, 0, 1] = -0.1  # negative intensity
    assert prior.log_prob(bad)[0, 0] == -np.inf
    assert np.isclose(prior.log_prob_ordered(x[0, 0]) - prior.log_prob(x[0, 0]), np.log(2))
    assert prior.sample((7,), rng=1).shape == (7, 4)


def test_scene_prior_sphere_plate_and_sigma():
    sph = Model(Sphere.fibonacci(40), sigma=0.05)
    prior = default_priors(sph, 1, i_max=2.0, infer_sigma=True)
    assert prior.param_names == ["lon[0]", "lat[0]", "I[0]", "sigma"]
    assert prior.periodic_indices == [0]
    draws = prior.sample(1000, rng=5)
    assert np.all(np.isfinite(prior.log_prob(draws)))
    plate = Model(Plate.grid(4, 4), sigma=0.01)
    pp = default_priors(plate, 2, i_max=1.0)
    assert pp.location[2].lower >= 0 and not pp.periodic.any()


def test_data_driven_intensity_bound_covers_truth():
    model = Model(Ring(30), sigma=0.01)
    x = np.array([0.3, 1.0, 0.3 + np.pi, 0.2])
    data = model.simulate(x, rng=0)
    prior = default_priors(model, 2, data=data)
    assert prior.intensity.hi > 1.0


def test_wrong_prior_for_geometry():
    ring = Model(Ring(8), sigma=0.1)
    with pytest.raises(InputError, match="location prior of theta"):
        ScenePrior(ring, 1, Uniform(0, 1), location=(HalfNormal(5.0),))
    with pytest.raises(InputError, match="location must hold 1"):
        ScenePrior(ring, 1, Uniform(0, 1), location=(CircularUniform(), SinLatitude()))
    with pytest.raises(InputError, match="intensity"):
        ScenePrior(ring, 1, Uniform(-1, 1))
    with pytest.raises(InputError, match="olsbayes.priors prior"):
        ScenePrior(ring, 1, stats.uniform(0, 1))
    sph = Model(Sphere.fibonacci(20), sigma=0.1)
    with pytest.raises(InputError, match="lat"):
        ScenePrior(sph, 1, Uniform(0, 1), location=(CircularUniform(), CircularUniform()))
    with pytest.raises(InputError, match="i_max"):
        default_priors(ring, 1)
    with pytest.raises(InputError, match="last axis"):
        default_priors(ring, 2, i_max=1.0).log_prob(np.zeros(3))
