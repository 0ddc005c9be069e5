"""The sliding search of the fast fit (K >= 5): relocations of one or two sources."""

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.errors import InputError
from olsbayes.ml import FastOptions, fit_ml
from olsbayes.ml.fast.slide import distinct_best, relocations


def _even_scene(k: int) -> np.ndarray:
    """K unit sources 6/K rad apart on the circle (0.75 rad at K = 8)."""
    theta = np.linspace(-3, 3, k, endpoint=False) + 0.1
    return np.column_stack([theta, np.ones(k)]).ravel()


@pytest.mark.parametrize("k", [6, 8])
def test_noise_free_many_source_ring_scene_is_fitted_exactly(k):
    """Noise-free readings of K sources on a 64-ring: the global optimum has chi^2 = 0
    (the truth), so the fit must describe the readings to rounding (chi^2 / sum s^2 of
    order 1e-30; a wrong configuration leaves 1e-6 or more).  The locations are not
    compared: at K = 6 another configuration explains these readings exactly too (the
    readings of a ring fix sums of source phasors per arc, not the phasors)."""
    model = ob.Model(ob.Ring(64), 1e-2)
    truth = _even_scene(k)
    s = model.response(truth)
    res = fit_ml(model, s, k, warn=False)
    chi2 = float(np.sum((s - model.response(res.params)) ** 2))
    assert chi2 <= 1e-20 * float(s @ s)


def test_slide_batch_equals_loop_and_never_worsens_the_fit():
    """Deterministic: a batch equals a loop of single fits; the search only replaces a
    fit by a better one, so its log-likelihood is >= that without it."""
    model = ob.Model(ob.Ring(64), 1e-2)
    rng = np.random.default_rng(5)
    truth = np.array([_even_scene(6) + np.tile([rng.uniform(-0.2, 0.2), 0.0], 6)
                      for _ in range(3)])
    data = model.simulate(truth, rng=rng)
    batch = fit_ml(model, data, 6, warn=False)
    single = np.array([fit_ml(model, s, 6, warn=False).params for s in data])
    np.testing.assert_array_equal(single, batch.params)
    off = fit_ml(model, data, 6, options=FastOptions(slide=0), warn=False)
    assert np.all(batch.log_likelihood >= off.log_likelihood)


def test_relocations_leave_the_current_sources_basins():
    """Every moved source starts at a grid atom outside the basins of the current
    sources; the other sources keep their locations."""
    model = ob.Model(ob.Ring(64), 1e-2)
    from olsbayes.ml.atoms import atoms, cached_default_grid

    grid = cached_default_grid(model)
    x = _even_scene(5)[None]
    s = model.response(x[0])[None] + 0.01
    starts = relocations(model, atoms(model, grid), grid, s, x)
    assert starts.shape == (1, 5 + 10, 5, 2)
    moved = np.abs(ob.wrap_angle(starts[0, :, :, 0] - x[0, 0::2])) > 1e-12
    assert np.array_equal(moved[:5], np.eye(5, dtype=bool))
    assert np.all(moved[5:].sum(axis=1) == 2)
    gap = np.abs(ob.wrap_angle(starts[0, :, :, 0][:, :, None] - x[0, 0::2][None, None, :]))
    assert np.all(gap[moved].min(axis=-1) > np.radians(10))  # beyond a basin of the atoms
    assert np.all(starts[..., 1] >= 0)


def test_distinct_best_takes_the_lowest_distinct_values():
    chi2 = np.array([[3.0, 1.0, 1.0 + 1e-12, np.inf, 2.0], [np.inf, 5.0, np.inf, 4.0, 4.0]])
    rows, cols = distinct_best(chi2, 2)
    assert rows.tolist() == [0, 0, 1, 1]
    assert cols.tolist() == [1, 4, 3, 1]


def test_slide_defaults_and_bad_values():
    ring = ob.Model(ob.Ring(64), 1e-2)
    assert [FastOptions().resolve(ring, k).slide for k in (4, 5, 6, 7, 8, 12)] == [
        0, 16, 16, 32, 64, 64]
    sphere = ob.Model(ob.Sphere.grid(5, 8), 1e-2)
    assert [FastOptions().resolve(sphere, k).slide for k in (4, 5, 8)] == [0, 16, 16]
    for field, value in (("slide", -1), ("slide", 65), ("slide", 1.5), ("slide_sweeps", 0)):
        with pytest.raises(InputError, match=field):
            FastOptions(**{field: value})


def test_first_visits_drop_optima_already_visited_by_the_same_data_vector():
    """A sliding path stops at an optimum (same chi^2 to 1e-9) that another path of
    its data vector visited or reaches in the same sweep; other data vectors' optima
    do not count."""
    from olsbayes.ml.fast.slide import _first_visits

    seen_owner, seen_chi2 = np.array([0, 0, 1]), np.array([1.0, 2.0, 3.0])
    owner = np.array([0, 0, 0, 1, 0])
    chi2 = np.array([2.0 * (1 + 1e-12), 1.5, 1.5, 2.0, 0.5])
    keep = _first_visits(owner, chi2, seen_owner, seen_chi2)
    assert keep.tolist() == [False, True, False, True, True]
