"""Nested evidence from several runs: the combination, the scaled call cap, exactness on K = 1."""

from __future__ import annotations

import math

import numpy as np
import pytest
from reference.quadrature import exact_log_evidence

from olsbayes import Model, Ring
from olsbayes.errors import InputError
from olsbayes.priors import default_priors
from olsbayes.select import NestedOptions
from olsbayes.select.engine import scalar_log_likelihood, scalar_prior_transform
from olsbayes.select.nested import NestedEvidence
from olsbayes.select.nested_error import combine_runs, repeated_log_evidence, scaled_maxcall


def _run(log_z, err):
    return NestedEvidence(log_evidence=log_z, error=err, n_calls=10, n_iter=5, converged=True,
                          seconds=0.0, samples=np.zeros((1, 1)), log_weights=np.zeros(1))


def test_identical_runs_combine_to_the_error_of_the_mean():
    out = combine_runs([_run(-3.0, 0.3)] * 4)
    assert out.log_evidence == pytest.approx(-3.0)
    assert out.between == 0.0 and out.within == pytest.approx(0.3 / 2)
    assert out.error == pytest.approx(0.15) and not out.disagree and out.n_calls == 40


def test_scattered_runs_widen_the_error_and_runs_that_lost_mass_are_flagged():
    # small scatter: between = sd(log Z) / sqrt(R) to first order
    z = np.array([-3.05, -2.95, -3.0])
    out = combine_runs([_run(v, 0.05) for v in z])
    assert out.between == pytest.approx(np.std(z, ddof=1) / math.sqrt(3), rel=0.02)
    assert out.error == pytest.approx(math.hypot(out.within, out.between))
    # one run found a mode worth e^3 more mass: log of the mean, flagged
    lost = combine_runs([_run(-3.0, 0.3), _run(-3.0, 0.3), _run(0.0, 0.3)])
    assert lost.log_evidence == pytest.approx(math.log((2 * math.exp(-3) + 1) / 3))
    assert lost.disagree and lost.spread == pytest.approx(3.0) and lost.error > 0.5


def test_the_call_cap_scales_with_parameters_and_live_points_within_the_memory_budget(
        monkeypatch):
    base = scaled_maxcall(2, 100)
    assert scaled_maxcall(4, 100) > 2 * base and scaled_maxcall(2, 200) == 2 * base
    monkeypatch.setenv("OLSBAYES_MEMORY_LIMIT", "1MB")
    assert scaled_maxcall(8, 200) <= 1e6 / (8 * 12)


@pytest.mark.parametrize(("call", "name"), [
    (lambda: NestedOptions(n_runs=0), "n_runs"),
    (lambda: NestedOptions(maxcall=10), "maxcall"),
    (lambda: scaled_maxcall(4, 4), "n_live"),
    (lambda: scaled_maxcall(2, 100, h_param=0.0), "h_param"),
    (lambda: repeated_log_evidence(lambda x: 0.0, lambda u: u, 1, n_runs=0), "n_runs"),
])
def test_bad_settings_are_refused(call, name):
    with pytest.raises(InputError, match=name):
        call()


def test_combined_error_holds_against_the_exact_evidence_of_one_source():
    """K = 1 on a 16-sensor ring: the exact log Z by quadrature (standard error ~0.01)
    lies within 3 quoted errors of the combined estimate on every seed (a Gaussian
    error fails that with probability 0.003 per seed)."""
    model = Model(Ring(16), 0.05)
    prior = default_priors(model, 1, i_max=2.0)
    for seed in range(2):
        data = model.simulate(np.array([0.7, 0.3]), rng=np.random.default_rng(100 + seed))
        ref, ref_se = exact_log_evidence(model, data, 1, 2.0, 11 + seed)
        out = repeated_log_evidence(scalar_log_likelihood(model, data),
                                    scalar_prior_transform(prior), 2, n_live=40, rng=seed,
                                    periodic=prior.periodic_indices)
        assert out.converged and len(out.runs) == 3
        assert abs(out.log_evidence - ref) < 3 * math.hypot(out.error, ref_se), (seed, out, ref)


@pytest.mark.filterwarnings("ignore:nested sampling stopped")
def test_a_sound_importance_value_is_kept_when_the_nested_runs_are_not_trusted():
    """Runs stopped by their cap err low: a K whose value came from importance sampling
    with a small error and enough effective draws keeps it, and says why; an unsound
    importance value is replaced."""
    import dataclasses

    from olsbayes.ml import fit_ml
    from olsbayes.select.engine import laplace_work, nested_work

    model = Model(Ring(16), 0.05)
    prior = default_priors(model, 1, i_max=2.0)
    data = model.simulate(np.array([0.7, 0.3]), rng=np.random.default_rng(100))
    fit = fit_ml(model, data, 1)
    work = laplace_work(model, 1, (fit, fit.params, float(fit.log_likelihood), "fit_ml"),
                        prior, None)
    sound = dataclasses.replace(work, method="importance", value=-1.0, error=0.1,
                                stats={"mixture_error": 0.1, "mixture_ess": 500.0})
    short = NestedOptions(maxcall=1000, n_live=20, n_runs=2)
    out = nested_work(model, data, sound, prior, short, rng=np.random.default_rng(0))
    assert out.method == "importance" and out.value == -1.0 and out.error == 0.1
    assert out.reasons[-1].endswith("the importance-sampling value is kept")
    assert "maxcall=1000 (2 of 2 runs)" in out.reasons[-1]
    doubtful = dataclasses.replace(sound, stats={"mixture_error": 0.9, "mixture_ess": 5.0})
    out = nested_work(model, data, doubtful, prior, short, rng=np.random.default_rng(0))
    assert out.method == "nested" and out.value != -1.0
