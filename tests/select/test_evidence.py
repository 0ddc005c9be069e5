"""Evidence estimators checked against closed forms and quadrature (no ML needed)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, stats

from olsbayes import Model, Plate, Ring, Sphere
from olsbayes.errors import ConvergenceWarning, InputError
from olsbayes.priors import ScenePrior, Uniform
from olsbayes.select import (
    closest_pair,
    laplace_log_evidence,
    laplace_trust,
    linear_gaussian_log_evidence,
    model_laplace,
    nested_log_evidence,
    noise_log_evidence,
    sensor_spacing,
)
from olsbayes.select.laplace import support_log_mass

RING = Model(Ring(30), 0.01)


def test_noise_evidence_is_the_gaussian_density_of_the_data():
    rng = np.random.default_rng(0)
    data = 0.01 * rng.standard_normal((3, 30))
    want = stats.multivariate_normal(np.zeros(30), 1e-4 * np.eye(30)).logpdf(data)
    np.testing.assert_allclose(noise_log_evidence(data, 0.01), want, rtol=1e-12)


def _imaging_problem(rng):
    """Ring N=30, three known directions: Eq. 1 is linear in the intensities."""
    directions = np.array([-2.0, 0.4, 1.9])
    unit = np.column_stack([directions, np.ones(3)])  # (3, 2): one source per row
    return RING.response(unit).T  # (N, 3)


def test_imaging_design_matrix_columns_are_unit_source_responses():
    design = _imaging_problem(None)
    x = np.array([-2.0, 1.0, 0.4, 0.0, 1.9, 0.0])
    np.testing.assert_allclose(design[:, 0], RING.response(x), atol=1e-15)


def test_laplace_is_exact_on_the_linear_gaussian_imaging_problem():
    """Gaussian prior, linear model: the posterior is Gaussian and Laplace is exact."""
    rng = np.random.default_rng(1)
    design = _imaging_problem(rng)
    sigma, m, s = 0.01, np.array([0.5, 0.5, 0.5]), np.diag([0.3, 0.2, 0.4]) ** 2
    data = design @ np.array([1.0, 0.3, 0.7]) + sigma * rng.standard_normal(30)
    exact = linear_gaussian_log_evidence(design, data, sigma, m, s)
    # the same marginal, written out independently
    marginal = stats.multivariate_normal(design @ m, sigma**2 * np.eye(30) + design @ s @ design.T)
    assert exact == pytest.approx(marginal.logpdf(data), abs=1e-8)
    # Laplace at the MAP point with H = A^T A / sigma^2 + S^-1
    h = design.T @ design / sigma**2 + np.linalg.inv(s)
    a_map = np.linalg.solve(h, design.T @ data / sigma**2 + np.linalg.solve(s, m))
    log_l = stats.multivariate_normal(design @ a_map, sigma**2 * np.eye(30)).logpdf(data)
    log_p = stats.multivariate_normal(m, s).logpdf(a_map)
    assert laplace_log_evidence(log_l, log_p, h) == pytest.approx(exact, abs=1e-8)


def test_linear_gaussian_evidence_matches_quadrature():
    rng = np.random.default_rng(2)
    design = _imaging_problem(rng)[:, :2]
    sigma = 0.2  # wide posterior so plain quadrature resolves it
    data = design @ np.array([0.8, 0.4]) + sigma * rng.standard_normal(30)
    m, s = np.array([0.5, 0.5]), np.diag([0.5, 0.5]) ** 2
    a1, a2 = np.meshgrid(np.linspace(-1.5, 2.5, 801), np.linspace(-1.5, 2.5, 801), indexing="ij")
    a = np.stack([a1, a2], axis=-1)
    resid = data - a @ design.T
    log_norm = 30 * math.log(sigma * math.sqrt(2 * math.pi))
    logf = (-0.5 * np.sum(resid**2, axis=-1) / sigma**2 - log_norm
            + stats.multivariate_normal(m, s).logpdf(a))
    top = logf.max()
    z = integrate.simpson(integrate.simpson(np.exp(logf - top), x=a2[0], axis=1), x=a1[:, 0])
    want = math.log(z) + top
    assert linear_gaussian_log_evidence(design, data, sigma, m, s) == pytest.approx(want, abs=1e-5)


def test_model_laplace_matches_brute_force_quadrature_for_one_source():
    """K = 1 on the ring (nonlinear in theta): Laplace vs a fine 2-D grid integral.

    The source at 0 puts the costn kinks (sub-sensors 90 deg away) half a spacing
    from the nearest sub-sensor, > 10 posterior sd away, so the posterior is smooth
    and Gaussian up to O(1/SNR^2) ~ 1e-3 (SNR = I / sd_I ~ 27).
    """
    model = Model(Ring(30), 0.02)
    prior = ScenePrior(model, 1, Uniform(0.0, 2.0))
    x0 = np.array([0.0, 1.0])
    data = model.simulate(x0, rng=np.random.default_rng(3))
    from olsbayes.ml import fit_ml

    fit = fit_ml(model, data, 1)
    log_z, _, sd = model_laplace(model, fit.params, fit.log_likelihood, prior)
    th = fit.params[0] + np.linspace(-12, 12, 801) * sd[0]
    inten = fit.params[1] + np.linspace(-12, 12, 801) * sd[1]
    tt, ii = np.meshgrid(th, inten, indexing="ij")
    x = np.stack([tt, ii], axis=-1)
    logf = model.log_likelihood(x, data) + prior.log_prob(x)
    top = logf.max()
    z = np.trapezoid(np.trapezoid(np.exp(logf - top), inten, axis=1), th)
    assert float(log_z) == pytest.approx(math.log(z) + top, abs=0.003)


def test_support_mass_is_the_gaussian_mass_inside_the_box():
    prior = ScenePrior(RING, 1, Uniform(0.0, 2.0))
    x = np.array([[0.3, 0.0], [0.3, 0.05], [0.3, 1.98]])
    sd = np.array([0.01, 0.05])
    want = np.log(stats.norm(x[:, 1], 0.05).cdf(2.0) - stats.norm(x[:, 1], 0.05).cdf(0.0))
    np.testing.assert_allclose(support_log_mass(x, sd, prior), want, rtol=1e-10)
    assert support_log_mass(x[0], sd, prior) == pytest.approx(math.log(0.5))
    # an angle Gaussian wider than the circle is capped at the whole prior
    wide = support_log_mass(x[1], np.array([10.0, 0.05]), prior)
    assert wide == pytest.approx(want[1] + math.log(2 * np.pi / (math.sqrt(2 * np.pi) * 10.0)))


def test_laplace_rejects_bad_hessians_and_handles_edge_cases():
    assert math.isnan(laplace_log_evidence(0.0, 0.0, np.diag([1.0, -1.0])))
    assert laplace_log_evidence(0.0, -np.inf, np.eye(2)) == -np.inf
    assert laplace_log_evidence(1.5, -0.5, np.zeros((0, 0))) == 1.0
    assert laplace_log_evidence(0.0, 0.0, np.eye(3), n_exchangeable=3) == pytest.approx(
        1.5 * math.log(2 * math.pi) + math.log(6))
    with pytest.raises(InputError, match="square"):
        laplace_log_evidence(0.0, 0.0, np.ones((2, 3)))


def test_nested_sampling_recovers_a_known_gaussian_evidence():
    """Gaussian likelihood in a box prior: Z = prior density x Gaussian normaliser."""
    cen, s = np.array([0.3, -0.2]), 0.05

    def log_like(x):
        return float(-0.5 * np.sum((x - cen) ** 2) / s**2)

    def transform(u):
        return -1.0 + 2.0 * u  # Uniform(-1, 1)^2, density 1/4

    want = math.log(2 * math.pi * s**2) + math.log(0.25)
    out = nested_log_evidence(log_like, transform, 2, rng=4, maxcall=50_000, n_live=60)
    assert out.converged
    assert abs(out.log_evidence - want) < 3 * out.error + 0.05
    assert out.samples.shape[1] == 2 and out.n_calls <= 50_000


def test_nested_sampling_cap_warns():
    with pytest.warns(ConvergenceWarning, match="maxcall"):
        out = nested_log_evidence(lambda x: float(-0.5 * np.sum(x**2) / 1e-6), lambda u: u - 0.5,
                                  3, rng=0, maxcall=1000)
    assert not out.converged


def test_nested_rejects_bad_options():
    with pytest.raises(InputError, match="maxcall"):
        nested_log_evidence(lambda x: 0.0, lambda u: u, 1, maxcall=10)
    with pytest.raises(InputError, match="n_live"):
        nested_log_evidence(lambda x: 0.0, lambda u: u, 3, n_live=3)
    with pytest.raises(TypeError):
        nested_log_evidence(lambda x: 0.0, lambda u: u, 1, None, 0)  # keyword-only
    with pytest.raises(InputError, match="sample"):
        nested_log_evidence(lambda x: 0.0, lambda u: u, 1, sample="nope")


def test_spacing_and_closest_pair():
    """The closest pair across the ring's wrap, on a sphere and on a plate; the first
    pair (i < j, row by row) on ties; inf and (-1, -1) for one source."""
    assert sensor_spacing(RING) == pytest.approx(2 * np.pi / 30)
    sep, pair = closest_pair(RING, np.array([3.1, 1.0, -3.1, 1.0, 0.0, 1.0]))
    assert sep == pytest.approx(2 * np.pi - 6.2) and pair == (0, 1)
    assert closest_pair(RING, np.array([0.1, 1.0])) == (np.inf, (-1, -1))
    assert closest_pair(RING, np.array([0.0, 1.0, 1.0, 1.0, 2.0, 1.0, 3.0, 1.0]))[1] == (0, 1)
    sphere = Model(Sphere.fibonacci(40), 0.01)
    sep, pair = closest_pair(sphere, np.array([0.0, 0.5, 1.0, 2.0, -0.3, 1.0, 0.0, 0.5 + 1e-7,
                                               1.0]))
    assert pair == (0, 2) and sep == pytest.approx(1e-7, abs=1e-15)  # unit-vector rounding
    plate = Model(Plate.grid(4, 4, 1.0), 0.01)
    sep, pair = closest_pair(plate, np.array([0.0, 0.0, 3.0, 1.0, 5.0, 1.0, 3.0, 1.0,
                                              5.0, 3.0, 3.0, 1.0]))
    assert pair == (1, 2) and sep == pytest.approx(2.0)
    for bad in (np.array([1.0, 2.0, 3.0]), np.array([[0.1, 1.0, 0.2, 1.0]]),
                np.array([np.nan, 1.0, 0.5, 1.0])):
        with pytest.raises(InputError, match="params"):
            closest_pair(RING, bad)


def _all_pairs_spacing(model: Model) -> float:
    """The definition: median over sub-sensors of the distance to the nearest other one.

    Distances between positions, angles between normals from their chord (2 arcsin(c / 2));
    every pair, a block of rows at a time.
    """
    pts = model.array.positions if model.kind == "position" else model.array.normals
    nearest = np.empty(len(pts))
    for lo in range(0, len(pts), 256):
        d = np.linalg.norm(pts[lo : lo + 256, None, :] - pts[None, :, :], axis=-1)
        d[np.arange(d.shape[0]), np.arange(lo, lo + d.shape[0])] = np.inf
        nearest[lo : lo + 256] = d.min(axis=1)
    if model.kind != "position":
        nearest = 2 * np.arcsin(np.minimum(nearest / 2, 1.0))
    return float(np.median(nearest))


def test_spacing_equals_the_all_pairs_definition_and_is_kept_on_the_model():
    # every pair up to 2048 sub-sensors, a k-d tree's candidates beyond (ties on the
    # grids and the ring): bit for bit the all-pairs value either way
    rng = np.random.default_rng(5)
    lat, lon = np.arcsin(rng.uniform(-1, 1, 700)), rng.uniform(-np.pi, np.pi, 700)
    arrays = [Ring(3), Ring(7), Ring(300), Ring(1100, offset=0.3), Sphere(lon, lat),
              Sphere.grid(12, 24), Plate.grid(30, 20, 0.5), Ring(2500, offset=0.1),
              Sphere.fibonacci(2100), Sphere.grid(50, 60), Plate.grid(60, 50, 1e-3)]
    for array in arrays:
        model = Model(array, 0.01)
        assert model.memo("sensor_spacing") is None
        assert sensor_spacing(model) == _all_pairs_spacing(model)
        assert model.memo("sensor_spacing") == sensor_spacing(model)


def test_spacing_of_large_rings_to_rounding():
    # 2 pi / N from the chord: the normals' rounding (~1e-16) over the angle (6e-5 at
    # N = 1e5) is ~2e-12 relative; arccos of the dot product was off by 1.9e-8 there
    for n in (3000, 100_000):
        assert sensor_spacing(Model(Ring(n), 0.01)) == pytest.approx(2 * np.pi / n, rel=1e-11)


def test_trust_flags_unresolvable_pairs_and_weak_sources():
    h = 2 * np.pi / 30
    x = np.array([0.1, 1.0, 0.1 + 0.5 * h, 1.0])  # half a spacing: singular on even N
    reasons, _ = laplace_trust(RING, x, RING.fisher(x))
    assert any("singular" in r for r in reasons)
    assert any("resolution limit" in r for r in reasons)
    x = np.array([0.1, 1.0, 2.0, 0.02])  # second source 0.02 ~ 5.5 sd of I (sd ~ 0.0037)
    reasons, st = laplace_trust(RING, x, RING.fisher(x), thresholds={"snr": 10.0})
    assert len(reasons) == 1 and "weak source I[1]" in reasons[0]
    with pytest.raises(InputError, match=r"unknown key\(s\) \['sep'\]"):
        laplace_trust(RING, x, RING.fisher(x), thresholds={"sep": 1.0})
    x = np.array([0.1, 1.0, 2.0, 0.7])
    reasons, st = laplace_trust(RING, x, RING.fisher(x))
    assert reasons == () and st["separation"] == pytest.approx(1.9 / h)


def test_laplace_matches_importance_sampling_on_a_two_source_scene():
    """Well-separated K=2 (ring N=30, sigma=0.01): Laplace vs a Student-t importance
    sampler around the same mode, both with log 2! for the swapped labelling.
    Non-Gaussianity at SNR ~ 200 is O(1e-3) nats; the IS standard error ~3e-3."""
    from olsbayes.ml import fit_ml
    from olsbayes.select.importance import importance_log_evidence

    prior = ScenePrior(RING, 2, Uniform(0.0, 2.0))
    data = RING.simulate(np.array([-0.6, 1.0, 1.5, 0.6]), rng=np.random.default_rng([2, 0]))
    fit = fit_ml(RING, data, 2)
    log_z, fisher, _ = model_laplace(RING, fit.params, fit.log_likelihood, prior)
    is_z, se = importance_log_evidence(RING, data, fit.params, np.linalg.inv(fisher), prior,
                                       n_draws=20_000, rng=1)
    assert se < 0.01
    assert abs(float(log_z) - is_z) < 5 * se + 0.005


def test_disagreeing_laplace_and_nested_evidences_warn():
    """A trusted Laplace value off by 10 nats must not pass silently after escalation."""
    import dataclasses

    from olsbayes.errors import EvidenceWarning
    from olsbayes.ml import fit_ml
    from olsbayes.select import NestedOptions
    from olsbayes.select.engine import laplace_work, nested_work

    model = Model(Ring(30), 0.05)
    prior = ScenePrior(model, 1, Uniform(0.0, 2.0))
    data = model.simulate(np.array([0.0, 1.0]), rng=np.random.default_rng(3))
    fit = fit_ml(model, data, 1)
    work = laplace_work(model, 1, (fit, fit.params, float(fit.log_likelihood), "fit_ml"),
                        prior, None)
    assert work.reasons == ()
    bad = dataclasses.replace(work, value=work.value + 10.0, laplace=work.laplace + 10.0)
    with pytest.warns(EvidenceWarning, match="disagree"):
        out = nested_work(model, data, bad, prior,
                          NestedOptions(maxcall=30_000, n_live=50, dlogz=0.5),
                          rng=np.random.default_rng(0))
    assert out.method == "nested" and abs(out.value - work.laplace) < 3 * out.error + 0.5
