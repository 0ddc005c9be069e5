"""Noise models: likelihoods, Fisher information, simulation, frames and bad input."""

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.noise import GaussianKnown, GaussianPerSensor, GaussianUnknown, Poisson


def _fd_hessian(f, x, h):
    p = x.size
    out = np.empty((p, p))
    for i in range(p):
        for j in range(p):
            e_i, e_j = np.eye(p)[i] * h[i], np.eye(p)[j] * h[j]
            out[i, j] = (f(x + e_i + e_j) - f(x + e_i - e_j) - f(x - e_i + e_j)
                         + f(x - e_i - e_j)) / (4 * h[i] * h[j])
    return out


def test_default_model_is_gaussian_known_with_the_original_arithmetic(rng):
    """Model(array, sigma) keeps the Gaussian formula: log L, Fisher and simulate to the bit."""
    model = ob.Model(ob.Ring(24), 0.02)
    assert isinstance(model.noise, GaussianKnown) and model.noise.is_default
    x = np.array([0.4, 1.0, -2.0, 0.5])
    data = model.response(x) + 0.02 * rng.standard_normal(24)
    resid = data - model.response(x)
    expect = -0.5 * np.einsum("n,n->", resid, resid) / 0.02**2 - 24 * (
        np.log(0.02) + 0.5 * np.log(2 * np.pi))
    assert model.log_likelihood(x, data) == expect
    jac = model.jacobian(x)
    assert np.array_equal(model.fisher(x), jac.T @ jac / 0.02**2)
    sim = model.simulate(x, rng=5, size=3)
    assert np.array_equal(sim, model.response(x) + 0.02 * np.random.default_rng(5)
                          .standard_normal((3, 24)))
    assert repr(model) == "Model(Ring(n=24, offset=0.0), sigma=0.02, sensitivity=Cosine())"


def test_explicit_gaussian_known_noise_equals_sigma():
    """noise=GaussianKnown(s) is the same model as sigma=s, numbers to the bit."""
    a = ob.Model(ob.Ring(16), 0.1)
    b = ob.Model(ob.Ring(16), noise=GaussianKnown(0.1))
    x = np.array([0.3, 2.0])
    d = a.simulate(x, rng=1)
    assert a.log_likelihood(x, d) == b.log_likelihood(x, d)


def test_poisson_fisher_is_minus_the_expected_hessian():
    """Fisher = -d^2 log L at data equal to the expected counts (the Hessian is linear in s)."""
    model = ob.Model(ob.Ring(20), noise=Poisson(exposure=3.0, dark=0.5))
    x = np.array([0.35, 40.0, -1.9, 25.0])
    lam = 3.0 * (model.response(x) + 0.5)
    hess = _fd_hessian(lambda z: float(model.log_likelihood(z, lam)), x,
                       np.array([1e-5, 1e-3, 1e-5, 1e-3]))
    np.testing.assert_allclose(model.fisher(x), -hess, rtol=1e-5, atol=1e-6 * np.abs(hess).max())


def test_poisson_fisher_one_source_closed_form():
    """One ring source: F_II = E sum c^2 / (I c + d), F_tt = E sum (I s)^2 / (I c + d) (facing)."""
    n, e, d, th, inten = 36, 2.5, 0.2, 0.3, 50.0
    model = ob.Model(ob.Ring(n), noise=Poisson(exposure=e, dark=d))
    phi = 2 * np.pi * np.arange(n) / n
    c, s = np.cos(th - phi), np.sin(th - phi)
    face = c > 0
    f_ii = e * np.sum(c[face] ** 2 / (inten * c[face] + d))
    f_tt = e * np.sum((inten * s[face]) ** 2 / (inten * c[face] + d))
    f_ti = e * np.sum(-inten * s[face] * c[face] / (inten * c[face] + d))
    fisher = model.fisher(np.array([th, inten]))
    np.testing.assert_allclose(fisher, [[f_tt, f_ti], [f_ti, f_ii]], rtol=1e-12)


def test_poisson_frames_add_their_exposures(rng):
    """F frames of exposures e_f: Fisher of the sum, log L the sum over frames."""
    expo = np.array([1.0, 2.0, 0.5])
    model = ob.Model(ob.Ring(12), noise=Poisson(exposure=expo))
    one = ob.Model(ob.Ring(12), noise=Poisson(exposure=expo.sum()))
    x = np.array([1.0, 30.0])
    np.testing.assert_allclose(model.fisher(x), one.fisher(x), rtol=1e-13)
    counts = model.simulate(x, rng=rng)
    assert counts.shape == (3, 12)
    per = [ob.Model(ob.Ring(12), noise=Poisson(exposure=e)).log_likelihood(x, c)
           for e, c in zip(expo, counts)]
    assert model.log_likelihood(x, counts, frames=True) == pytest.approx(sum(per), rel=1e-13)


def test_poisson_simulation_mean_and_variance():
    """Counts have mean = variance = exposure * (rate + dark)."""
    model = ob.Model(ob.Ring(8), noise=Poisson(exposure=4.0, dark=1.0))
    x = np.array([0.0, 5.0])
    lam = 4.0 * (model.response(x) + 1.0)
    c = model.simulate(x, rng=3, size=40000)
    assert np.all(c == np.round(c)) and c.min() >= 0
    se = np.sqrt(lam / 40000)
    assert np.all(np.abs(c.mean(axis=0) - lam) < 5 * se)
    assert np.all(np.abs(c.var(axis=0) / lam - 1) < 5 * np.sqrt(2 / 40000) + 0.01)


def test_gaussian_per_sensor_weights_and_likelihood(rng):
    """Per-sensor sds: Fisher J^T diag(1/sigma^2) J; log L the sum of the sensors' normals."""
    sig = np.linspace(0.01, 0.05, 10)
    model = ob.Model(ob.Ring(10), noise=GaussianPerSensor(sig))
    x = np.array([0.2, 1.0])
    jac = model.jacobian(x)
    np.testing.assert_allclose(model.fisher(x), jac.T @ (jac / sig[:, None] ** 2), rtol=1e-13)
    d = model.simulate(x, rng=rng)
    r = (d - model.response(x)) / sig
    expect = np.sum(-0.5 * r**2 - np.log(sig) - 0.5 * np.log(2 * np.pi))
    assert model.log_likelihood(x, d) == pytest.approx(expect, rel=1e-13)


def test_gaussian_unknown_sigma_as_extra_and_frames(rng):
    """Unknown sigma: log L at an explicit sigma, and frames sum over the frame axis."""
    model = ob.Model(ob.Ring(10), noise=GaussianUnknown(0.05))
    assert model.sigma == 0.05
    x = np.array([0.2, 1.0])
    d = model.simulate(x, rng=rng, n_frames=4)
    assert d.shape == (4, 10)
    known = ob.Model(ob.Ring(10), 0.07)
    total = sum(known.log_likelihood(x, row) for row in d)
    got = model.log_likelihood(x, d, extra=np.array([0.07]), frames=True)
    assert got == pytest.approx(total, rel=1e-13)


def test_crlb_poisson_scales_with_exposure():
    """Poisson without dark: information proportional to exposure, CRLB to 1 / sqrt(E)."""
    scene = ob.Scene(directions=[0.3], intensities=[20.0])
    a = ob.crlb(ob.Model(ob.Ring(30), noise=Poisson(1.0, 0.1)), scene)
    b = ob.crlb(ob.Model(ob.Ring(30), noise=Poisson(4.0, 0.1)), scene)
    np.testing.assert_allclose(a.std / b.std, 2.0, rtol=1e-12)


@pytest.mark.parametrize("make, match", [
    (lambda: Poisson(exposure=0.0), "exposure must be > 0"),
    (lambda: Poisson(exposure=[1.0, -1.0]), "exposure must be > 0"),
    (lambda: Poisson(dark=-0.1), "dark must be >= 0"),
    (lambda: GaussianPerSensor([0.1, 0.0, 0.1]), "no zeros"),
    (lambda: ob.Model(ob.Ring(5), noise=GaussianPerSensor([0.1, 0.1])), r"shape \(5,\)"),
    (lambda: ob.Model(ob.Ring(5), noise=Poisson(dark=[0.1, 0.2])), r"dark must be"),
    (lambda: ob.Model(ob.Ring(5), 0.1, noise=Poisson()), "not both"),
    (lambda: ob.Model(ob.Ring(5)), "needs sigma"),
    (lambda: ob.Model(ob.Ring(5), noise="poisson"), "NoiseModel"),
])
def test_bad_noise_settings(make, match):
    with pytest.raises(ob.InputError, match=match):
        make()


@pytest.mark.parametrize("counts, match", [
    (np.full(6, -1.0), "counts: integers"),
    (np.full(6, 2.5), "counts: integers"),
    (np.full(5, 2.0), "last axis of length 6"),
    (np.array([1, 2, np.nan, 1, 1, 1]), "finite"),
])
def test_poisson_refuses_non_counts(counts, match):
    model = ob.Model(ob.Ring(6), noise=Poisson(2.0))
    with pytest.raises(ob.InputError, match=match):
        model.check_data(counts)


def test_poisson_exposure_vector_needs_matching_frames():
    model = ob.Model(ob.Ring(6), noise=Poisson(exposure=[1.0, 2.0]))
    with pytest.raises(ob.InputError, match="2 frames"):
        model.check_data(np.ones((3, 6)), frames=True)
    with pytest.raises(ob.InputError, match="2 frames"):
        model.check_data(np.ones((2, 6)))
    assert model.check_data(np.ones((2, 6)), frames=True).shape == (2, 6)


def test_models_with_noise_survive_save_and_load(tmp_path):
    """A result's model keeps its noise and nuisance through a NetCDF file."""
    from olsbayes._store import load_result, save_result
    from olsbayes.bounds import CRLBResult

    model = ob.Model(ob.Ring(8), noise=Poisson(exposure=[1.0, 2.0], dark=0.3),
                     nuisance=ob.Nuisance(gains=np.linspace(0.9, 1.1, 8), background=0.2))
    res = ob.crlb(model, ob.Scene(directions=[0.1], intensities=[5.0]))
    assert isinstance(res, CRLBResult)
    from olsbayes.ml import MLResult
    fit = MLResult(params=np.array([0.1, 5.0]), log_likelihood=np.array(-3.0),
                   converged=np.array(True), n_evaluations=np.array(1), cov=res.cov,
                   rival_gap=np.array(np.inf), method="fast", n_sources=1, model=model)
    path = save_result(fit, tmp_path / "fit.nc")
    back = load_result(path, MLResult)
    assert back.model.noise == model.noise
    np.testing.assert_array_equal(back.model.nuisance.gains, model.nuisance.gains)
    assert back.model.nuisance.background == 0.2
