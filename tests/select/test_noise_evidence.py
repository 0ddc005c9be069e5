"""Evidence under other noise models: an unknown sigma integrated, Poisson counts."""

import math

import numpy as np
import pytest
from scipy.special import gammainc, gammaln, logsumexp

import olsbayes as ob
from olsbayes.noise import GaussianUnknown, Poisson
from olsbayes.priors import CircularUniform, LogUniform, ScenePrior, Uniform
from olsbayes.select import SelectOptions
from olsbayes.select.options import NestedOptions


def _log_z_sigma(rss, m, lo, hi):
    """log of int N(resid; 0, s^2 I_m) / (s log(hi / lo)) ds over [lo, hi], closed form."""
    rss = np.asarray(rss, float)
    a = m / 2
    t_lo, t_hi = rss / (2 * hi**2), rss / (2 * lo**2)
    mass = gammainc(a, t_hi) - gammainc(a, t_lo)
    return (-a * np.log(np.pi * rss) + gammaln(a) - np.log(2 * np.log(hi / lo))
            + np.log(mass))


def test_k0_evidence_with_unknown_sigma_matches_the_closed_form(rng):
    """K = 0: the sigma quadrature against the incomplete-gamma closed form."""
    model = ob.Model(ob.Ring(12), noise=GaussianUnknown(0.1))
    data = 0.1 * rng.standard_normal(12)
    res = ob.select_k(model, data, 0)
    expect = float(_log_z_sigma(data @ data, 12, 0.001, 10.0))
    assert res.log_evidence[0] == pytest.approx(expect, abs=1e-6)


def test_k1_evidence_with_unknown_sigma_matches_quadrature():
    """K = 1, sigma integrated: Laplace and nested sampling against a 2-D grid (sigma exact)."""
    n, i_max = 10, 2.0
    model = ob.Model(ob.Ring(n), noise=GaussianUnknown(0.05))
    truth = np.array([0.3, 1.0])
    data = model.simulate(truth, rng=7)
    prior = ScenePrior(model, 1, Uniform(0.0, i_max), location=(CircularUniform(),),
                       extra=(("sigma", LogUniform(0.005, 0.5)),))
    th = np.linspace(-np.pi, np.pi, 4000, endpoint=False)
    ii = (np.arange(3000) + 0.5) / 3000 * i_max
    unit = model.response(np.stack([th, np.ones_like(th)], -1))  # (T, N)
    a, b, c = unit @ unit.T, unit @ data, data @ data  # RSS = c - 2 I b + I^2 a_tt
    rss = c - 2 * ii[None, :] * b[:, None] + ii[None, :] ** 2 * np.diag(a)[:, None]
    lz = _log_z_sigma(rss, n, 0.005, 0.5)
    expect = float(logsumexp(lz) - np.log(lz.size))  # uniform theta and I on the grid
    opts = SelectOptions(nested=NestedOptions(n_live=100, maxcall=300_000))
    with pytest.warns(ob.EvidenceWarning, match="is k_max"):
        lap = ob.select_k(model, data, 1, priors={1: prior}, method="laplace")
    with pytest.warns(ob.EvidenceWarning, match="is k_max"):
        nest = ob.select_k(model, data, 1, priors={1: prior}, method="nested", rng=3,
                           options=opts)
    assert lap.log_evidence[1] == pytest.approx(expect, abs=0.3)
    err = nest.error[1]
    assert abs(nest.log_evidence[1] - expect) < 3 * err + 0.05


def test_poisson_evidence_prefers_the_true_number_of_sources():
    """Counts of two well-separated sources: K = 2 wins; the evidence of K = 0 is exact."""
    model = ob.Model(ob.Ring(30), noise=Poisson(exposure=5.0, dark=1.0))
    x = np.array([0.2, 20.0, 2.6, 10.0])
    counts = model.simulate(x, rng=4)
    res = ob.select_k(model, counts, 3, rng=1)
    assert res.best == 2
    expect = model.log_likelihood(np.zeros(0), counts)
    assert res.log_evidence[0] == pytest.approx(float(expect), rel=1e-12)


def test_poisson_evidence_frames_equal_summed_counts_up_to_a_constant(rng):
    """Frames of one scene: the K comparison is that of the summed counts."""
    expo = np.array([1.0, 2.0])
    model = ob.Model(ob.Ring(24), noise=Poisson(exposure=expo, dark=2.0))
    counts = model.simulate(np.array([0.4, 15.0]), rng=rng)
    joint = ob.select_k(model, counts, 2, frames=True, i_max=100.0, method="laplace")
    summed = ob.select_k(ob.Model(ob.Ring(24), noise=Poisson(3.0, 2.0)), counts.sum(axis=0),
                         2, i_max=100.0, method="laplace")
    d_joint = np.diff(joint.log_evidence)
    d_sum = np.diff(summed.log_evidence)
    np.testing.assert_allclose(d_joint, d_sum, atol=1e-4)


def test_select_k_refuses_counts_that_are_not_counts():
    model = ob.Model(ob.Ring(10), noise=Poisson(1.0))
    with pytest.raises(ob.InputError, match="counts"):
        ob.select_k(model, np.full(10, 1.5), 1)
    with pytest.raises(ob.InputError, match="frames must be True or False"):
        ob.select_k(model, np.ones(10), 1, frames=1)
    assert math.isfinite(ob.select_k(model, np.ones(10), 0).log_evidence[0])
