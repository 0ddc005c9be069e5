"""Honesty warnings: a result that cannot be trusted says so, and never changes its numbers.

fit_ml: infinite/NaN standard errors (ResolutionWarning) and chi^2 in a tail of
chi^2(N - P) (ConvergenceWarning, with the p-value); select_k: the chosen K at
k_max (EvidenceWarning); sample: a posterior sd far below the CRLB at high SNR
(ConvergenceWarning); the sampler's burn-in: refused or honoured, never quietly cut.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.stats import chi2 as chi2_law

import olsbayes as ob
from olsbayes.ml.honesty import GOF_ALPHA, gof_pvalues

MODEL = ob.Model(ob.Ring(30), 0.01)
TWO = ob.Scene(directions=[0.3, 2.0], intensities=[1.0, 0.5])
DATA = MODEL.simulate(TWO, rng=1)


def _fit_both(model, data, k, **kw):
    """The fit with warnings recorded, and the same fit with warn=False."""
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        res = ob.fit_ml(model, data, k, **kw)
    quiet = ob.fit_ml(model, data, k, warn=False, **kw)
    np.testing.assert_array_equal(res.params, quiet.params)  # warnings change nothing
    np.testing.assert_array_equal(res.cov, quiet.cov)
    return res, [(w.category, str(w.message)) for w in seen]


@pytest.mark.parametrize(
    "model,k",
    [(ob.Model(ob.Ring(4), 0.01), 2), (MODEL, 8), (MODEL, 15)],
    ids=["ring4-K2", "ring30-K8", "ring30-K15"],
)
def test_infinite_standard_errors_warn(model, k):
    res, seen = _fit_both(model, model.simulate(TWO, rng=1), k)
    assert not np.all(np.isfinite(res.std))
    assert any(c is ob.ResolutionWarning and "no finite standard error" in m for c, m in seen)


@pytest.mark.parametrize("factor,side", [(0.1, "more sources than K"),
                                         (3.0, "sigma overestimated")])
def test_wrong_sigma_fails_the_goodness_of_fit(factor, side):
    res, seen = _fit_both(MODEL.with_sigma(0.01 * factor), DATA, 2)
    msgs = [m for c, m in seen if c is ob.ConvergenceWarning]
    assert len(msgs) == 1 and side in msgs[0] and "two-sided p = " in msgs[0]
    assert bool(res.converged)  # converged, yet not a description of the readings


def test_too_few_sources_fail_the_goodness_of_fit():
    _, seen = _fit_both(MODEL, DATA, 1)
    assert any(c is ob.ConvergenceWarning and "chi^2/(N-P) = " in m for c, m in seen)


def test_good_fits_do_not_warn():
    data = MODEL.simulate(TWO, rng=2, size=200)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ob.fit_ml(MODEL, data, 2)


def test_goodness_of_fit_p_values_follow_the_chi2_law():
    """Under the model chi^2/sigma^2 ~ chi^2(N - P): p-values roughly uniform, few below alpha."""
    data = MODEL.simulate(TWO, rng=3, size=400)
    res = ob.fit_ml(MODEL, data, 2, warn=False)
    z, p, dof = gof_pvalues(MODEL, res.log_likelihood, 4)
    assert dof == 26
    resid = data - MODEL.response(res.params)
    np.testing.assert_allclose(z, np.sum(resid**2, axis=1) / 0.01**2, rtol=1e-8)
    np.testing.assert_allclose(p, 2 * np.minimum(chi2_law.cdf(z, 26), chi2_law.sf(z, 26)))
    assert 0.35 < np.mean(p < 0.5) < 0.65  # binomial(400, 0.5): +-6 sd
    assert np.sum(p < GOF_ALPHA) <= 3


@pytest.mark.parametrize("dof", [1, 2, 26, 997, 9996])
@pytest.mark.parametrize("alpha", [GOF_ALPHA, GOF_ALPHA / 500, 1.5e-12])
def test_the_goodness_of_fit_screen_passes_only_what_the_test_passes(dof, alpha):
    """The screen fit_ml runs first (a band of chi^2 / sigma^2 with no p-value computed)
    holds only values whose two-sided p-value exceeds alpha, and all but those within
    its 1e-6 margins.  Probed at relative offsets 1e-10..1e-2 around each quantile
    (the lower one of 1 degree of freedom is ~1e-24) and across the middle; at the
    level 1.5e-12, 1 - alpha / 2 rounds down, so a lower quantile taken from the
    survival function would be 1e-4 too low."""
    from olsbayes.ml.honesty import _gof_band

    lo, hi = _gof_band(dof, alpha)
    r = np.logspace(-10, -2, 400)
    edges = [q * (1 + np.concatenate([-r, r])) for q in
             (chi2_law.ppf(alpha / 2, dof), chi2_law.isf(alpha / 2, dof))]
    z = np.concatenate(edges + [np.linspace(edges[0].max(), edges[1].min(), 2001)])
    p = 2 * np.minimum(chi2_law.cdf(z, dof), chi2_law.sf(z, dof))
    inside = (z > lo) & (z < hi)
    assert np.all(p[inside] > alpha)
    near = np.minimum(np.abs(z / edges[0].mean() - 1), np.abs(z / edges[1].mean() - 1))
    assert np.all(inside[(p > alpha) & (near > 2e-6)])  # only the margins are left out


def test_no_readings_left_over_skips_the_goodness_of_fit():
    _, p, dof = gof_pvalues(MODEL, np.array([0.0]), 30)
    assert dof == 0 and np.isnan(p).all()


def test_all_zero_readings_warn_but_fit():
    res, seen = _fit_both(MODEL, np.zeros((5, 30)), 2)
    assert np.all(res.params[:, 1::2] == 0)
    cats = {c for c, _ in seen}
    assert ob.ResolutionWarning in cats and ob.ConvergenceWarning in cats


# ---- select_k ----------------------------------------------------------------------
def test_select_k_warns_when_the_best_k_is_k_max():
    from olsbayes.select import select_k

    scene = ob.Scene(directions=[-2.5, -1.0, 0.6, 2.2], intensities=[1.0, 0.8, 0.9, 0.7])
    data = MODEL.simulate(scene, rng=4)
    with pytest.warns(ob.EvidenceWarning, match="the chosen K = 3 is k_max") as rec:
        res = select_k(MODEL, data, k_max=3, method="laplace", rng=0, i_max=2.0)
    assert res.best == 3 and "is k_max" in res.notes[0]
    assert all("is k_max" not in str(w.message) or w.category is ob.EvidenceWarning for w in rec)


def test_select_k_below_k_max_does_not_warn_about_it():
    from olsbayes.select import select_k

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        res = select_k(MODEL, DATA, k_max=3, method="laplace", rng=0, i_max=2.0)
    assert res.best == 2
    assert not any("is k_max" in str(w.message) for w in seen)


# ---- posterior ----------------------------------------------------------------------
def _narrow_run():
    """Walkers started in a ball 1e-3 CRLB wide and run 20 stretch steps: far too narrow."""
    from olsbayes.posterior import SamplerOptions, sample

    fit = ob.fit_ml(MODEL, DATA, 2)
    start = fit.params + 1e-3 * fit.std * np.random.default_rng(0).standard_normal((32, 4))
    return sample(MODEL, DATA, 2, start=start, rng=2, progress=False,
                  options=SamplerOptions(n_steps=20, n_walkers=32, moves="stretch"))


def test_posterior_far_below_the_crlb_warns():
    with pytest.warns(ob.ConvergenceWarning, match=r"posterior sd far below the CRLB.*I\[1\]"):
        res = _narrow_run()
    check = res.crlb_check()
    assert check.ratio[3] < 0.5 and check.flagged[3]


def test_a_converged_posterior_does_not_warn():
    from olsbayes.posterior import SamplerOptions, sample

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = sample(MODEL, DATA, 2, options=SamplerOptions(n_steps=2000), rng=2,
                     progress=False)
    assert np.all(np.abs(res.crlb_check().ratio - 1) < 0.2)


@pytest.mark.parametrize("kw,match", [
    (dict(n_steps=100, n_burn=100), "n_burn must be < n_steps = 100"),
    (dict(max_steps=100, n_burn=500), "n_burn must be < max_steps = 100"),
])
def test_burn_in_beyond_the_run_is_refused(kw, match):
    from olsbayes.posterior import SamplerOptions

    with pytest.raises(ob.InputError, match=match):
        SamplerOptions(**kw)


def test_explicit_burn_in_is_honoured():
    from olsbayes.posterior import SamplerOptions, sample

    res = sample(MODEL, DATA, 2, options=SamplerOptions(n_steps=200, n_burn=150), rng=1,
                 progress=False)
    assert res.n_burn == 150 and res.samples.shape[1] == 50  # not cut to half the run


def test_select_k_refuses_unknown_threshold_keys():
    from olsbayes.select import LaplaceOptions

    with pytest.raises(ob.InputError, match="separaton"):
        LaplaceOptions(thresholds={"separaton": 2.0})
