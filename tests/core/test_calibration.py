"""Nuisance terms: marginal CRLB (Schur complement), free gains, background, calibration."""

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.bounds import bayesian_information, marginal_information
from olsbayes.calibration import Calibration, calibrate
from olsbayes.noise import Poisson
from olsbayes.priors import LogNormal, Normal, Uniform


def test_schur_complement_equals_the_block_of_the_full_inverse():
    """inv(F_ss - F_se F_ee^-1 F_es) = (F^-1)_ss for background, gains and offsets."""
    n = 16
    nu = ob.Nuisance(gains=np.linspace(0.9, 1.1, n), background=0.5,
                     gain_prior=LogNormal(0.0, 0.05), offset_prior=Normal(0.0, 0.1),
                     background_prior=Uniform(0.0, 5.0))
    model = ob.Model(ob.Ring(n), noise=Poisson(exposure=20.0, dark=0.3), nuisance=nu)
    x = np.array([0.3, 10.0, -2.0, 6.0])
    full = bayesian_information(model, x)
    assert full.shape == (4 + 1 + 2 * n, 4 + 1 + 2 * n)
    marg = np.linalg.inv(marginal_information(full, 4))
    np.testing.assert_allclose(marg, np.linalg.inv(full)[:4, :4], rtol=1e-8)
    res = ob.crlb(model, model.unpack(x))
    np.testing.assert_allclose(res.cov, np.linalg.inv(full)[:4, :4], rtol=1e-8)
    assert res.extra_names[:2] == ("b", "g[0]") and res.extra_std.shape == (1 + 2 * n,)
    assert np.all(res.nuisance_cost >= 1.0)


def test_known_calibration_costs_nothing():
    """Known gains and offsets: the bound is the plain Fisher bound of the calibrated readings."""
    g = np.linspace(0.8, 1.2, 12)
    model = ob.Model(ob.Ring(12), 0.02, nuisance=ob.Nuisance(gains=g, offsets=0.1))
    x = np.array([0.1, 1.0])
    jac = model.jacobian(x) * g[:, None]
    np.testing.assert_allclose(model.fisher(x), jac.T @ jac / 0.02**2, rtol=1e-12)
    res = ob.crlb(model, model.unpack(x))
    assert res.cov_known is None and res.nuisance_cost is None


def test_ml_with_free_gains_reaches_the_bayesian_crlb():
    """Gains drawn from LogNormal(0, s), inferred with that prior: RMSE = bound, z sd = 1."""
    n, s, t = 24, 0.05, 400
    gen = np.random.default_rng(5)
    x = np.array([np.pi / 24, 1.0])
    gains = np.exp(s * gen.standard_normal((t, n)))
    data = np.stack([ob.Model(ob.Ring(n), 0.01, nuisance=ob.Nuisance(gains=gk)).simulate(
        x, rng=gen) for gk in gains])
    model = ob.Model(ob.Ring(n), 0.01, nuisance=ob.Nuisance(gain_prior=LogNormal(0.0, s)))
    fit = ob.fit_ml(model, data, 1)
    bound = ob.crlb(model, model.unpack(x))
    err = fit.params - x
    tol = 3 * np.sqrt(1 / (2 * t))
    np.testing.assert_allclose(np.sqrt(np.mean(err**2, axis=0)) / bound.std, 1.0, atol=tol)
    np.testing.assert_allclose(np.std(err / fit.std, axis=0), 1.0, atol=tol)
    assert np.all(bound.nuisance_cost > 1.5)  # 5 % gains cost more than the noise of 1 %


def test_background_is_recovered_by_ml():
    """An isotropic background inferred with the sources: unbiased, Fisher sd right."""
    t = 300
    nu = ob.Nuisance(background=4.0, background_prior=Uniform(0.0, 100.0))
    model = ob.Model(ob.Ring(30), noise=Poisson(exposure=5.0, dark=1.0), nuisance=nu)
    x = np.array([np.pi / 30, 40.0])
    counts = model.simulate(x, rng=21, size=t)
    fit = ob.fit_ml(model, counts, 1)
    b = fit.extra[:, 0]
    assert fit.extra_names == ("b",)
    assert abs(b.mean() - 4.0) < 4 * b.std() / np.sqrt(t)
    assert np.std((b - 4.0) / fit.extra_std[:, 0]) == pytest.approx(1.0, abs=3 / np.sqrt(2 * t))


def _calibration_frames(truth, scenes, gen):
    return np.stack([truth.simulate(sc if sc.n_sources else np.zeros(0), rng=gen)
                     for sc in scenes])


def test_calibration_from_frames_recovers_gains_within_their_crlb():
    """Frames of a known source at 12 directions plus dark frames: z-scores of sd 1."""
    n, reps = 20, 200
    gen = np.random.default_rng(3)
    g, o = np.exp(0.1 * gen.standard_normal(n)), gen.uniform(0, 2, n)
    truth = ob.Model(ob.Ring(n), noise=Poisson(exposure=10.0, dark=0.5),
                     nuisance=ob.Nuisance(gains=g, offsets=o))
    model = ob.Model(ob.Ring(n), noise=Poisson(exposure=10.0, dark=0.5))
    scenes = [ob.Scene(directions=[a], intensities=[50.0])
              for a in np.linspace(-np.pi, np.pi, 12, endpoint=False)]
    scenes += [ob.Scene(directions=[], intensities=[])] * 2
    z = np.array([(lambda c: [(c.gains - g) / c.gain_sd, (c.offsets - o) / c.offset_sd])(
        calibrate(model, _calibration_frames(truth, scenes, gen), scenes))
        for _ in range(reps)])
    np.testing.assert_allclose(z.std(axis=(0, 2)), 1.0, atol=3 / np.sqrt(2 * reps * n))
    assert np.all(np.abs(z.mean(axis=(0, 2))) < 3 / np.sqrt(reps * n))


def test_gaussian_calibration_is_weighted_least_squares(rng):
    """Gaussian noise: the per-sensor regression on the known responses, exactly."""
    n = 8
    model = ob.Model(ob.Ring(n), 0.01)
    scenes = [ob.Scene(directions=[a], intensities=[1.0]) for a in (0.0, 1.0, 2.0, -2.0)]
    r = np.stack([model.response(sc) for sc in scenes]) + np.array([0.5, 0.5, 0.0, 1.0])[:, None]
    frames = 1.1 * r + 0.2 + 0.01 * rng.normal(size=(4, n))
    cal = calibrate(model, frames, scenes, flat=[0.5, 0.5, 0.0, 1.0])
    for k in range(n):
        design = np.column_stack([r[:, k], np.ones(4)])
        beta = np.linalg.lstsq(design, frames[:, k], rcond=None)[0]
        np.testing.assert_allclose([cal.gains[k], cal.offsets[k]], beta, rtol=1e-10)
        sd = 0.01 * np.sqrt(np.diag(np.linalg.inv(design.T @ design)))
        np.testing.assert_allclose([cal.gain_sd[k], cal.offset_sd[k]], sd, rtol=1e-10)


def test_calibration_files_round_trip_and_refuse_another_array(tmp_path):
    cal = Calibration(gains=np.linspace(0.9, 1.1, 6), offsets=np.zeros(6),
                      gain_sd=np.full(6, 0.01), offset_sd=np.full(6, 0.02),
                      normals=ob.Ring(6).normals)
    for name in ("cal.toml", "cal.nc"):
        back = Calibration.load(cal.save(tmp_path / name))
        for f in ("gains", "offsets", "gain_sd", "offset_sd", "normals"):
            np.testing.assert_array_equal(getattr(back, f), getattr(cal, f))
    cal.check(ob.Ring(6))
    with pytest.raises(ob.InputError, match="6 sub-sensors"):
        cal.check(ob.Ring(7))
    with pytest.raises(ob.InputError, match="normals differ"):
        cal.check(ob.Ring(6, 0.1))
    nu = cal.nuisance(infer=True)
    assert isinstance(nu.gain_prior[0], LogNormal) and nu.gain_prior[0].s == pytest.approx(
        0.01 / 0.9)
    (tmp_path / "bad.toml").write_text("[calibration]\ngains = [1.0]\n")
    with pytest.raises(ob.ConfigError, match="exactly the keys"):
        Calibration.load(tmp_path / "bad.toml")
    with pytest.raises(ob.InputError, match=".toml or .nc"):
        cal.save(tmp_path / "cal.txt")


@pytest.mark.parametrize("make, match", [
    (lambda: ob.Nuisance(gains=[1.0, 0.0]), "gains must be > 0"),
    (lambda: ob.Nuisance(background=-1.0), "background"),
    (lambda: ob.Nuisance(gain_prior=Normal(1.0, 0.1)), "support within"),
    (lambda: ob.Model(ob.Ring(5), 0.1, nuisance=ob.Nuisance(gains=np.ones(4))), r"\(5,\)"),
    (lambda: ob.Model(ob.Ring(5), 0.1, nuisance=ob.Nuisance(
        gain_prior=(LogNormal(0, 0.1),) * 3)), "one prior or 5"),
    (lambda: calibrate(ob.Model(ob.Ring(4), 0.1), np.ones((2, 4)),
                       [ob.Scene(directions=[0.0], intensities=[1.0])] * 2), "distinct"),
    (lambda: calibrate(ob.Model(ob.Ring(4), 0.1), np.ones((2, 4)), []), "one Scene per frame"),
])
def test_bad_nuisance_and_calibration_input(make, match):
    with pytest.raises(ob.InputError, match=match):
        make()
