"""Posterior sampling: prior recovery, CRLB agreement, label switching, bad input."""

import numpy as np
import pytest
from scipy import stats

from olsbayes import ConvergenceWarning, InputError, Model, Ring, Sphere
from olsbayes.posterior import sample
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
    return sample(model, data, 2, start=truth, rng=1, progress=False, rhat_max=None)


def test_prior_recovered_without_likelihood():
    """Likelihood off: draws follow the prior (KS per parameter, then uniform p-values)."""
    model = Model(Sphere.fibonacci(20), sigma=0.1)
    prior = default_priors(model, 1, i_max=2.0)
    res = sample(model, np.zeros(20), 1, priors=prior, start="prior", rng=3, progress=False,
                 use_likelihood=False, n_steps=1200)
    draws = res.samples  # (W, D, P)
    tau = max(float(np.max(res.tau)), 1.0)
    step = int(np.ceil(2 * tau))
    pvals = []
    for j, marg in enumerate(prior.marginals):
        # nearly independent draws: every 2 tau-th step of a few walkers far apart
        x = draws[::4, ::step, j].ravel()
        pvals.append(stats.kstest(x, marg.cdf).pvalue)
    assert min(pvals) > 1e-3 / len(pvals)
    assert stats.kstest(pvals, "uniform").pvalue > 1e-3


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


def test_same_rng_same_chains(ring_case):
    model, truth, data = ring_case
    a = sample(model, data, 1, start=truth[:2], rng=7, progress=False, n_steps=300)
    b = sample(model, data, 1, start=truth[:2], rng=np.random.default_rng(7), progress=False,
               n_steps=300)
    np.testing.assert_array_equal(a.samples, b.samples)


def test_ml_seeded_start(ring_case):
    """start=None fits ML itself; an MLResult seeds the same ball without refitting."""
    from olsbayes.ml import fit_ml

    model, truth, data = ring_case
    ml = fit_ml(model, data, 2)
    res = sample(model, data, 2, start=ml, rng=3, progress=False, n_steps=200)
    np.testing.assert_array_equal(res.start, ml.params)
    auto = sample(model, data, 2, rng=3, progress=False, n_steps=200)
    np.testing.assert_allclose(auto.start, ml.params, atol=1e-6)
    with pytest.raises(InputError, match="MLResult"):
        sample(model, data, 1, start=ml, progress=False, n_steps=10)


def test_step_limit_warns(ring_case):
    model, truth, data = ring_case
    with pytest.warns(ConvergenceWarning, match="max_steps=200"):
        res = sample(model, data, 1, start=truth[:2], rng=2, progress=False, max_steps=200)
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
                 n_steps=1500)
    assert res.switch_fraction > 0.2  # the raw draws swap labels
    x = res.flat_samples
    from olsbayes.geometry import wrap_angle

    # cyclic order from the pivot (the largest gap, near 0): theta[0] ~ pi - 0.4 first
    assert np.all(wrap_angle(x[:, 2] - x[:, 0]) > 0)
    # every relabelled draw within 6 CRLB sd of the truth: no swapped draw is left
    assert np.all(np.abs(wrap_angle(x - truth)) < 6 * res.crlb_std)
    table = res.summary()
    np.testing.assert_allclose(table["mean"].to_numpy(), truth, atol=4 * res.crlb_std.max())
    check = res.crlb_check()
    assert np.all(np.abs(check.ratio - 1.0) < 0.2), check.to_frame()


def test_relabel_recovers_permuted_draws():
    rng = np.random.default_rng(0)
    base = np.array([np.pi - 0.05, 1.0, 1.0, 0.5, -1.5, 0.3])  # one source at +-pi
    draws = base + 0.01 * rng.standard_normal((2000, 6))
    perms = np.array([rng.permutation(3) for _ in range(2000)])
    blocks = draws.reshape(-1, 3, 2)
    mixed = np.take_along_axis(blocks, perms[:, :, None], axis=1).reshape(-1, 6)
    fixed, _ = relabel(mixed, 3, np.array([True, False]))
    from olsbayes.geometry import wrap_angle

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
    from olsbayes.geometry import wrap_angle

    fb = fixed.reshape(-1, 3, 3)
    for s in range(3):
        assert np.abs(wrap_angle(fb[:, s, 0] - fb[0, s, 0])).max() < 0.3
        assert np.abs(fb[:, s, 1] - fb[0, s, 1]).max() < 0.3  # never jumps lat +-0.6


def test_bad_input(ring_case):
    model, truth, data = ring_case
    with pytest.raises(InputError, match="n_walkers"):
        sample(model, data, 2, start=truth, n_walkers=7, progress=False)
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
