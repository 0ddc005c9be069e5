"""The compiled LM kernel (olsbayes.ml._numba.lm) against the numpy LM (olsbayes.ml.lm).

Both run the same bounded Levenberg–Marquardt; they differ only in rounding
(summation order, LU instead of LAPACK's solve).  Both stop when an accepted
step lowers chi^2 by less than ftol * chi^2 (ftol = 1e-10), so two runs to the
same minimum agree in chi^2 to ~ftol, and in each parameter to about
sqrt(ftol * chi^2) / sigma ~ sqrt(ftol * N) CRLB standard deviations (~1e-4
for N <= 120): the tolerances below are 10x those.
"""

from __future__ import annotations

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.bounds import kink_sources
from olsbayes.ml._numba import cells as _cells
from olsbayes.ml._numba import lm as _kernel
from olsbayes.ml._numba import refine as _refine_kernel
from olsbayes.ml.lm import Dedupe, refine_batch, refine_batch_numpy
from olsbayes.sensitivity import CustomSensitivity

FTOL = 1e-10


def _crlb_sd(model: ob.Model, truth: np.ndarray) -> np.ndarray:
    return np.sqrt(np.diag(np.linalg.pinv(model.fisher(truth))))


def _compare(model, truth, data, x0, frozen=None, n_close=None):
    """Kernel vs numpy from the same starts: same optimum, same flags."""
    assert _kernel.supports(model)
    a = refine_batch(model, data, x0, frozen=frozen)
    b = refine_batch_numpy(model, data, x0, frozen=frozen)
    assert a.converged.all() and b.converged.all()
    rel = np.abs(a.chi2 - b.chi2) / b.chi2
    sd = _crlb_sd(model, truth)
    dx = np.abs(a.x - b.x) / sd
    close = (rel <= 10 * FTOL) & np.all(dx <= 10 * np.sqrt(FTOL * model.n_sensors), axis=1)
    # every trial, unless the caller allows a few rounding-driven branch changes
    assert close.sum() >= (close.size if n_close is None else n_close), (rel.max(), dx.max())
    # chi^2 reported is the chi^2 of the returned x
    resid = data - model.response(a.x)
    np.testing.assert_allclose(a.chi2, np.einsum("tn,tn->t", resid, resid), rtol=1e-12)
    return a, b


def _starts(model, truth, data_rng, n, scale):
    rng = np.random.default_rng(data_rng)
    return truth + scale * rng.standard_normal((n, truth.size))


@pytest.mark.parametrize("law", ["cosine", ob.CosinePower(2.0), ob.CosinePower(2.5)])
def test_ring_matches_numpy(law):
    model = ob.Model(ob.Ring(30), 1e-2, law)
    scene = ob.Scene(directions=[0.4, 2.5, -1.9], intensities=[1.0, 0.7, 0.5])
    truth = model.pack(scene)
    data = model.simulate(scene, rng=1, size=40)
    _compare(model, truth, data, _starts(model, truth, 2, 40, 0.03))


def test_sphere_matches_numpy():
    model = ob.Model(ob.Sphere.fibonacci(120), 1e-2)
    scene = ob.Scene(directions=[[0.4, 0.2], [2.5, -0.5]], intensities=[1.0, 0.6])
    truth = model.pack(scene)
    data = model.simulate(scene, rng=3, size=30)
    _compare(model, truth, data, _starts(model, truth, 4, 30, 0.03))


def test_plate_matches_numpy():
    model = ob.Model(ob.Plate.grid(6, 6, pitch=1.0), 1e-3)
    scene = ob.Scene(positions=[[2.0, 2.5, 3.0], [3.5, 1.0, 2.0]], intensities=[10.0, 6.0])
    truth = model.pack(scene)
    data = model.simulate(scene, rng=5, size=30)
    _compare(model, truth, data, _starts(model, truth, 6, 30, 0.05))


def test_intensity_at_bound():
    """A second source with true intensity 0: fits end with I = 0 exactly on both paths."""
    model = ob.Model(ob.Ring(30), 1e-2)
    scene = ob.Scene(directions=[0.4, 2.5], intensities=[1.0, 0.0])
    truth = model.pack(scene)
    data = model.simulate(scene, rng=7, size=40)
    x0 = _starts(model, truth, 8, 40, 0.02)
    x0[:, 3] = 0.05
    sd = _crlb_sd(model, model.pack(ob.Scene(directions=[0.4, 2.5], intensities=[1.0, 0.5])))
    a = refine_batch(model, data, x0)
    b = refine_batch_numpy(model, data, x0)
    at_bound = b.x[:, 3] == 0.0
    assert at_bound.sum() >= 10  # the case is exercised
    np.testing.assert_array_equal(a.x[:, 3] == 0.0, at_bound)
    np.testing.assert_array_less(np.abs(a.chi2 - b.chi2) / b.chi2, 10 * FTOL)
    ok = at_bound  # the angle of a zero-intensity source is unidentified: compare the rest
    dx = np.abs(a.x[ok][:, :3] - b.x[ok][:, :3]) / sd[:3]
    assert dx.max() <= 10 * np.sqrt(FTOL * model.n_sensors)


def test_frozen_parameter():
    model = ob.Model(ob.Ring(30), 1e-2)
    scene = ob.Scene(directions=[0.4, 2.5], intensities=[1.0, 0.6])
    truth = model.pack(scene)
    data = model.simulate(scene, rng=9, size=30)
    x0 = _starts(model, truth, 10, 30, 0.02)
    frozen = np.zeros(x0.shape, bool)
    frozen[:, 2] = True  # second source's angle held at its start
    a, _ = _compare(model, truth, data, x0, frozen=frozen)
    np.testing.assert_array_equal(a.x[:, 2], x0[:, 2])


def test_source_on_kink():
    """A source 90 deg from a sub-sensor (the kink of the clipped cosine): starts on the
    kink, free and (as the fast fit's kink polish does) with that angle frozen."""
    ring = ob.Ring(30)
    model = ob.Model(ring, 1e-2)
    kink = ring.angles[3] + np.pi / 2
    scene = ob.Scene(directions=[kink, 2.0], intensities=[1.0, 0.5])
    truth = model.pack(scene)
    data = model.simulate(scene, rng=11, size=40)
    x0 = _starts(model, truth, 12, 40, 0.02)
    x0[:, 0] = kink
    frozen = np.zeros(x0.shape, bool)
    frozen[:, 0] = True
    a, _ = _compare(model, truth, data, x0, frozen=frozen)
    assert kink_sources(model, a.x, atol=1e-9)[:, 0].all()
    _compare(model, truth, data, x0)


def test_batch_equals_loop_exactly():
    model = ob.Model(ob.Sphere.fibonacci(60), 1e-2)
    scene = ob.Scene(directions=[[0.4, 0.2], [2.5, -0.5]], intensities=[1.0, 0.6])
    truth = model.pack(scene)
    data = model.simulate(scene, rng=13, size=12)
    x0 = _starts(model, truth, 14, 12, 0.05)
    a = refine_batch(model, data, x0)
    for i in range(12):
        b = refine_batch(model, data[i : i + 1], x0[i : i + 1])
        np.testing.assert_array_equal(a.x[i], b.x[0])
        assert a.chi2[i] == b.chi2[0] and a.n_evaluations[i] == b.n_evaluations[0]


def test_max_iter_and_counts_match_numpy():
    model = ob.Model(ob.Ring(30), 1e-2)
    scene = ob.Scene(directions=[0.4, 2.5], intensities=[1.0, 0.6])
    data = model.simulate(scene, rng=15, size=10)
    x0 = _starts(model, model.pack(scene), 16, 10, 0.3)
    a = refine_batch(model, data, x0, max_iter=2)
    b = refine_batch_numpy(model, data, x0, max_iter=2)
    assert not a.converged.any() and not b.converged.any()
    np.testing.assert_array_equal(a.n_evaluations, b.n_evaluations)
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-9)


def test_custom_law_takes_numpy_path():
    law = CustomSensitivity(lambda c: np.maximum(c, 0.0) ** 3, lambda c: 3 * np.maximum(c, 0) ** 2)
    model = ob.Model(ob.Ring(30), 1e-2, law)
    assert not _kernel.supports(model)
    scene = ob.Scene(directions=[0.4, 2.5], intensities=[1.0, 0.6])
    data = model.simulate(scene, rng=17, size=5)
    x0 = _starts(model, model.pack(scene), 18, 5, 0.02)
    a = refine_batch(model, data, x0)
    b = refine_batch_numpy(model, data, x0)
    np.testing.assert_array_equal(a.x, b.x)


@pytest.mark.parametrize("k", [2, 3])
def test_fit_ml_same_optimum_as_numpy_path(k, monkeypatch):
    """The whole fast fit (search, restarts, kink hops, polish) on either LM path."""
    model = ob.Model(ob.Ring(30), 1e-2)
    ang = 0.37 + 2 * np.pi * np.arange(k) / k + 0.13 * np.arange(k)
    scene = ob.Scene(directions=ang, intensities=np.linspace(1.0, 0.6, k))
    data = model.simulate(scene, rng=19, size=60)
    a = ob.fit_ml(model, data, k)
    monkeypatch.setattr(_kernel, "supports", lambda model: False)
    b = ob.fit_ml(model, data, k)
    # log L = -chi^2 / (2 sigma^2) + const, chi^2 ~ N sigma^2: 10 ftol relative in chi^2
    np.testing.assert_allclose(a.log_likelihood, b.log_likelihood, rtol=0,
                               atol=10 * FTOL * model.n_sensors)


def test_spd_solve_falls_back_to_lu():
    """The Cholesky solve of the LM step hands a non-SPD matrix to pivoted LU."""
    for m in (np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]]),  # SPD
              np.array([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),  # indefinite
              np.array([[0.0, 1.0], [1.0, 0.0]])):  # zero pivot
        b = np.arange(1.0, m.shape[0] + 1.0)
        out = np.empty_like(b)
        _kernel._solve_spd(m.copy(), b, out)
        np.testing.assert_allclose(out, np.linalg.solve(m, b), rtol=1e-13, atol=1e-14)


def test_refine_batch_shape_errors():
    model = ob.Model(ob.Ring(30), 1e-2)
    data, x0 = np.zeros((3, 30)), np.zeros((3, 4))
    for bad_data, bad_x0 in ((data[0], x0), (data, x0[0]), (data[:2], x0), (data[:, :29], x0),
                             (data, x0[:, :3])):
        with pytest.raises(ob.InputError, match="data must have shape"):
            refine_batch(model, bad_data, bad_x0)


def test_compiled_hop_starts_identical():
    from olsbayes.ml.fast.refine import hop_starts

    ring = ob.Ring(30)
    model = ob.Model(ring, 1e-2)
    rng = np.random.default_rng(25)
    x = np.stack([rng.uniform(-4, 4, (50, 3)), rng.uniform(0, 1, (50, 3))], axis=-1).reshape(50, 6)
    x[0, 0] = ring.angles[2] + np.pi / 2  # exactly on a crossing
    np.testing.assert_array_equal(_refine_kernel.hop_starts(model, x), hop_starts(model, x))


@pytest.mark.parametrize("geometry", ["ring", "sphere", "plate"])
def test_compiled_kink_test_matches_crlb(geometry):
    ring = ob.Ring(30)
    if geometry == "ring":
        model = ob.Model(ring, 1e-2)
        x = np.array([[ring.angles[4] + np.pi / 2, 1.0, 2.0, 0.5], [0.3, 1.0, 2.0, 0.5]])
    elif geometry == "sphere":
        model = ob.Model(ob.Sphere.fibonacci(40), 1e-2)
        x = np.array([[0.4, 0.2, 1.0], [2.5, -0.5, 0.6]])
    else:
        model = ob.Model(ob.Plate.grid(4, 4, pitch=1.0), 1e-3)
        x = np.array([[0.0, 0.0, 0.0, 1.0], [1.0, 1.0, 2.0, 1.0]])  # z = 0: on the kink
    for atol in (1e-6, 0.05):
        np.testing.assert_array_equal(_refine_kernel.on_kink(model, x, atol),
                                      kink_sources(model, x, atol=atol))


def test_kink_cuts_same_best_fewer_evaluations():
    """LM with steps cut at sub-sensor horizons (kinks=True), Fig. 3 at sigma = 0.1:
    per fit the best candidate is as good (to ftol) and the runs that end on a kink
    take far fewer evaluations than zig-zagging onto it (measured ~98 -> ~10)."""
    from reference.search_numpy import search_options

    from olsbayes.ml.atoms import atoms, cached_default_grid
    from olsbayes.ml.fast.refine import _kinked
    from olsbayes.ml.fast.search import grid_search

    model = ob.Model(ob.Ring(30), 0.1)
    scene = ob.Scene(directions=[0.5, 0.5 + np.pi], intensities=[1.0, 0.2])
    data = model.simulate(scene, rng=5, size=150)
    grid = cached_default_grid(model)
    idx, inten, _ = grid_search(atoms(model, grid), data, 2, search_options(2))
    t, c = idx.shape[:2]
    x0 = np.concatenate([grid[idx], inten[..., None]], axis=-1).reshape(t * c, -1)
    rep = np.repeat(data, c, axis=0)
    plain = refine_batch(model, rep, x0)
    cut = refine_batch(model, rep, x0, kinks=True)
    assert cut.converged.all()
    best_plain, best_cut = plain.chi2.reshape(t, c).min(1), cut.chi2.reshape(t, c).min(1)
    assert np.all(best_cut <= best_plain * (1 + 10 * FTOL))
    resid = rep - model.response(cut.x)
    np.testing.assert_allclose(cut.chi2, np.einsum("tn,tn->t", resid, resid), rtol=1e-12)
    on = _kinked(model, plain.x)
    assert on.any(axis=1).sum() >= 50  # the case at issue is common here
    assert cut.n_evaluations.sum() < 0.5 * plain.n_evaluations.sum()


def test_known_cell_matches_sub_sensor_visibility():
    """_known_cell finds the known optimum whose sub-sensor visibility pattern the
    iterate shares (read off the Jacobian's intensity rows, max(cos, 0)); a known
    optimum with a source on a horizon has no cell (ambiguous)."""
    from olsbayes.ml._numba.model import _residual

    model = ob.Model(ob.Ring(12), 0.05)
    kind, law, p, nrm, pos = _kernel._arrays(model)
    step = 2 * np.pi / 12  # crossings every half step (pi / 12)
    known = np.array([[0.1, 1.0, 2.0, 0.5], [1.0, 0.8, -2.0, 0.4], [np.pi / 2, 1.0, 2.0, 0.5]])
    vis = np.zeros((3, 2, 12), np.bool_)
    ok = np.array([_cells._cell(nrm, known[j], vis[j]) for j in range(3)])
    assert ok.tolist() == [True, True, False]  # pi / 2 is on a sub-sensor's horizon
    jt, r = np.zeros((4, 16)), np.zeros(16)
    s = np.zeros(12)
    for x, expect in (([0.1 + 0.02, 0.3, 2.0 - 0.02, 0.9], 0),  # inside known[0]'s cell
                      ([0.1 + step, 1.0, 2.0, 0.5], -1),  # source 0 a whole step away
                      ([1.0 - 0.01, 0.1, -2.0 + 0.01, 2.0], 1),
                      ([np.pi / 2 + 0.01, 1.0, 2.0, 0.5], -1)):  # next to the ambiguous one
        _residual(kind, law, p, nrm, pos, np.array(x), s, jt[:, :12], r[:12], True)
        assert _cells._known_cell(jt, vis, ok, 3) == expect


def test_numpy_lm_stops_at_known_optima_like_the_kernel():
    """Dedupe on the numpy path (custom laws): the starts of a group run one after
    another as in the kernel, so a run that reaches its group's known optimum stops
    there -- the same best optimum per group as without dedupe (to ftol), in fewer
    evaluations, and the same as the compiled path of the equal built-in law."""
    law = CustomSensitivity(lambda c: np.maximum(c, 0.0) ** 3,
                            lambda c: 3 * np.maximum(c, 0.0) ** 2)
    custom = ob.Model(ob.Ring(24), 1e-2, law)
    builtin = ob.Model(ob.Ring(24), 1e-2, ob.CosinePower(3))
    scene = ob.Scene(directions=[0.4, 2.5], intensities=[1.0, 0.6])
    t, c = 6, 5
    data = custom.simulate(scene, rng=31, size=t)
    x0 = _starts(custom, custom.pack(scene), 32, t * c, 0.05)
    rep = np.repeat(data, c, axis=0)
    base = np.full((t, x0.shape[1]), np.nan)
    dedupe = Dedupe(group=c, base=base, tol=1e-4)
    plain = refine_batch(custom, rep, x0)
    fast = refine_batch(custom, rep, x0, dedupe=dedupe)
    comp = refine_batch(builtin, rep, x0, dedupe=dedupe)
    best = [o.chi2.reshape(t, c).min(axis=1) for o in (plain, fast, comp)]
    np.testing.assert_allclose(best[1], best[0], rtol=10 * FTOL)
    np.testing.assert_allclose(best[2], best[0], rtol=10 * FTOL)
    assert fast.n_evaluations.sum() < plain.n_evaluations.sum()
    assert np.all(fast.converged)
    # a run stopped at a known optimum reports a point within tol of it
    again = refine_batch(custom, rep, np.repeat(plain.x[::c], c, axis=0),
                         dedupe=Dedupe(group=c, base=plain.x[::c], tol=1e-4))
    assert np.all(again.n_evaluations <= 2 * 2)


def test_fast_fit_of_a_custom_law_equals_the_builtin_law():
    """The whole fast fit on the numpy LM path (a custom law) reaches the optima of
    the compiled path of the same built-in law: the same algorithm on both paths."""
    law = CustomSensitivity(lambda c: np.maximum(c, 0.0) ** 3,
                            lambda c: 3 * np.maximum(c, 0.0) ** 2)
    custom = ob.Model(ob.Ring(24), 1e-2, law)
    builtin = ob.Model(ob.Ring(24), 1e-2, ob.CosinePower(3))
    scene = ob.Scene(directions=[0.4, 2.5, -1.7], intensities=[1.0, 0.6, 0.8])
    data = custom.simulate(scene, rng=33, size=20)
    a = ob.fit_ml(custom, data, 3, warn=False)
    b = ob.fit_ml(builtin, data, 3, warn=False)
    np.testing.assert_allclose(a.log_likelihood, b.log_likelihood, rtol=0,
                               atol=10 * FTOL * custom.n_sensors)


def test_projection_carries_latitude_over_the_pole():
    """Both paths map |lat| > pi/2 to the same direction with |lat| <= pi/2."""
    from olsbayes.geometry import lonlat_to_unit
    from olsbayes.ml.lm import project

    model = ob.Model(ob.Sphere.fibonacci(40), 1e-2)
    rng = np.random.default_rng(12)
    x = np.column_stack([rng.uniform(-np.pi, np.pi, 500), rng.uniform(-7.0, 7.0, 500),
                         rng.uniform(0.1, 1.0, 500)]).reshape(100, 15)
    a = project(model, x)
    b = x.copy()
    for row in b:
        _kernel._project(1, 0.0, row)
    np.testing.assert_array_equal(a, b)
    assert np.all(np.abs(a[:, 1::3]) <= np.pi / 2)
    assert np.all(np.abs(a[:, 0::3]) <= np.pi)  # longitudes in (-pi, pi] stay there
    np.testing.assert_allclose(lonlat_to_unit(a[:, 0::3], a[:, 1::3]),
                               lonlat_to_unit(x[:, 0::3], x[:, 1::3]), atol=1e-13)
    inside = np.abs(x[:, 1::3]) <= np.pi / 2
    np.testing.assert_array_equal(a[:, 1::3][inside], x[:, 1::3][inside])


def test_sphere_fit_crosses_the_pole():
    """Starts on the far side of the pole reach the optimum (a clipped latitude stuck there)."""
    model = ob.Model(ob.Sphere.fibonacci(120), 1e-2)
    scene = ob.Scene(directions=[[0.3, 1.35], [2.5, -0.5]], intensities=[1.0, 0.6])
    truth = model.pack(scene)
    data = model.simulate(scene, rng=13, size=20)
    x0 = _starts(model, truth, 14, 20, 0.03)
    x0[:, 0] += np.pi  # 0.43-0.55 rad from the truth, across the north pole
    x0[:, 1] += 1.3 - truth[1]
    best = refine_batch(model, data, np.tile(truth, (20, 1)))
    for run in (refine_batch, refine_batch_numpy):
        out = run(model, data, x0)
        assert out.converged.all()
        np.testing.assert_allclose(out.chi2, best.chi2, rtol=10 * FTOL)
        assert out.n_evaluations.max() <= 40
