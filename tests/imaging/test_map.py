"""Imaging: the mode-only fast path and the two-level (0 / i_max) MAP search."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.optimize import lsq_linear

import olsbayes as ob
from olsbayes.errors import InputError
from olsbayes.imaging import (
    Bounded,
    ImageOptions,
    NonNegative,
    Sparse,
    TwoLevel,
    design_matrix,
    image,
)
from olsbayes.imaging.binary import two_level_log_posterior, two_level_map


def _brute_force(a, y, sigma, i_max, p):
    """Every binary scene's log posterior; returns (best scene, best L, all L by scene)."""
    k = a.shape[1]
    scenes = np.array(list(itertools.product([0.0, i_max], repeat=k)))
    r = y - scenes @ a.T
    n_on = (scenes > 0).sum(axis=1)
    lp = -0.5 * np.sum(r**2, axis=1) / sigma**2 + n_on * np.log(p) + (k - n_on) * np.log1p(-p)
    return scenes[np.argmax(lp)], float(lp.max()), dict(zip(map(tuple, scenes), lp))


@pytest.fixture
def sphere_problem():
    # 2 of its 10 intensity combinations are pinned less well than the priors' scale
    # (NullSpaceWarning at the default null_warn = 0.1; these tests ask 0.5)
    model = ob.Model(ob.Sphere.grid(4, 6), sigma=0.2)
    dirs = np.array([[lo, la] for la in (-0.4, 0.4) for lo in np.linspace(-1.5, 1.5, 5)])
    a = design_matrix(model, dirs)
    truth = np.array([1, 0, 0, 1, 0, 0, 1, 1, 0, 0], dtype=float) * 2.0
    y = a @ truth + model.sigma * np.random.default_rng(12).standard_normal(a.shape[0])
    return model, dirs, a, y, truth


# -- mode only -------------------------------------------------------------------
@pytest.mark.parametrize("prior,hi", [(Bounded(i_max=2.0), 2.0),
                                      (NonNegative(scale=2.0), np.inf)])
def test_mode_only_is_bounded_least_squares_without_sampling(sphere_problem, prior, hi):
    model, dirs, a, y, _ = sphere_problem
    res = image(model, y, dirs, prior, options=ImageOptions(n_samples=0, null_warn=0.5))
    ref = lsq_linear(a, y, bounds=(0.0, hi), method="bvls").x
    np.testing.assert_allclose(res.mode, ref, atol=1e-10)
    np.testing.assert_array_equal(res.mean, res.mode)
    assert res.samples is None and res.sampler == "mode-only"
    assert np.all(np.isnan(res.sd)) and np.all(np.isnan(res.lower)) and np.isnan(res.rhat)
    assert res.rank == np.linalg.matrix_rank(a) and res.design.null_space.shape[0] == 10
    assert res.diagnostics()["n_draws"] == 0


@pytest.mark.parametrize(
    "prior,n,match",
    [("bounded", 2, "0 \\(mode only\\) or >= 4"), (Sparse(), 0, ">= 4"),
     (TwoLevel(i_max=1.0), 10, "MAP only")],
)
def test_n_samples_rules_per_prior(sphere_problem, prior, n, match):
    model, dirs, _, y, _ = sphere_problem
    with pytest.raises(InputError, match=match):
        image(model, y, dirs, prior, options=ImageOptions(n_samples=n))


# -- two-level MAP ---------------------------------------------------------------
def test_two_level_log_posterior_matches_the_formula(sphere_problem):
    model, _, a, y, truth = sphere_problem
    _, _, table = _brute_force(a, y, model.sigma, 2.0, 0.3)
    assert two_level_log_posterior(a, y, model.sigma, truth, 2.0, 0.3) == pytest.approx(
        table[tuple(truth)], rel=1e-12)


@pytest.mark.parametrize("p", [0.5, 0.2])
def test_two_level_image_finds_the_brute_force_map(sphere_problem, p):
    model, dirs, a, y, truth = sphere_problem
    best, best_lp, _ = _brute_force(a, y, model.sigma, 2.0, p)
    res = image(model, y, dirs, TwoLevel(i_max=2.0, p_bright=p),
                options=ImageOptions(reference=truth, null_warn=0.5))
    assert res.sampler == "map-search" and res.samples is None
    np.testing.assert_array_equal(res.mode, best)
    np.testing.assert_array_equal(res.mean, res.mode)
    assert res.search.log_posterior == pytest.approx(best_lp, rel=1e-12)
    assert res.search.local_optimum and res.search.reference_better is False
    assert res.diagnostics()["reference_log_posterior"] <= res.diagnostics()["log_posterior"]


def test_two_level_search_ends_in_a_local_optimum_of_its_moves(sphere_problem):
    # from the worst start (all bright) with single flips and all 2-flips: no 1- or
    # 2-flip of the scene found may improve L (checked against the brute-force table)
    model, _, a, y, _ = sphere_problem
    _, _, table = _brute_force(a, y, model.sigma, 2.0, 0.5)
    run = two_level_map(a, y, model.sigma, 2.0, np.full(10, 2.0), pairs="all")
    assert run.local_optimum and run.n_flips + run.n_swaps > 0
    here = table[tuple(run.x)]
    for flip in itertools.chain(itertools.combinations(range(10), 1),
                                itertools.combinations(range(10), 2)):
        other = run.x.copy()
        other[list(flip)] = 2.0 - other[list(flip)]
        assert table[tuple(other)] <= here + 1e-9


def test_search_failure_is_reported_and_fixed_by_larger_moves():
    # two nearly equal columns: from [0, 1] no single flip helps, the swap does
    rng = np.random.default_rng(3)
    a1 = rng.random(6)
    a = np.column_stack([a1, a1 + 0.05 * rng.random(6)])
    y = a[:, 0].copy()
    stuck = two_level_map(a, y, 0.01, 1.0, np.array([0.0, 1.0]), pairs=None,
                          reference=np.array([1.0, 0.0]))
    assert stuck.local_optimum and stuck.reference_better is True
    np.testing.assert_array_equal(stuck.x, [0.0, 1.0])
    fixed = two_level_map(a, y, 0.01, 1.0, np.array([0.0, 1.0]), pairs=np.array([[0, 1]]),
                          reference=np.array([1.0, 0.0]))
    np.testing.assert_array_equal(fixed.x, [1.0, 0.0])
    assert fixed.n_swaps == 1 and fixed.reference_better is False


def test_group_moves_flip_a_checkerboard_that_no_2_flip_reaches():
    # a1 + a4 = a2 + a3 + eps: from [0, 1, 1, 0] every 1- and 2-flip is worse
    rng = np.random.default_rng(5)
    a = rng.random((8, 3))
    a = np.column_stack([a, a[:, 1] + a[:, 2] - a[:, 0] + 0.05])
    truth = np.array([1.0, 0.0, 0.0, 1.0])
    y = a @ truth
    start = 1.0 - truth
    pairs_only = two_level_map(a, y, 0.01, 1.0, start, pairs="all", reference=truth)
    assert pairs_only.reference_better is True
    grouped = two_level_map(a, y, 0.01, 1.0, start, pairs="all", groups=np.array([[0, 1, 2, 3]]),
                            reference=truth)
    np.testing.assert_array_equal(grouped.x, truth)
    assert grouped.n_group_moves == 1 and grouped.reference_better is False


@pytest.mark.parametrize("p", [1.0, 0.0, -0.5, np.nan, True, "0.5"])
def test_two_level_p_bright_outside_the_open_unit_interval_is_refused(p):
    with pytest.raises(InputError, match=r"TwoLevel.p_bright must be a number in \(0, 1\)"):
        TwoLevel(i_max=1.0, p_bright=p)


def test_two_level_reference_of_the_wrong_length_is_refused(sphere_problem):
    model, dirs, _, y, _ = sphere_problem
    with pytest.raises(InputError, match=r"reference must have shape \(10,\)"):
        image(model, y, dirs, TwoLevel(i_max=1.0), options=ImageOptions(reference=np.zeros(3)))


def test_search_stops_at_max_moves_and_says_so(sphere_problem):
    model, _, a, y, _ = sphere_problem
    groups = np.array([[0, 1, 2, 5, 6], [3, 4, 7, 8, 9]])
    run = two_level_map(a, y, model.sigma, 2.0, np.full(10, 2.0), groups=groups, max_moves=1)
    assert not run.local_optimum and run.n_flips + run.n_swaps + run.n_group_moves == 1
    assert run.log_posterior > run.start_log_posterior


def test_two_level_restarts_are_reproducible_and_never_worse(sphere_problem):
    model, dirs, a, y, truth = sphere_problem
    prior = TwoLevel(i_max=2.0)
    plain = image(model, y, dirs, prior, options=ImageOptions(reference=truth, null_warn=0.5))
    r1 = image(model, y, dirs, prior, options=ImageOptions(restarts=5, null_warn=0.5), rng=3)
    r2 = image(model, y, dirs, prior, options=ImageOptions(restarts=5, null_warn=0.5), rng=3)
    np.testing.assert_array_equal(r1.mode, r2.mode)
    assert r1.search.log_posterior >= plain.search.log_posterior - 1e-9
    with pytest.raises(InputError, match="restarts"):
        ImageOptions(restarts=-1)
