"""Exact global ML on a ring (fit_ml method="exact"): optimality, recovery, fast fits reach it,
bad input."""

from __future__ import annotations

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.errors import InputError
from olsbayes.ml import fit_ml, refine_batch
from olsbayes.ml.exact import enumerate_optimum

#: Log-likelihood slack of an exact optimum against a local method (rounding only).
LL_TOL = 1e-9


def _random_scene(rng: np.random.Generator, k: int, min_sep: float = np.radians(30.0)):
    """k angles uniform with pairwise circular separation >= min_sep, I ~ U(0.5, 1)."""
    while True:
        a = rng.uniform(-np.pi, np.pi, k)
        gaps = np.abs(ob.wrap_angle(a[:, None] - a[None, :]))
        if k == 1 or gaps[np.triu_indices(k, 1)].min() >= min_sep:
            return ob.Scene(directions=a, intensities=rng.uniform(0.5, 1.0, k))


def fit_exact(model, data, k):
    """The exact global optimum through the public entry point."""
    return fit_ml(model, data, k, "exact")


def _lm_from(model, data, starts):
    """LM refinements from starts (S, P) for one data vector: best log L."""
    out = refine_batch(model, np.tile(data, (len(starts), 1)), starts)
    return model.log_likelihood(out.x, data).max()


def test_k1_beats_dense_grid_with_closed_form_intensity():
    model = ob.Model(ob.Ring(7, offset=0.2), sigma=0.05)
    data = model.simulate(ob.Scene(directions=[0.4], intensities=[1.0]), rng=3)
    res = fit_exact(model, data, 1)
    th = np.linspace(-np.pi, np.pi, 20001)
    g = np.maximum(np.cos(th[:, None] - model.array.angles[None, :]), 0.0)  # (A, N)
    inten = np.maximum(g @ data, 0.0) / np.maximum(np.einsum("an,an->a", g, g), 1e-300)
    grid_ll = model.log_likelihood(np.column_stack([th, inten]), data).max()
    assert res.log_likelihood >= grid_ll - LL_TOL
    assert _lm_from(model, data, res.params[None, :]) <= res.log_likelihood + LL_TOL
    assert res.log_likelihood == pytest.approx(float(model.log_likelihood(res.params, data)))


@pytest.mark.parametrize("n, seed", [(6, 0), (9, 1)])
def test_k2_beats_lm_from_dense_starts_and_is_a_local_optimum(n, seed):
    model = ob.Model(ob.Ring(n, offset=0.1), sigma=0.1)
    data = model.simulate(ob.Scene(directions=[-1.0, 0.9], intensities=[1.0, 0.7]), rng=seed)
    res = fit_exact(model, data, 2)
    a = np.linspace(-np.pi, np.pi, 24, endpoint=False)
    a1, a2 = np.meshgrid(a, a, indexing="ij")
    starts = np.column_stack([a1.ravel(), np.full(a1.size, 0.5), a2.ravel(),
                              np.full(a1.size, 0.5)])
    assert res.log_likelihood >= _lm_from(model, data, starts) - LL_TOL
    assert _lm_from(model, data, res.params[None, :]) <= res.log_likelihood + LL_TOL


def test_noiseless_identifiable_scene_is_recovered():
    model = ob.Model(ob.Ring(30), sigma=0.01)
    scene = ob.Scene(directions=[-2.2, 0.35, 1.4], intensities=[0.9, 0.6, 0.8])
    with pytest.warns(ob.ConvergenceWarning, match="sigma overestimated"):  # no noise
        res = fit_exact(model, model.response(scene), 3)
    np.testing.assert_allclose(res.params, model.canonical(model.pack(scene)), atol=1e-8)
    assert res.n_evaluations == 1 + 60 + 60 * 59 // 2 + 60 * 59 * 58 // 6


@pytest.mark.parametrize("k", [1, 2, 3])
def test_fast_fit_reaches_the_global_optimum(k):
    model = ob.Model(ob.Ring(30), sigma=1e-2)
    rng = np.random.default_rng(100 + k)
    for _ in range(10):
        data = model.simulate(_random_scene(rng, k), rng=rng, size=3)
        exact = fit_exact(model, data, k)
        fast = fit_ml(model, data, k, warn=False)  # random scenes: any notice may apply
        assert np.all(fast.log_likelihood >= exact.log_likelihood - 1e-6)
        assert np.all(exact.log_likelihood >= fast.log_likelihood - LL_TOL)


def test_batch_equals_loop_and_odd_ring():
    model = ob.Model(ob.Ring(9, offset=-0.3), sigma=0.05)
    data = model.simulate(ob.Scene(directions=[0.0, 2.0], intensities=[1.0, 0.8]), rng=5, size=3)
    batch = fit_exact(model, data, 2)
    assert batch.is_batch
    for t in range(3):
        one = fit_exact(model, data[t], 2)
        np.testing.assert_allclose(one.params, batch.params[t], atol=1e-12)
        assert one.log_likelihood == pytest.approx(batch.log_likelihood[t], abs=1e-12)
    with pytest.raises(InputError, match="single fit"):
        batch.scene
    counted = enumerate_optimum(model, data, 2, count_feasible=True)
    quick = enumerate_optimum(model, data, 2)
    assert counted.n_feasible.shape == (3,) and np.all(counted.n_feasible >= 1)
    assert quick.n_feasible is None and np.array_equal(quick.params, counted.params)


@pytest.mark.parametrize(
    "model, k, match",
    [
        (ob.Model(ob.Ring(12), 0.1, "cosine_power"), 1, "clipped cosine"),
        (ob.Model(ob.Sphere.fibonacci(20), 0.1), 1, "Ring"),
        (ob.Model(ob.Ring(12), 0.1), 0, "n_sources"),
        (ob.Model(ob.Ring(12), 0.1), 5, "n_sources"),
        (ob.Model(ob.Ring(5), 0.1), 3, "n_sources"),
        ("not a model", 1, "model"),
    ],
)
def test_bad_input(model, k, match):
    data = np.zeros(getattr(model, "n_sensors", 12))
    with pytest.raises(InputError, match=match):
        fit_exact(model, data, k)


def test_bad_data():
    model = ob.Model(ob.Ring(12), 0.1)
    for bad in (np.zeros(11), np.full(12, np.nan), np.zeros((2, 2, 12))):
        with pytest.raises(InputError, match="data"):
            fit_exact(model, bad, 1)


@pytest.mark.parametrize("n, k", [(8, 3), (11, 2), (30, 2), (7, 3), (10, 4)])
def test_compiled_scan_equals_numpy_reference(n, k):
    from reference import exact_numpy as _exact_numpy

    from olsbayes.ml._numba import exact as _exact_kernel
    from olsbayes.ml.exact import FEAS_RTOL, RANK_RTOL, RERANK_RTOL, _design

    model = ob.Model(ob.Ring(n, offset=0.05 * n), sigma=0.05)
    data = model.simulate(ob.Scene(directions=[-2.0, 0.1, 1.7][:k],
                                   intensities=[1.0, 0.6, 0.8][:k]), rng=11, size=4)
    c, cols = _design(model)
    args = (cols.T @ cols, data @ cols, np.column_stack([np.cos(c), np.sin(c)]), k,
            RERANK_RTOL * np.einsum("tn,tn->t", data, data), RANK_RTOL, FEAS_RTOL, 64)
    gain_c, states_c, count_c, feas_c, n_c = _exact_kernel.scan(*args)
    gain_n, states_n, count_n, feas_n, n_n = _exact_numpy.scan(*args)
    assert n_c == n_n and np.array_equal(feas_c, feas_n) and np.array_equal(count_c, count_n)
    np.testing.assert_allclose(gain_c.max(axis=1), gain_n.max(axis=1), rtol=1e-12)
    for t in range(4):  # the same near-best candidates (ties re-ranked directly later)
        cands_c = sorted(tuple(sorted(st)) for st in states_c[t, : count_c[t]])
        cands_n = sorted(tuple(sorted(st)) for st in states_n[t, : count_n[t]])
        assert cands_c == cands_n
    # without the feasibility count, configurations that cannot be candidates are not
    # solved: the same candidates, no count
    gain_f, states_f, count_f, feas_f, n_f = _exact_kernel.scan(*args, count_feasible=False)
    assert feas_f is None and n_f == n_c and np.array_equal(count_f, count_c)
    assert np.array_equal(gain_f, gain_c) and np.array_equal(states_f, states_c)


def test_a_long_enumeration_says_so_on_stderr(monkeypatch, capsys):
    """More than NOTICE_CONFIGURATIONS configurations (per call, all data vectors)
    print one line on stderr with their number; fewer print nothing."""
    from olsbayes.ml import exact

    model = ob.Model(ob.Ring(8), 1e-2)
    data = model.simulate(ob.Scene(directions=[0.3, 2.0], intensities=[1.0, 0.8]), rng=1,
                          size=2)
    ob.fit_ml(model, data, n_sources=2, method="exact")
    assert "enumerating" not in capsys.readouterr().err
    n = exact.n_configurations(model, 2)
    monkeypatch.setattr(exact, "NOTICE_CONFIGURATIONS", 2 * n - 1)
    ob.fit_ml(model, data, n_sources=2, method="exact")
    (line,) = [x for x in capsys.readouterr().err.splitlines() if "enumerating" in x]
    assert f"enumerating {2 * n:.3g} configurations of K = 2" in line
