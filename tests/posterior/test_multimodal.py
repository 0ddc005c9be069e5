"""Near-antipodal pairs, the mode search and the multimodal sampler."""

import warnings

import numpy as np
import pytest

from olsbayes import AntipodalWarning, InputError, Model, MultimodalWarning, Ring, Sphere
from olsbayes.antipodal import antipodal_pairs, mirror_pair
from olsbayes.circular import wrap_angle
from olsbayes.exchange import match_sources
from olsbayes.posterior import ModeOptions, PosteriorResult, SamplerOptions, sample
from olsbayes.posterior.modes import find_modes
from olsbayes.priors import default_priors

# two pairs 0.44 and 0.68 sensor spacings from antipodal on a ring of 30
TRUTH4 = np.array([-2.6, 1.0, -1.05, 0.8, 0.45, 1.2, 1.95, 0.9])
SHORT = SamplerOptions(n_steps=200, rhat_max=None)


@pytest.fixture(scope="module")
def scene4():
    model = Model(Ring(30), sigma=1e-3)
    return model, model.simulate(TRUTH4, rng=0)


@pytest.fixture(scope="module")
def multimodal4(scene4):
    model, data = scene4
    with pytest.warns(MultimodalWarning) as caught:
        res = sample(model, data, 4, rng=3, progress=False, options=SHORT)
    # the multimodal sampler is chosen for the near-antipodal pairs, and the two pairs
    # still warn: sampled intervals of such scenes under-covered in simulation
    said = [(type(w.message), str(w.message)) for w in caught]
    assert any(c is MultimodalWarning and "near-antipodal" in m for c, m in said)
    assert any(c is AntipodalWarning and "covered the truth less often" in m for c, m in said)
    return res


def test_opposite_readings_differ_by_one_cosine():
    """s(alpha) - s(alpha + pi) = sum_k I_k cos(theta_k - alpha) on an even ring."""
    model = Model(Ring(30), sigma=1e-3)
    s = model.response(TRUTH4)
    alpha = np.arctan2(model.array.normals[:, 1], model.array.normals[:, 0])
    th, amp = TRUTH4[0::2], TRUTH4[1::2]
    expect = np.sum(amp[:, None] * np.cos(th[:, None] - alpha[None, :]), axis=0)
    np.testing.assert_allclose(s[:15] - s[15:], expect[:15], atol=1e-12)


def test_antipodal_pairs_found_with_signed_offsets():
    model = Model(Ring(30), sigma=1e-3)
    pairs = antipodal_pairs(model, TRUTH4)
    spacing = 2 * np.pi / 30
    assert [(i, j) for i, j, _ in pairs] == [(0, 2), (1, 3)]
    np.testing.assert_allclose([p[2] for p in pairs],
                               [(0.45 + 2.6 - np.pi) / spacing, (1.95 + 1.05 - np.pi) / spacing])
    assert antipodal_pairs(model, TRUTH4, within=0.4) == ()
    assert antipodal_pairs(Model(Sphere.fibonacci(20), sigma=0.01), np.array([0.1, 0.2, 1.0])) == ()
    with pytest.raises(InputError, match="within"):
        antipodal_pairs(model, TRUTH4, within=0.0)
    y = mirror_pair(TRUTH4, 0, 2, 2)
    np.testing.assert_allclose(y[[0, 4]], wrap_angle(np.array([0.45 - np.pi, -2.6 + np.pi])))


def test_mode_search_finds_the_four_mirrored_optima(scene4):
    """Each near-antipodal pair has two optima of (almost) equal fit: 2 x 2 modes."""
    model, data = scene4
    prior = default_priors(model, 4, data=data)
    modes, lp = find_modes(model, data, prior, TRUTH4, ModeOptions())
    assert modes.shape == (4, 8)
    assert lp[0] - lp[-1] < 0.5  # within half a nat: none is negligible
    err = np.abs(wrap_angle(modes[:, 0::2] - TRUTH4[0::2]))
    # each mode moves both sources of a pair (~0.1 rad, > 100 CRLB sd) or neither
    moved = err > 0.05
    assert np.array_equal(moved[:, 0], moved[:, 2]) and np.array_equal(moved[:, 1], moved[:, 3])
    assert len({tuple(m) for m in moved[:, :2]}) == 4


def test_multimodal_run_weights_the_modes_and_covers_the_truth(scene4, multimodal4):
    model, _ = scene4
    res = multimodal4
    assert isinstance(res, PosteriorResult) and res.modes.n_modes == 4
    # equal fits and equal Fisher volumes: weights 1/4 each, up to the evidence error
    # (se ~0.01 nats per mode) and the modes' log-posterior spread (< 0.05 nats)
    np.testing.assert_allclose(res.modes.weight, 0.25, atol=0.03)
    assert np.all(res.modes.stayed > 0.99)
    # the truth's own mode is among them (within 5 CRLB sd), with a quarter of the mass;
    # a single ensemble finds it one time in four (the ML point picks one mode)
    err = np.abs(wrap_angle(match_sources(model, res.modes.params, TRUTH4) - TRUTH4))
    sd = np.sqrt(np.diag(np.linalg.inv(model.fisher(TRUTH4))))
    near = np.all(err[:, 0::2] < 5 * sd[0::2], axis=1)
    assert near.sum() == 1 and res.modes.weight[near][0] > 0.2
    # the marginals span the modes: each angle's 90 % interval is wider than the
    # mirror shift (~0.1 rad), not CRLB-wide (~0.001 rad)
    lo, hi = np.quantile(res.unwrapped_samples().reshape(-1, 8), [0.05, 0.95], axis=0)
    assert np.all(hi[0::2] - lo[0::2] > 0.08)
    assert "modes=4" in repr(res)


def test_single_ensemble_warns_and_misses_a_mode(scene4):
    model, data = scene4
    opts = SamplerOptions(n_steps=200, rhat_max=None, multimodal=False)
    with pytest.warns(AntipodalWarning, match="antipodal"):
        res = sample(model, data, 4, rng=3, progress=False, options=opts)
    assert res.modes is None
    sd = res.flat_samples.std(axis=0)
    np.testing.assert_array_less(sd[0::2], 0.01)  # one mode: CRLB-wide, not 0.1 rad


def test_modes_survive_the_netcdf_round_trip(multimodal4, tmp_path):
    back = PosteriorResult.from_netcdf(multimodal4.to_netcdf(tmp_path / "p.nc"))
    np.testing.assert_array_equal(back.modes.weight, multimodal4.modes.weight)
    np.testing.assert_array_equal(back.modes.params, multimodal4.modes.params)
    assert back.modes.reason == multimodal4.modes.reason


def test_default_path_unchanged_when_nothing_triggers():
    """A well-separated scene: no mode search result, the same draws as multimodal=False."""
    model = Model(Ring(30), sigma=0.01)
    data = model.simulate(np.array([-1.0, 1.0, 1.2, 0.8]), rng=0)
    opts = SamplerOptions(n_steps=200, rhat_max=None)
    auto = sample(model, data, 2, rng=5, progress=False, options=opts)
    off = sample(model, data, 2, rng=5, progress=False,
                 options=SamplerOptions(n_steps=200, rhat_max=None, multimodal=False))
    assert auto.modes is None
    np.testing.assert_array_equal(auto.samples, off.samples)


def test_requested_on_one_mode_runs_and_reports_it():
    model = Model(Ring(30), sigma=0.01)
    data = model.simulate(np.array([0.4, 1.0]), rng=1)
    res = sample(model, data, 1, rng=2, progress=False,
                 options=SamplerOptions(n_steps=300, rhat_max=None, multimodal=True))
    assert res.modes.n_modes == 1 and res.modes.reason == "requested"
    np.testing.assert_allclose(res.modes.weight, [1.0])


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"log_range": 0.0}, "log_range"),
    ({"max_modes": 0}, "max_modes"),
    ({"rounds": 0}, "rounds"),
    ({"evidence_draws": 10}, "evidence_draws"),
    ({"shifts": "yes"}, "shifts"),
    ({"condition_max": 1.0}, "condition_max"),
    ({"antipodal_spacings": -1.0}, "antipodal_spacings"),
])
def test_mode_options_validated(kwargs, match):
    with pytest.raises(InputError, match=match):
        ModeOptions(**kwargs)


def test_sampler_options_and_start_validated(scene4):
    model, data = scene4
    with pytest.raises(InputError, match="multimodal"):
        SamplerOptions(multimodal="auto")
    with pytest.raises(InputError, match="modes"):
        SamplerOptions(modes={"log_range": 3})
    with pytest.raises(InputError, match="multimodal"):
        sample(model, data, 4, start="prior", progress=False,
               options=SamplerOptions(multimodal=True))


def test_crlb_alarm_reruns_with_the_modes(scene4, monkeypatch):
    """A default run narrower than the CRLB at high SNR is rerun over the modes found."""
    import olsbayes.posterior._modal as modal
    import olsbayes.posterior.sampler as sampler

    model, data = scene4
    monkeypatch.setattr(modal, "trigger_reason", lambda *args: "")  # no trigger before the run
    monkeypatch.setattr(sampler, "narrower_than_crlb",
                        lambda result: [("theta[0]", 0.5, 1000.0)])
    doubt = "covered the truth less often"  # the two near-antipodal pairs, either way
    with pytest.warns(AntipodalWarning, match=doubt), \
            pytest.warns(MultimodalWarning, match="far below the CRLB"):
        res = sample(model, data, 4, rng=3, progress=False,
                     options=SamplerOptions(n_steps=150, rhat_max=None))
    assert res.modes.n_modes == 4 and "CRLB" in res.modes.reason
    off = SamplerOptions(n_steps=150, rhat_max=None, modes=ModeOptions(crlb_alarm=False))
    with pytest.warns(AntipodalWarning, match=doubt), \
            pytest.warns(Warning, match="far below the CRLB"):
        assert sample(model, data, 4, rng=3, progress=False, options=off).modes is None


def test_ml_fit_warns_about_a_mirrored_optimum(scene4):
    """fit_ml: the mirrored configuration of a near-antipodal pair is a distinct optimum
    within 3 of the log-likelihood (AntipodalWarning); an exactly antipodal pair is not."""
    from olsbayes import fit_ml

    model, data = scene4
    with pytest.warns(AntipodalWarning, match="mirrored"):
        fit_ml(model, data, 4)
    fig3 = Model(Ring(30), sigma=1e-2)
    fig3_data = fig3.simulate(np.array([0.5, 1.0, 0.5 + np.pi, 0.2]), rng=4, size=5)
    with warnings.catch_warnings():
        warnings.simplefilter("error", AntipodalWarning)
        fit_ml(fig3, fig3_data, 2)


def test_mode_search_with_no_optimum_inside_the_prior_returns_the_centre():
    """Every optimum brighter than the prior's intensity bound: one mode, the centre,
    and the automatic choice keeps one ensemble (no crash on an empty mode list)."""
    from olsbayes.posterior._modal import mode_plan

    model = Model(Ring(30), sigma=1e-2)
    truth = np.array([0.3, 1.0, 0.3 + np.pi - 0.1, 1.2])  # a near-antipodal pair
    data = model.simulate(truth, rng=0)
    prior = default_priors(model, 2, i_max=0.5)  # both intensities above the bound
    modes, lp = find_modes(model, data, prior, truth, ModeOptions())
    np.testing.assert_array_equal(modes, truth[None, :])
    assert lp.shape == (1,) and lp[0] == -np.inf
    assert mode_plan(model, data, prior, truth, SamplerOptions()) is None


def test_mode_evidence_survives_scales_far_apart():
    """Draws whose sds span 7 decades (a numerically singular covariance for the
    Student-t proposal): the scaled proposal gives log Z of a normalised Gaussian, 0."""
    from scipy import stats

    from olsbayes.posterior.multimodal import mode_evidence

    sd = np.array([1e-7, 1.0, 0.5])
    rng = np.random.default_rng(4)
    z = rng.standard_normal((400, 3)) * sd
    with pytest.raises(np.linalg.LinAlgError):  # what the direct proposal meets
        stats.multivariate_t(loc=z.mean(0), shape=np.cov(z, rowvar=False), df=5.0)

    def logpost(x):
        return np.sum(stats.norm.logpdf(x / sd) - np.log(sd), axis=-1)

    log_z, se = mode_evidence(logpost, z, 4000, rng)
    assert abs(log_z) < 4 * se + 0.02 and se < 0.05


def test_sampler_doubt_follows_the_ml_rule():
    """The sampler's AntipodalWarning fires exactly where fit_ml's doubt rule does:
    four sources with a pair within one spacing of antipodal, not a separated
    four-source scene nor the two-source antipodal scene of the paper's Fig. 3."""
    from olsbayes.posterior.sampler import _warn_doubts

    model = Model(Ring(30), sigma=1e-3)
    with pytest.warns(AntipodalWarning, match="less often than stated"):
        _warn_doubts(model, TRUTH4)
    separated = np.array([-2.7, 1.0, -1.3, 0.8, 0.0, 1.2, 1.2, 0.9])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _warn_doubts(model, separated)
        _warn_doubts(model, np.array([0.5, 1.0, 0.5 + np.pi, 0.2]))


def test_near_antipodal_pair_at_a_crowded_ml_point_does_not_trigger_the_modes():
    # a near-antipodal pair triggers the search for modes, unless two sources of the ML
    # point are closer than the resolution limit: that point does not pin the
    # configuration, and one ensemble covered such scenes far better on the map
    from olsbayes.posterior.multimodal import trigger_reason
    from olsbayes.resolution import RESOLUTION_SPACINGS

    model = Model(Ring(30), sigma=1e-3)
    h = 2 * np.pi / 30
    for gap, expect in ((RESOLUTION_SPACINGS + 0.5, True), (RESOLUTION_SPACINGS - 0.5, False)):
        x = np.array([0.0, 1.0, np.pi - 0.3 * h, 0.8, np.pi / 2, 1.1, np.pi / 2 + gap * h, 0.9])
        assert len(antipodal_pairs(model, x)) == 1
        reason = trigger_reason(model, x, np.nan, ModeOptions())
        assert ("near-antipodal" in reason) is expect, (gap, reason)


def test_near_antipodal_pair_with_a_weak_source_does_not_trigger_the_modes():
    # a pair one of whose sources the readings cannot tell from zero (intensity under
    # WEAK_SDS Cramer-Rao sd) is an artefact of the ML point: no search for modes;
    # the same pair with both sources pinned triggers it
    from olsbayes.bounds import bound_covariance
    from olsbayes.posterior.multimodal import trigger_reason
    from olsbayes.resolution import WEAK_SDS

    model = Model(Ring(30), sigma=1e-3)
    h = 2 * np.pi / 30
    for weak, expect in ((1e-4, False), (0.8, True)):
        x = np.array([0.0, 1.0, np.pi - 0.3 * h, weak, np.pi / 2, 1.1, np.pi / 2 + 4 * h, 0.9])
        sd = np.sqrt(np.diag(bound_covariance(model.fisher(x))[0]))[3]
        assert bool(x[3] >= WEAK_SDS * sd) is expect
        assert len(antipodal_pairs(model, x)) == 1
        reason = trigger_reason(model, x, np.nan, ModeOptions())
        assert ("near-antipodal" in reason) is expect, (weak, reason)


def test_walkers_placed_around_a_mode_on_a_corner_of_the_support():
    # a mode with two intensities at 0 whose errors are anti-correlated (two faint
    # sources at one direction): about 0.4 % of its ball is inside the support, however
    # far the ball shrinks; the walkers come from the whole ball in batches
    from olsbayes.posterior._start import initial_ensemble

    centre = np.array([0.0, 0.0, 0.0])
    rho = -0.999
    cov = np.array([[1.0, rho, 0.0], [rho, 1.0, 0.0], [0.0, 0.0, 1.0]]) * 0.01

    def inside(x):
        return (x[..., 0] >= 0) & (x[..., 1] >= 0) & (x[..., 2] >= 0)

    share = 0.5 * (0.25 + np.arcsin(rho) / (2 * np.pi))  # P(x0, x1 >= 0) P(x2 >= 0)
    assert 0.002 < share < 0.005
    walkers = initial_ensemble(centre, cov, 64, inside, np.random.default_rng(1))
    assert walkers.shape == (64, 3) and inside(walkers).all()
    # drawn from the ball, not squeezed onto the centre
    assert np.median(np.abs(walkers[:, 2])) > 0.03
