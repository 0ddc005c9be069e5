"""Posteriors under other noise models: Poisson counts, an unknown sigma, nuisance terms."""

import numpy as np
import pytest
from scipy import stats

import olsbayes as ob
from olsbayes.noise import GaussianUnknown, Poisson
from olsbayes.posterior import SamplerOptions
from olsbayes.priors import CircularUniform, ScenePrior, Uniform


def _grid(model, i_max, n_th=360, n_i=200):
    th = np.linspace(-np.pi, np.pi, n_th, endpoint=False)
    ii = (np.arange(n_i) + 0.5) / n_i * i_max
    unit = model.response(np.stack([th, np.ones_like(th)], -1))
    return th, ii, unit


def _poisson_loglik(counts, e, d, ii, unit):
    lam = e * (ii[None, :, None] * unit[:, None, :] + d)  # (theta, I, N)
    return np.sum(counts * np.log(lam) - lam, axis=-1)


def _cdfs(ll, th, ii, truth):
    w = np.exp(ll - ll.max())
    w /= w.sum()
    return np.array([w[th < truth[0]].sum(), w[:, ii < truth[1]].sum()])


def test_poisson_sbc_is_uniform_where_a_gaussian_model_is_not():
    """SBC at 5-20 counts per sensor (exact grid posteriors, K = 1): Poisson calibrated.

    The Gaussian model of the same counts with one sigma (sqrt of the mean count)
    visibly fails: its central 90 % intensity intervals cover the truth in fewer
    than 0.90 - 3 sd of a binomial proportion of the replicates.
    """
    n, e, d, i_max, reps = 24, 1.0, 0.5, 20.0, 200
    model = ob.Model(ob.Ring(n), noise=Poisson(exposure=e, dark=d))
    th, ii, unit = _grid(model, i_max)
    gen = np.random.default_rng(2024)
    cp, cg = [], []
    for _ in range(reps):
        truth = np.array([gen.uniform(-np.pi, np.pi), gen.uniform(0, i_max)])
        counts = model.simulate(truth, rng=gen)
        cp.append(_cdfs(_poisson_loglik(counts, e, d, ii, unit), th, ii, truth))
        s = np.sqrt(max(counts.mean(), 1.0)) / e
        resid = counts / e - d - ii[None, :, None] * unit[:, None, :]
        cg.append(_cdfs(-0.5 * np.sum(resid**2, axis=-1) / s**2, th, ii, truth))
    p_pois = [stats.kstest(np.array(cp)[:, j], "uniform").pvalue for j in range(2)]
    cover = np.mean((np.array(cg) > 0.05) & (np.array(cg) < 0.95), axis=0)
    assert min(p_pois) > 0.01, p_pois
    assert cover[1] < 0.90 - 3 * np.sqrt(0.09 / reps), cover


def test_poisson_posterior_matches_the_exact_grid_posterior():
    """emcee on counts: posterior mean and sd of (theta, I) as the exact grid's."""
    n, e, d, i_max = 24, 1.0, 0.5, 40.0
    model = ob.Model(ob.Ring(n), noise=Poisson(exposure=e, dark=d))
    truth = np.array([np.pi / 24, 15.0])
    counts = model.simulate(truth, rng=8)
    prior = ScenePrior(model, 1, Uniform(0.0, i_max), location=(CircularUniform(),))
    post = ob.sample_posterior(model, counts, 1, priors=prior, rng=3, progress=False)
    th, ii, unit = _grid(model, i_max, 2000, 600)
    ll = _poisson_loglik(counts, e, d, ii, unit)
    w = np.exp(ll - ll.max())
    w /= w.sum()
    c = th[np.argmax(w.sum(axis=1))]
    dth = ob.wrap_angle(th - c)
    m_th, m_i = c + w.sum(axis=1) @ dth, w.sum(axis=0) @ ii
    sd_th = np.sqrt(w.sum(axis=1) @ (dth - (m_th - c)) ** 2)
    sd_i = np.sqrt(w.sum(axis=0) @ (ii - m_i) ** 2)
    x = post.samples.reshape(-1, 2)
    ess = np.prod(post.samples.shape[:2]) / np.max(post.tau)
    err = np.abs(post.estimate - [m_th, m_i])
    assert np.all(err < 4 * np.array([sd_th, sd_i]) / np.sqrt(ess)), (err, ess)
    sd = np.array([np.std(ob.wrap_angle(x[:, 0] - m_th)), x[:, 1].std()])
    assert np.all(np.abs(sd / [sd_th, sd_i] - 1) < 4 / np.sqrt(2 * ess)), (sd, sd_th, sd_i)


def test_poisson_posterior_sd_equals_the_crlb_at_high_counts():
    """Thousands of counts: posterior sd / CRLB = 1 within the Monte Carlo error."""
    model = ob.Model(ob.Ring(30), noise=Poisson(exposure=100.0, dark=5.0))
    counts = model.simulate(np.array([2 * np.pi / 30, 50.0]), rng=9)
    post = ob.sample_posterior(model, counts, 1, rng=4, progress=False)
    check = post.crlb_check()
    assert not np.any(check.flagged), check
    assert np.all(np.abs(check.ratio - 1.0) < 4 * check.mc_error), check


def test_unknown_sigma_is_sampled_with_the_sources(rng):
    """sigma is the last parameter; its posterior sd about sigma / sqrt(2 N F)."""
    n, f = 30, 4
    model = ob.Model(ob.Ring(n), noise=GaussianUnknown(0.05))
    frames = model.simulate(np.array([0.3, 1.0]), rng=rng, n_frames=f)
    post = ob.sample_posterior(model, frames, 1, frames=True, rng=5, progress=False,
                               options=SamplerOptions(n_steps=3000))
    assert post.names[-1] == "sigma"
    sig = post.samples[..., -1].ravel()
    assert abs(sig.mean() - 0.05) < 4 * 0.05 / np.sqrt(2 * n * f)
    assert sig.std() == pytest.approx(0.05 / np.sqrt(2 * n * f), rel=0.15)
    assert 0.001 < post.model_check().ppp < 0.999


def test_background_and_gains_are_sampled():
    """Poisson counts with a background and gains known to 5 %: both sampled, no warnings."""
    from olsbayes.priors import LogNormal

    n = 12
    g = np.exp(0.05 * np.random.default_rng(1).standard_normal(n))
    nu = ob.Nuisance(gains=g, background=3.0, gain_prior=LogNormal(0.0, 0.05),
                     background_prior=Uniform(0.0, 30.0))
    model = ob.Model(ob.Ring(n), noise=Poisson(exposure=10.0, dark=1.0), nuisance=nu)
    counts = model.simulate(np.array([0.2, 30.0]), rng=10)
    post = ob.sample_posterior(model, counts, 1, rng=6, progress=False,
                               options=SamplerOptions(n_steps=2000))
    assert post.names[2] == "b" and post.names[3] == "g[0]" and len(post.names) == 2 + 1 + n
    b = post.samples[..., 2].ravel()
    assert abs(b.mean() - 3.0) < 4 * b.std()


def test_priors_must_carry_the_models_extras():
    model = ob.Model(ob.Ring(10), noise=GaussianUnknown(0.1))
    bare = ScenePrior(model, 1, Uniform(0.0, 2.0))
    with pytest.raises(ob.InputError, match="extra parameters"):
        ob.sample_posterior(model, np.zeros(10), 1, priors=bare, rng=1, progress=False)
