"""Posterior sampling: prior recovery, CRLB agreement, label switching, bad input."""

import numpy as np
import pytest
from scipy import stats

from olsbayes import ConvergenceWarning, InputError, Model, Plate, Ring, Sphere
from olsbayes.posterior import SamplerOptions, sample
from olsbayes.posterior._labels import relabel
from olsbayes.priors import HalfNormal, ScenePrior, Uniform, default_priors


@pytest.fixture(scope="module")
def ring_case():
    model = Model(Ring(30), sigma=0.01)
    truth = np.array([0.3, 1.0, 0.3 + np.pi, 0.2])  # Fig. 3: I = 1.0 and 0.2, pi apart
    data = model.simulate(truth, rng=0)
    return model, truth, data


@pytest.fixture(scope="module")
def ring_result(ring_case):
    model, truth, data = ring_case
    return sample(model, data, 2, start=truth, rng=1, progress=False,
                  options=SamplerOptions(rhat_max=None))


def _prior_only_pvalues(model, prior, k, rng):
    """KS p-values of every parameter of a likelihood-free run against its prior marginal."""
    opts = SamplerOptions(use_likelihood=False, n_steps=800, relabel_sources=False)
    res = sample(model, np.zeros(model.n_sensors), k, priors=prior, start="prior", rng=rng,
                 progress=False, options=opts)
    draws = res.samples  # (W, D, P), raw exchangeable labels
    step = int(np.ceil(2 * max(float(np.max(res.tau)), 1.0)))
    # nearly independent draws: every 2 tau-th step of every 4th walker
    return [stats.kstest(draws[::4, ::step, j].ravel(), marg.cdf).pvalue
            for j, marg in enumerate(prior.marginals)]


def test_prior_recovered_without_likelihood():
    """Likelihood off: draws follow the prior (KS per parameter, then one uniformity test
    over all p-values).  Covers the circle (K = 2, raw labels), the isotropic sphere, the
    plate box, log-uniform intensities and a log-uniform noise sigma."""
    ring = Model(Ring(12), sigma=0.1)
    sph = Model(Sphere.fibonacci(20), sigma=0.1)
    plate = Model(Plate.grid(3, 3), sigma=0.1)
    cases = [
        (ring, default_priors(ring, 2, i_max=2.0, intensity="loguniform", infer_sigma=True), 2),
        (sph, default_priors(sph, 1, i_max=2.0), 1),
        (plate, default_priors(plate, 1, i_max=2.0), 1),
    ]
    pvals = [p for i, (m, pr, k) in enumerate(cases) for p in _prior_only_pvalues(m, pr, k, i)]
    assert len(pvals) == 5 + 3 + 4
    assert min(pvals) > 1e-3 / len(pvals)  # Bonferroni over the parameters
    assert stats.kstest(pvals, "uniform").pvalue > 1e-3


def test_sigma_inferred_matches_exact_marginal():
    """Noise sd inferred under a log-uniform prior.  At high SNR the model is linear near the
    optimum, so integrating out the P location/intensity parameters gives
    p(sigma | d) ~ sigma^-(N-P+1) exp(-S/(2 sigma^2)), S the residual sum of squares at the
    ML point: 1/sigma^2 ~ Gamma((N-P)/2, rate S/2).  Mean and sd of sigma must match within
    3 Monte Carlo standard errors; the sd exceeds the CRLB sigma/sqrt(2N) by the known
    factor (P parameters are estimated too), so crlb_check does not flag it."""
    from scipy.special import gammaln

    from olsbayes.ml import fit_ml

    model = Model(Ring(30), sigma=0.01)
    data = model.simulate(np.array([1.0, 1.0]), rng=20)  # 3.3 deg from a horizon: no kink
    ml = fit_ml(model, data, 1)
    a = (model.n_sensors - 2) / 2
    b = float(np.sum((data - model.response(ml.params)) ** 2)) / 2
    mean = np.sqrt(b) * np.exp(gammaln(a - 0.5) - gammaln(a))
    sd = np.sqrt(b / (a - 1) - mean**2)
    prior = default_priors(model, 1, i_max=2.0, infer_sigma=True)
    res = sample(model, data, 1, priors=prior, start=ml, rng=0, progress=False)
    assert res.converged and res.names[-1] == "sigma"
    row = res.summary().loc["sigma"]
    assert abs(row["mean"] - mean) < 3 * row["mcse_mean"]
    assert abs(row["sd"] - sd) < 3 * row["mcse_sd"]
    check = res.crlb_check()
    expected = np.sqrt(2 * model.n_sensors) * sd / mean  # sd over CRLB at the posterior mean
    assert abs(check.ratio[-1] - expected) < 3 * check.mc_error[-1] + 1e-3
    assert check.ok, check.to_frame()
    # log-likelihood per sub-sensor uses each draw's own sigma
    ll = res.idata.log_likelihood["obs"].values.sum(-1)
    lp = res.idata.sample_stats["lp"].values - res.idata.sample_stats["log_prior"].values
    np.testing.assert_allclose(ll, lp, rtol=1e-10)


def test_crlb_check_flags_low_snr_with_reasons():
    """Low SNR: the direction's posterior is much wider than the CRLB, flagged with reasons."""
    model = Model(Ring(16), sigma=0.5)
    truth = np.array([1.0, 0.5])
    data = model.simulate(truth, rng=2)
    prior = default_priors(model, 1, i_max=3.0)
    res = sample(model, data, 1, priors=prior, start=truth, rng=1, progress=False)
    check = res.crlb_check()
    assert not check.ok
    assert check.flagged[0] and check.ratio[0] > 1.2 + 3 * check.mc_error[0]
    assert "low SNR" in check.reasons[0] and "prior-dominated" in check.reasons[0]
    frame = check.to_frame()
    assert list(frame.columns) == ["posterior_sd", "crlb_sd", "ratio", "mc_error", "flagged",
                                   "reason"]


def test_crlb_reasons_tell_resolution_limit_from_within_source_correlation():
    """Plate, two sources: each source's z and I are strongly correlated (a geometric
    degeneracy of one source, not a resolution limit); only the I[0]-I[1] correlation
    between the two sources is reported as the resolution limit."""
    plate = Model(Plate.grid(4, 4), sigma=0.01)
    truth = np.array([-0.7, -0.5, 1.0, 1.0, 0.8, 0.6, 1.2, 0.7])
    data = plate.simulate(truth, rng=3)
    res = sample(plate, data, 2, priors=default_priors(plate, 2, i_max=3.0), start=truth,
                 rng=1, progress=False, options=SamplerOptions(n_steps=300))
    corr = res.crlb_cov / np.outer(res.crlb_std, res.crlb_std)
    assert abs(corr[2, 3]) > 0.9 and abs(corr[3, 7]) > 0.9 and abs(corr[2, 7]) < 0.9
    reasons = dict(zip(res.names, res.crlb_check().reasons))
    assert "strongly correlated (CRLB |r| = " in reasons["z[0]"] and "with I[0]" in reasons["z[0]"]
    assert "resolution" not in reasons["z[0]"] and "resolution" not in reasons["x[0]"]
    assert "near the resolution limit (CRLB |r| = " in reasons["I[0]"]
    assert "with I[1])" in reasons["I[0]"]


def test_short_run_has_no_arviz_shape_warning(ring_case):
    """More walkers than stored draws is legitimate: no ArviZ shape warning (-> error here)."""
    model, truth, data = ring_case
    res = sample(model, data, 1, start=truth[:2], rng=0, progress=False,
                 options=SamplerOptions(n_steps=40))
    assert res.samples.shape[0] > res.samples.shape[1]
    assert np.all(np.isfinite(res.summary()["sd"]))


def test_high_snr_posterior_width_matches_crlb(ring_result):
    res = ring_result
    assert res.converged
    check = res.crlb_check()
    # posterior sd / CRLB equals 1 within 3 Monte Carlo standard errors
    assert np.all(np.abs(check.ratio - 1.0) < 3 * check.mc_error + 1e-3), check.to_frame()
    assert check.ok
    table = res.summary()
    assert np.all(table["r_hat"] < 1.05) and np.all(table["ess_bulk"] > 400)
    # the truth lies within 4 CRLB sd of the posterior mean (labels: cyclic order)
    est = res.estimate
    order = np.argsort(np.abs(est[[0, 2]] - (0.3 + np.pi - 2 * np.pi)))
    assert order[0] == 0  # source 0 is the one at 0.3 + pi, wrapped to -2.84
    assert np.all(np.abs(est - truth_relabelled(est)) < 4 * res.crlb_std)


def truth_relabelled(est):
    return np.array([0.3 + np.pi - 2 * np.pi, 0.2, 0.3, 1.0])


@pytest.mark.parametrize("geometry", ["sphere", "plate"])
def test_sphere_and_plate_posteriors(geometry):
    """One source on the sphere (longitude at the +-pi edge) and over a plate: the ML-seeded
    ensemble converges, the circular longitude summary has sd ~ CRLB (not ~pi), the truth
    lies within 4 CRLB sd, and crlb_check raises no flag at high SNR."""
    from olsbayes.circular import wrap_angle

    if geometry == "sphere":
        model = Model(Sphere.fibonacci(40), sigma=0.01)
        truth = np.array([np.pi - 0.01, 0.2, 1.0])
    else:
        model = Model(Plate.grid(4, 4), sigma=0.01)
        truth = np.array([0.3, -0.4, 1.0, 1.0])
    data = model.simulate(truth, rng=12)
    res = sample(model, data, 1, rng=2, progress=False)
    assert res.converged
    err = res.estimate - truth
    err[res.periodic] = wrap_angle(err[res.periodic])
    assert np.all(np.abs(err) < 4 * res.crlb_std)
    check = res.crlb_check()
    assert check.ok, check.to_frame()
    assert np.all(res.summary()["sd"] < 1.3 * res.crlb_std)  # lon near +-pi: not ~pi


def test_same_rng_same_chains(ring_case):
    model, truth, data = ring_case
    opts = SamplerOptions(n_steps=300)
    a = sample(model, data, 1, start=truth[:2], rng=7, progress=False, options=opts)
    b = sample(model, data, 1, start=truth[:2], rng=np.random.default_rng(7), progress=False,
               options=opts)
    np.testing.assert_array_equal(a.samples, b.samples)


def test_ml_seeded_start(ring_case):
    """start=None fits ML itself; an MLResult seeds the same ball without refitting."""
    from olsbayes.ml import fit_ml

    model, truth, data = ring_case
    ml = fit_ml(model, data, 2)
    opts = SamplerOptions(n_steps=200)
    res = sample(model, data, 2, start=ml, rng=3, progress=False, options=opts)
    np.testing.assert_array_equal(res.start, ml.params)
    auto = sample(model, data, 2, rng=3, progress=False, options=opts)
    np.testing.assert_allclose(auto.start, ml.params, atol=1e-6)
    with pytest.raises(InputError, match="MLResult"):
        sample(model, data, 1, start=ml, progress=False, options=opts)


def test_step_limit_warns(ring_case):
    model, truth, data = ring_case
    with pytest.warns(ConvergenceWarning, match="max_steps=200"):
        res = sample(model, data, 1, start=truth[:2], rng=2, progress=False,
                     options=SamplerOptions(max_steps=200))
    assert not res.converged


def test_label_switching_near_pi():
    """Walkers in both labelled modes of two sources straddling +-pi: differential-evolution
    moves swap raw labels; relabelled draws are unimodal and circular summaries give
    sd ~ CRLB, not ~pi, with means near the +-pi edge."""
    model = Model(Ring(30), sigma=0.02)
    truth = np.array([np.pi - 0.4, 1.0, -np.pi + 0.4, 0.8])
    swapped = truth[[2, 3, 0, 1]]
    data = model.simulate(truth, rng=4)
    prior = default_priors(model, 2, i_max=3.0)
    gen = np.random.default_rng(6)
    start = np.concatenate([truth + 0.005 * gen.standard_normal((16, 4)),
                            swapped + 0.005 * gen.standard_normal((16, 4))])
    res = sample(model, data, 2, priors=prior, start=start, rng=5, progress=False,
                 options=SamplerOptions(n_steps=1500))
    assert res.switch_fraction > 0.2  # the raw draws swap labels
    x = res.flat_samples
    from olsbayes.circular import wrap_angle

    # no anchor (an ensemble start): sources in the canonical order of their circular
    # means, as Model.canonical sorts an ML fit: theta[0] ~ -pi + 0.4 first
    assert np.all(wrap_angle(x[:, 2] - x[:, 0]) < 0)
    # every relabelled draw within 6 CRLB sd of the truth: no swapped draw is left
    assert np.all(np.abs(wrap_angle(x - swapped)) < 6 * res.crlb_std)
    table = res.summary()
    np.testing.assert_allclose(table["mean"].to_numpy(), swapped, atol=4 * res.crlb_std.max())
    check = res.crlb_check()
    assert np.all(np.abs(check.ratio - 1.0) < 0.2), check.to_frame()


def test_tau_follows_the_relabelled_parameters(ring_case):
    """Walkers started with the sources in the reverse of the canonical order: the summary's
    tau of theta[0] is the tau of the sampler coordinate that became theta[0]."""
    model, truth, data = ring_case
    # bright source first; the canonical (cyclic) order puts the faint one first here,
    # as test_high_snr_posterior_width_matches_crlb checks
    kw = dict(start=truth, rng=8, progress=False)
    raw = sample(model, data, 2, options=SamplerOptions(n_steps=400, relabel_sources=False),
                 **kw)
    # same rng: the same chains, relabelled afterwards
    fixed = sample(model, data, 2, options=SamplerOptions(n_steps=400), **kw)
    assert fixed.switch_fraction == 0.0
    np.testing.assert_allclose(fixed.estimate[[0, 2]] % (2 * np.pi),
                               raw.estimate[[2, 0]] % (2 * np.pi), atol=1e-12)
    np.testing.assert_array_equal(fixed.tau, raw.tau[[2, 3, 0, 1]])
    np.testing.assert_array_equal(fixed.summary()["tau"].to_numpy(), fixed.tau)


def test_relabel_recovers_permuted_draws():
    rng = np.random.default_rng(0)
    base = np.array([np.pi - 0.05, 1.0, 1.0, 0.5, -1.5, 0.3])  # one source at +-pi
    draws = base + 0.01 * rng.standard_normal((2000, 6))
    perms = np.array([rng.permutation(3) for _ in range(2000)])
    blocks = draws.reshape(-1, 3, 2)
    mixed = np.take_along_axis(blocks, perms[:, :, None], axis=1).reshape(-1, 6)
    fixed, _ = relabel(mixed, 3, np.array([True, False]))
    from olsbayes.circular import wrap_angle

    fb = fixed.reshape(-1, 3, 2)
    for s in range(3):
        spread = np.abs(wrap_angle(fb[:, s, 0] - fb[0, s, 0]))
        assert spread.max() < 0.2
    assert np.allclose(np.sort(wrap_angle(fb[0, :, 0])),
                       np.sort(wrap_angle(base[[0, 2, 4]])), atol=0.1)


def test_relabel_on_the_sphere():
    """Sources at the same longitude (lon order is useless) and one across the dateline."""
    rng = np.random.default_rng(1)
    base = np.array([np.pi - 0.01, 0.6, 1.0, np.pi - 0.01, -0.6, 0.5, 0.5, 0.0, 0.8])
    draws = base + 0.02 * rng.standard_normal((3000, 9))
    perms = np.array([rng.permutation(3) for _ in range(3000)])
    mixed = np.take_along_axis(draws.reshape(-1, 3, 3), perms[:, :, None], axis=1)
    fixed, _ = relabel(mixed.reshape(-1, 9), 3, np.array([True, False, False]))
    from olsbayes.circular import wrap_angle

    fb = fixed.reshape(-1, 3, 3)
    for s in range(3):
        assert np.abs(wrap_angle(fb[:, s, 0] - fb[0, s, 0])).max() < 0.3
        assert np.abs(fb[:, s, 1] - fb[0, s, 1]).max() < 0.3  # never jumps lat +-0.6


def test_bad_input(ring_case):
    model, truth, data = ring_case
    with pytest.raises(InputError, match="n_walkers"):
        sample(model, data, 2, start=truth, options=SamplerOptions(n_walkers=7), progress=False)
    with pytest.raises(InputError, match="start"):
        sample(model, data, 2, start=np.array([0.3, np.nan, 2.0, 0.2]), progress=False)
    prior = ScenePrior(model, 2, Uniform(0.0, 0.5))
    with pytest.raises(InputError, match="outside the prior support"):
        sample(model, data, 2, priors=prior, start=truth, progress=False)
    with pytest.raises(InputError, match="location prior of theta"):
        ScenePrior(model, 2, Uniform(0.0, 2.0), location=(HalfNormal(1.0),))
    with pytest.raises(InputError, match="priors were built"):
        sample(model, data, 2, priors=default_priors(model, 1, i_max=2.0), start=truth,
               progress=False)
    with pytest.raises(InputError, match="start ensemble"):
        sample(model, data, 2, start=np.tile(truth, (5, 1)), progress=False)
    with pytest.raises(InputError, match="linearly independent"):
        sample(model, data, 2, start=np.tile(truth, (32, 1)), progress=False)
    with pytest.raises(InputError, match="data"):
        sample(model, data[:10], 2, start=truth, progress=False)


@pytest.mark.parametrize(("field", "value"), [
    ("n_walkers", 1), ("n_walkers", 8.0), ("max_steps", 0), ("n_steps", 0), ("n_steps", 2.5),
    ("tau_multiple", 0.0), ("tau_multiple", np.inf), ("rhat_max", -1.01), ("rhat_max", "1.01"),
    ("check_every", 0), ("n_burn", -1), ("thin", 0), ("moves", "hmc"), ("moves", []),
    ("moves", [("de", 1.0)]), ("vectorize", "yes"), ("relabel_sources", 1),
    ("use_likelihood", None),
])
def test_sampler_options_refuse_bad_values_naming_the_field(field, value):
    with pytest.raises(InputError, match=field):
        SamplerOptions(**{field: value})


def test_sampler_options_accept_emcee_moves():
    import emcee

    de = emcee.moves.DEMove()
    assert SamplerOptions(moves=de).moves is de
    mix = [(emcee.moves.DEMove(), 0.7), (emcee.moves.StretchMove(), 0.3)]
    assert SamplerOptions(moves=mix).moves is mix
    with pytest.raises(InputError, match="moves"):
        SamplerOptions(moves=[(de, 0.0)])


def test_bad_arguments_are_refused_before_the_ml_fit(ring_case, monkeypatch):
    """start=None fits ML first: every argument is checked before that fit runs."""
    import olsbayes.ml
    import olsbayes.posterior._start

    def no_fit(*args, **kwargs):
        raise AssertionError("the ML fit ran before the arguments were checked")

    monkeypatch.setattr(olsbayes.ml, "fit_ml", no_fit)
    monkeypatch.setattr(olsbayes.posterior._start, "fit_ml", no_fit)
    model, truth, data = ring_case
    cases = [
        ({"options": SamplerOptions(n_walkers=7)}, "n_walkers must be >= 2 \\* n_params = 8"),
        ({"options": {"moves": "hmc"}}, "options must be"),
        ({"start": "middle"}, "start"),
        ({"priors": "flat"}, "priors"),
        ({"rng": -1}, "rng"),
        ({"progress": "no"}, "progress"),
    ]
    for kwargs, match in cases:
        with pytest.raises(InputError, match=match):
            sample(model, data, 2, **kwargs)
    with pytest.raises(InputError, match="moves"):
        sample(model, data, 2, options=SamplerOptions(moves="hmc"))
    with pytest.raises(InputError, match="rhat_max"):
        sample(model, data, 2, options=SamplerOptions(rhat_max=0.0))


def test_rng_and_options_are_keyword_only(ring_case):
    model, truth, data = ring_case
    with pytest.raises(TypeError):
        sample(model, data, 2, None, truth)  # priors, start positionally
