"""Maximum-likelihood fits: efficiency against the CRLB, batch == loop, fast == multistart."""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.errors import ConvergenceWarning, InputError
from olsbayes.ml import FastOptions, MLResult, MultistartOptions, fit_ml


def _errors(model: ob.Model, est: np.ndarray, scene: ob.Scene) -> np.ndarray:
    """Estimation errors (T, P) in canonical order, angles wrapped."""
    err = est - model.canonical(model.pack(scene))
    if model.kind != "position":
        err[:, 0 :: model.n_loc + 1] = ob.wrap_angle(err[:, 0 :: model.n_loc + 1])
    return err


def _efficiency_check(model, scene, n_trials, seed, n_sources):
    data = model.simulate(scene, rng=seed, size=n_trials)
    res = fit_ml(model, data, n_sources)
    assert res.converged.all()
    err = _errors(model, res.params, scene)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ob.KinkWarning)
        bound = ob.crlb(model, scene.sorted()).std
    eff = bound**2 / err.var(axis=0)
    # sd of a variance ratio over T trials is sqrt(2/T); 4 sd = false alarm ~ 1e-4
    tol = 4.0 * np.sqrt(2.0 / n_trials)
    np.testing.assert_array_less(np.abs(eff - 1.0), tol)
    # unbiased to within 4 Monte Carlo standard errors of the mean
    np.testing.assert_array_less(np.abs(err.mean(axis=0)), 4.0 * bound / np.sqrt(n_trials))
    return res


def test_efficiency_single_source_ring():
    model = ob.Model(ob.Ring(30), sigma=1e-2)
    scene = ob.Scene(directions=[0.7], intensities=[1.0])
    _efficiency_check(model, scene, 400, 11, 1)


def test_efficiency_fig3_two_sources_ring():
    model = ob.Model(ob.Ring(30), sigma=1e-2)
    scene = ob.Scene(directions=[0.3, 0.3 + np.pi], intensities=[1.0, 0.2])
    _efficiency_check(model, scene, 400, 12, 2)


def test_efficiency_sphere_two_sources():
    model = ob.Model(ob.Sphere.fibonacci(120), sigma=1e-2)
    scene = ob.Scene(directions=[[0.4, 0.2], [2.5, -0.5]], intensities=[1.0, 0.6])
    _efficiency_check(model, scene, 300, 13, 2)


def test_efficiency_plate_one_source():
    model = ob.Model(ob.Plate.grid(6, 6, pitch=1.0), sigma=1e-3)
    scene = ob.Scene(positions=[[0.4, -0.3, 2.0]], intensities=[1.0])
    _efficiency_check(model, scene, 300, 14, 1)


def test_batch_equals_loop():
    model = ob.Model(ob.Ring(24), sigma=3e-2)
    scene = ob.Scene(directions=[-2.0, 0.1, 1.9], intensities=[1.0, 0.7, 0.5])
    data = model.simulate(scene, rng=5, size=6)
    batch = fit_ml(model, data, 3, warn=False)  # 2 of 6 have a rival mode (sigma = 0.03)
    for i, s in enumerate(data):
        one = fit_ml(model, s, 3, warn=False)
        np.testing.assert_allclose(one.params, batch.params[i], rtol=0, atol=1e-10)
        np.testing.assert_allclose(one.rival_gap, batch.rival_gap[i], rtol=1e-8)
        np.testing.assert_allclose(one.log_likelihood, batch.log_likelihood[i], rtol=1e-12)
        np.testing.assert_allclose(one.cov, batch.cov[i], rtol=1e-8)
        assert one.n_evaluations == batch.n_evaluations[i]
        assert one.converged == batch.converged[i]


@pytest.mark.parametrize(
    "model, scene, k",
    [
        (ob.Model(ob.Ring(30), 1e-2),
         ob.Scene(directions=[-1.5, 1.0], intensities=[1.0, 0.5]), 2),
        (ob.Model(ob.Ring(30), 3e-2),
         ob.Scene(directions=[-2.2, 0.0, 2.0], intensities=[0.8, 1.0, 0.6]), 3),
        (ob.Model(ob.Sphere.fibonacci(80), 1e-2),
         ob.Scene(directions=[[0.3, 0.2]], intensities=[1.0]), 1),
    ],
)
def test_fast_matches_multistart_on_easy_scenes(model, scene, k):
    data = model.simulate(scene, rng=21, size=2)
    fast = fit_ml(model, data, k)
    multi = fit_ml(model, data, k, method="multistart", rng=22,
                   options=MultistartOptions(n_starts=6))
    # the fast optimum is at least as good, and the same point when multistart found it
    assert np.all(fast.log_likelihood >= multi.log_likelihood - 1e-7)
    same = multi.log_likelihood >= fast.log_likelihood - 1e-7
    assert same.any()
    np.testing.assert_allclose(fast.params[same], multi.params[same], atol=1e-5)


def test_intensities_nonnegative_with_extra_source():
    model = ob.Model(ob.Ring(30), sigma=1e-2)
    data = model.simulate(ob.Scene(directions=[0.5], intensities=[1.0]), rng=3, size=20)
    res = fit_ml(model, data, 3, warn=False)  # surplus sources: many equivalent optima
    inten = res.params.reshape(20, 3, 2)[..., 1]
    assert np.all(inten >= 0)
    assert np.any(inten == 0)  # surplus sources are switched off, not made negative


def test_result_fields_and_scene():
    model = ob.Model(ob.Ring(30), sigma=1e-2)
    scene = ob.Scene(directions=[2.0, -1.0], intensities=[1.0, 0.5])
    res = fit_ml(model, model.simulate(scene, rng=4), 2)
    assert isinstance(res, MLResult) and not res.is_batch and res.n_trials == 1
    assert res.params.shape == (4,) and res.cov.shape == (4, 4) and res.log_likelihood.shape == ()
    np.testing.assert_allclose(res.params, model.canonical(res.params))
    est = res.scene
    assert est.n_sources == 2 and est.directions[0] < est.directions[1]
    np.testing.assert_allclose(est.directions, scene.sorted().directions, atol=0.05)
    np.testing.assert_allclose(res.log_likelihood,
                               model.log_likelihood(res.params, model.simulate(scene, rng=4)))
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.method = "x"
    with pytest.raises(ValueError):
        res.params[0] = 1.0
    batch = fit_ml(model, model.simulate(scene, rng=4, size=2), 2)
    assert batch.scene_at(1).n_sources == 2 and len(batch) == 2
    with pytest.raises(InputError, match="scene_at"):
        batch.scene  # noqa: B018


def test_nonconvergence_is_reported_and_warned():
    model = ob.Model(ob.Ring(30), sigma=1e-2)
    data = model.simulate(ob.Scene(directions=[0.5, 2.0], intensities=[1, 1]), rng=6, size=4)
    with pytest.warns(ConvergenceWarning, match="did not meet"):
        res = fit_ml(model, data, 2, options=FastOptions(max_iter=1, n_restarts=0))
    assert not res.converged.all()


@pytest.mark.parametrize(
    "data, k, method, match",
    [
        (np.zeros(29), 1, "fast", "last axis of length 30"),
        (np.full(30, np.nan), 1, "fast", "finite"),
        (np.zeros((2, 2, 30)), 1, "fast", r"\(N,\) or \(T, N\)"),
        (np.zeros(30), 0, "fast", "n_sources"),
        (np.zeros(30), 16, "fast", "n_sources"),
        (np.zeros(30), 1.5, "fast", "n_sources"),
        (np.zeros(30), 1, "newton", "method"),
    ],
)
def test_bad_input(data, k, method, match):
    model = ob.Model(ob.Ring(30), sigma=1e-2)
    with pytest.raises(InputError, match=match):
        fit_ml(model, data, k, method=method)


def test_bad_options():
    model = ob.Model(ob.Ring(30), sigma=1e-2)
    with pytest.raises(InputError, match="model"):
        fit_ml("ring", np.zeros(30), 1)
    with pytest.raises(InputError, match="grid"):
        fit_ml(model, np.zeros(30), 1, grid=np.zeros((5, 2)))
    with pytest.raises(InputError, match="n_starts"):
        fit_ml(model, np.zeros(30), 1, method="multistart",
               options=MultistartOptions(n_starts=0))
    with pytest.raises(InputError, match="rng"):
        fit_ml(model, np.zeros(30), 1, rng=-1)


def test_estimation_errors_match_sources_before_differencing():
    from olsbayes.exchange import estimation_errors

    model = ob.Model(ob.Ring(30), sigma=1e-2)
    truth = np.array([-3.0, 1.0, 3.0, 0.2])
    # the weak source (3.0 -> 3.2) wraps past -pi, so angle order puts it first
    est = model.canonical(np.array([-2.99, 1.01, 3.2, 0.2]))
    np.testing.assert_allclose(est[:2], [3.2 - 2 * np.pi, 0.2])
    err = estimation_errors(model, np.stack([est, est]), truth)
    np.testing.assert_allclose(err, [[0.01, 0.01, 0.2, 0.0]] * 2, atol=1e-12)


def test_batched_covariance_matches_bound_covariance():
    from olsbayes.bounds import bound_covariance

    model = ob.Model(ob.Ring(30), sigma=1e-2)
    x = np.array([[-1.0, 1.0, 2.0, 0.5],  # regular
                  [0.3, 1.0, 0.3, 0.5],  # coincident sources: singular Fisher
                  [0.3, 1.0, 2.5, 0.0]])  # a switched-off source: its angle unidentifiable
    cov = bound_covariance(model.fisher(x))[0]
    for xi, ci in zip(x, cov):
        ref = bound_covariance(model.fisher(xi))[0]
        np.testing.assert_array_equal(np.isinf(ci), np.isinf(ref))
        fin = np.isfinite(ref)
        np.testing.assert_allclose(ci[fin], ref[fin], rtol=1e-10, atol=0)
    assert np.isinf(cov[1]).any() and np.isinf(cov[2]).any() and np.isfinite(cov[0]).all()


def test_largest_identifiable_n_sources_runs():
    # K (d + 1) = N: the coarse K-tuple search has no full-rank tuple and is skipped
    model = ob.Model(ob.Ring(30), sigma=1e-2)
    data = model.simulate(ob.Scene(directions=[0.5, 2.5], intensities=[1.0, 0.7]), rng=8)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        with pytest.warns(ob.ResolutionWarning, match="no finite standard error"):
            res = fit_ml(model, data, 15)  # 13 sources fit noise: no direction, inf std
    assert res.params.shape == (30,) and np.all(res.params[1::2] >= 0)


@pytest.mark.parametrize("method, options, match", [
    ("fast", MultistartOptions(), "must be a FastOptions"),
    ("multistart", FastOptions(), "must be a MultistartOptions"),
    ("fast", {"n_restarts": 2}, "must be a FastOptions"),
    ("slow", None, "method must be one of"),
])
def test_options_must_belong_to_the_method(method, options, match):
    model = ob.Model(ob.Ring(12), 1e-2)
    with pytest.raises(InputError, match=match):
        fit_ml(model, np.zeros(12), 1, method, options=options)


@pytest.mark.parametrize("field, value", [
    ("n_restarts", -1), ("n_restarts", 65), ("restart_scale", 0.0), ("max_iter", 0),
    ("n_coarse", 65), ("tuple_budget", 0), ("runners_up", -1), ("max_sweeps", 0),
    ("dedupe_tol", -1e-4), ("close_spacings", 0.0), ("weak_ratio", -0.5),
    ("pursuit", "yes"), ("kink_cuts", 1), ("n_restarts", 2.5), ("scatter", -1),
    ("scatter", 100_001),
])
def test_fast_options_refuse_bad_values_before_any_work(field, value):
    with pytest.raises(InputError, match=field):
        FastOptions(**{field: value})


@pytest.mark.parametrize("field, value", [("n_starts", 0), ("max_iter", 0), ("n_starts", 1.5)])
def test_multistart_options_refuse_bad_values(field, value):
    with pytest.raises(InputError, match=field):
        MultistartOptions(**{field: value})


def test_fast_options_per_k_defaults_and_structural_refusals():
    """None fields take their per-K defaults; settings a model cannot honour raise."""
    ring = ob.Model(ob.Ring(30), 1e-2)
    sphere = ob.Model(ob.Sphere.fibonacci(40), 1e-2)
    r3, r4 = FastOptions().resolve(ring, 3), FastOptions().resolve(ring, 4)
    assert (r3.n_coarse, r3.distinct_modes, r3.tuple_budget, r3.runners_up, r3.escalate) == (
        3, True, 3000, 0, True)
    assert (r4.n_coarse, r4.pursuit, r4.single_precision, r4.escalate) == (24, False, True, False)
    s2 = FastOptions().resolve(sphere, 2)
    assert (s2.escalate, s2.kink_hops, s2.runners_up) == (False, False, 2)
    assert FastOptions(n_coarse=5).resolve(ring, 4).n_coarse == 5
    assert (r3.scatter, r4.scatter) == (0, 0)
    r5 = FastOptions().resolve(ob.Model(ob.Ring(64), 1e-2), 5)
    assert (r5.scatter, r5.distinct_modes, r5.pursuit) == (300, True, True)
    with pytest.raises(InputError, match="escalate=True"):
        FastOptions(escalate=True).resolve(sphere, 2)
    with pytest.raises(InputError, match="kink_hops=True"):
        FastOptions(kink_hops=True).resolve(sphere, 2)
    with pytest.raises(InputError, match="escalate=True"):
        fit_ml(sphere, np.zeros(40), 2, options=FastOptions(escalate=True))


def test_escalation_runs_by_default_only_where_the_enumeration_is_affordable():
    # sum_{j <= K} C(2M, j) configurations per data vector (M = N crossings on an even
    # ring): the default escalation stops at ESCALATE_CONFIGURATIONS; beyond, K = 3 on
    # a 1000-ring would enumerate ~1.3e9 configurations per fit
    from olsbayes.ml.exact import design_bytes, n_configurations
    from olsbayes.ml.fast.options import ESCALATE_CONFIGURATIONS

    def model(n):
        return ob.Model(ob.Ring(n), 1e-2)

    assert n_configurations(model(30), 3) == sum(math.comb(60, j) for j in range(4))
    assert n_configurations(model(31), 2) == sum(math.comb(124, j) for j in range(3))
    for n, k, on in ((194, 3, True), (196, 3, False), (1000, 3, False), (1000, 2, True),
                     (2234, 2, True), (2236, 2, False), (97, 3, True), (99, 3, False)):
        assert FastOptions().resolve(model(n), k).escalate is on, (n, k)
        assert (n_configurations(model(n), k) <= ESCALATE_CONFIGURATIONS) is on
    # asked for explicitly, the enumeration's O(N^2) arrays are bounded before allocation
    big = model(20_000)
    assert design_bytes(big) > 4 * 2**30
    with pytest.raises(InputError, match="escalate=True on 20000 sub-sensors"):
        FastOptions(escalate=True).resolve(big, 2)
    with pytest.raises(InputError, match="method='exact' on 20000 sub-sensors"):
        fit_ml(big, np.zeros(20_000), 1, "exact")


def _same_gaps(got, ref):
    """Rival gaps equal to rounding, with both finite and infinite ones among them."""
    assert np.isfinite(ref).any() and np.isinf(ref).any()
    np.testing.assert_array_equal(np.isinf(got), np.isinf(ref))
    np.testing.assert_allclose(got, ref, rtol=1e-14)  # x / (2 s^2) vs x * (0.5 / s^2)


def _check_rival_gaps(model, x, alt, rng):
    """rival_gap (compiled where it covers the model) == rival_gap_numpy on fits x (T, P)
    with candidates alt (T, C, P): random candidate chi^2 (a fifth of them none) and
    Fisher std drawn from rng."""
    from olsbayes.ml.rivals import rival_gap, rival_gap_numpy

    t, c = alt.shape[:2]
    alt_chi2 = rng.uniform(0.0, 1e-2, (t, c))
    alt_chi2[rng.uniform(size=(t, c)) < 0.2] = np.inf
    chi2 = np.full(t, 2e-4)
    std = rng.uniform(0.001, 0.02, x.shape)
    _same_gaps(rival_gap(model, x, chi2, (alt, alt_chi2), std),
               rival_gap_numpy(model, x, chi2, alt, alt_chi2, std))


def test_compiled_post_fit_checks_match_numpy():
    """Rival gaps and the close/weak selection: compiled == numpy on random fits."""
    from olsbayes.ml._numba import escalate as ck

    model = ob.Model(ob.Ring(30), 1e-2)
    rng = np.random.default_rng(44)
    t, c, k = 300, 9, 3
    x = model.canonical(np.column_stack([rng.uniform(-np.pi, np.pi, (t, k)),
                                         rng.uniform(0, 1, (t, k))])[:, [0, 3, 1, 4, 2, 5]])
    alt = x[:, None, :] + rng.normal(0, 0.02, (t, c, 2 * k))  # near and far (in std) optima
    _check_rival_gaps(model, x, alt, rng)
    h = 2 * np.pi / 30
    sep = np.abs(ob.wrap_angle(x[:, 0::2][:, :, None] - x[:, 0::2][:, None, :]))
    sep[:, np.arange(k), np.arange(k)] = np.inf
    inten = x[:, 1::2]
    want = (sep.min(axis=(1, 2)) < 4 * h) | (inten.min(1) <= 0.05 * inten.max(1))
    np.testing.assert_array_equal(ck.close_or_weak(x, 4 * h, 0.05), want)


@pytest.mark.parametrize("k", [1, 3, 4])
def test_compiled_rival_gaps_on_a_sphere_match_numpy(k):
    """Sphere fits (lon, lat, I per source): the compiled rival gaps == numpy's, with
    candidates listing their sources in another order, near and far (in std) optima,
    and longitudes across the +-pi seam."""
    model = ob.Model(ob.Sphere.fibonacci(100), 1e-2)
    rng = np.random.default_rng(46 + k)
    t, c = 300, 8
    loc = np.stack([rng.choice([-1.0, 1.0], (t, k)) * rng.uniform(3.0, np.pi, (t, k)),
                    rng.uniform(-1.2, 1.2, (t, k)), rng.uniform(0.2, 1, (t, k))], axis=-1)
    x = model.canonical(loc.reshape(t, 3 * k))
    alt = x[:, None, :] + rng.normal(0, 1, (t, c, 3 * k)) * rng.uniform(1e-4, 0.05, (t, c, 1))
    alt = alt.reshape(t, c, k, 3)[:, :, rng.permutation(k)].reshape(t, c, 3 * k)
    _check_rival_gaps(model, x, alt, rng)


@pytest.mark.parametrize("k", [7, 8])
def test_rival_gaps_beyond_the_compiled_rule_match_it(k):
    """From K = 7 on, rival gaps come from the numpy rule (sources matched by the
    Hungarian algorithm beyond 7): equal to the compiled rule's exhaustive K!
    matching, which the package runs only up to K = 6."""
    from olsbayes.exchange import permutations
    from olsbayes.ml._numba.rivals import far_rival_gap
    from olsbayes.ml.rivals import DISTINCT_STD, RIVAL_RANGE, TIE, rival_gap

    model = ob.Model(ob.Ring(64), 1e-2)
    rng = np.random.default_rng(45 + k)
    t, c = 40, 6
    x = model.canonical(np.stack([rng.uniform(-np.pi, np.pi, (t, k)),
                                  rng.uniform(0, 1, (t, k))], axis=-1).reshape(t, 2 * k))
    alt = x[:, None, :] + rng.normal(0, 1, (t, c, 2 * k)) * rng.uniform(1e-4, 0.02, (t, c, 1))
    perm = rng.permutation(k)  # the candidates list their sources in another order
    alt = alt.reshape(t, c, k, 2)[:, :, perm].reshape(t, c, 2 * k)
    alt_chi2 = rng.uniform(0.0, 1e-3, (t, c))
    chi2 = np.full(t, 2e-4)
    std = rng.uniform(0.002, 0.02, (t, 2 * k))
    got = rival_gap(model, x, chi2, (alt, alt_chi2), std)
    ref = far_rival_gap(x, chi2, alt, alt_chi2, std, 0.5 / model.sigma**2, TIE, RIVAL_RANGE,
                        permutations(k), DISTINCT_STD, 2)
    _same_gaps(got, ref)


def test_rival_gap_numpy_nearest_first_equals_matching_every_candidate():
    """The numpy rule matches candidates nearest first and stops at the first
    distinct one: the same gaps as matching all of them, here with up to 39
    near-copies of the estimate (not distinct) below the first distinct optimum."""
    from olsbayes.exchange import estimation_errors
    from olsbayes.ml.rivals import DISTINCT_STD, RIVAL_RANGE, TIE, rival_gap_numpy

    model = ob.Model(ob.Sphere.grid(6, 8), 1e-2)
    rng = np.random.default_rng(46)
    t, c, k = 60, 40, 3
    x = np.column_stack([rng.uniform(-np.pi, np.pi, (t, k)), rng.uniform(-1.2, 1.2, (t, k)),
                         rng.uniform(0.5, 1, (t, k))])[:, [0, 3, 6, 1, 4, 7, 2, 5, 8]]
    x = model.canonical(x)
    std = np.full((t, 3 * k), 0.01)
    far = rng.uniform(size=(t, c)) < rng.uniform(0.0, 0.1, (t, 1))  # distinct candidates
    alt = x[:, None, :] + rng.normal(0, 1e-3, (t, c, 3 * k)) + far[..., None] * rng.normal(
        0, 0.2, (t, c, 3 * k))
    alt_chi2 = 2e-4 + rng.uniform(0.0, 3e-3, (t, c))
    alt_chi2[rng.uniform(size=(t, c)) < 0.1] = np.inf
    chi2 = np.full(t, 2e-4)
    got = rival_gap_numpy(model, x, chi2, alt, alt_chi2, std)
    gap = (alt_chi2 - chi2[:, None]) / (2 * model.sigma**2)
    ref = np.full(t, np.inf)
    loc = np.arange(3 * k) % 3 != 2
    for i in range(t):
        for j in range(c):
            if TIE < gap[i, j] < RIVAL_RANGE:
                err = estimation_errors(model, alt[i, j], x[i])
                if np.any(np.abs(err[loc]) > DISTINCT_STD * std[i, loc]):
                    ref[i] = min(ref[i], gap[i, j])
    assert np.isfinite(ref).sum() > 20 and np.isinf(ref).sum() > 5
    np.testing.assert_array_equal(got, ref)


def test_eight_source_fits_report_their_rival_optima():
    """Eight sources on a 64-ring at sigma = 0.01: many optima lie within a few
    log-likelihood units of each other, and the fit reports the ones it reached
    (finite rival gaps, a MultimodalWarning) instead of leaving them unassessed."""
    model = ob.Model(ob.Ring(64), 1e-2)
    angles = np.radians(np.arange(8) * 45.0 + 10.0)
    truth = np.column_stack([angles, np.linspace(0.5, 1.0, 8)]).ravel()
    data = model.simulate(truth, size=3, rng=8)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        res = fit_ml(model, data, 8)
    assert any(w.category is ob.MultimodalWarning for w in seen)
    assert np.all(res.rival_gap >= 0) and np.any(res.rival_gap < 3.0)


def test_a_large_batch_says_so_on_stderr(monkeypatch, capsys):
    """Batches beyond NOTICE_BATCH data vectors x sub-sensors x K^2 print one line
    on stderr before they start; single vectors and small batches print nothing."""
    from olsbayes.ml import plain

    model = ob.Model(ob.Ring(12), 1e-2)
    data = model.simulate(ob.Scene(directions=[0.3], intensities=[1.0]), rng=1, size=3)
    monkeypatch.setattr(plain, "NOTICE_BATCH", 3 * 12 - 1)
    ob.fit_ml(model, data[0], n_sources=1)
    ob.fit_ml(model, data[:2], n_sources=1)
    assert "fitting" not in capsys.readouterr().err
    ob.fit_ml(model, data, n_sources=1)
    (line,) = [x for x in capsys.readouterr().err.splitlines() if "fitting" in x]
    assert line == "olsbayes: fitting 3 data vectors of 12 readings at K = 1 (fast) ..."
