"""The fast ML fit's compiled grid and K-tuple search (olsbayes.ml._numba.search,
olsbayes.ml._numba.tuples) against the numpy references in tests/reference: the
same candidates (scores differ by rounding only), batch == loop, and the tuple
scores == each tuple's own least squares."""

from __future__ import annotations

import numpy as np
import pytest
from reference.search_numpy import grid_search_numpy, plans, search_options
from reference.tuples_numpy import tuple_scores, tuple_search

import olsbayes as ob


@pytest.mark.parametrize("case", ["ring1", "ring2", "ring3", "ring4", "sphere2", "plate1"])
def test_compiled_search_matches_numpy(case):
    """Compiled grid search == numpy reference: the same candidate atoms (scores differ
    by rounding only, so a flip needs a near-exact tie: allowed in <= 1 % of trials)."""
    from olsbayes.ml.atoms import atoms, default_grid
    from olsbayes.ml.fast.search import grid_search

    if case.startswith("ring"):
        k = int(case[-1])
        model = ob.Model(ob.Ring(30), 1e-2)
        ang = 0.37 + 2 * np.pi * np.arange(k) / k + 0.13 * np.arange(k)
        scene = ob.Scene(directions=ang, intensities=np.linspace(1.0, 0.6, k))
    elif case == "sphere2":
        k, model = 2, ob.Model(ob.Sphere.fibonacci(60), 1e-2)
        scene = ob.Scene(directions=[[0.4, 0.2], [2.5, -0.5]], intensities=[1.0, 0.6])
    else:
        k, model = 1, ob.Model(ob.Plate.grid(5, 5, pitch=1.0), 1e-3)
        scene = ob.Scene(positions=[[2.0, 2.5, 3.0]], intensities=[10.0])
    data = model.simulate(scene, rng=21, size=100)
    g = atoms(model, default_grid(model))
    a_idx, a_int, a_rss = grid_search(g, data, k, search_options(k))
    b_idx, b_int, b_rss = grid_search_numpy(g, data, k, search_options(k))
    assert a_idx.shape == b_idx.shape
    same = np.all(a_idx == b_idx, axis=(1, 2))
    assert same.mean() >= 0.99
    scale = np.max(np.abs(b_int[same]))
    np.testing.assert_allclose(a_int[same], b_int[same], rtol=0, atol=1e-9 * scale)
    ss = np.einsum("tn,tn->t", data, data)[same, None]
    assert np.all(np.abs(a_rss[same] - b_rss[same]) <= 1e-9 * ss)


def test_search_without_pursuit_is_the_tuples():
    """grid_search(pursuit=False) (the fast fit's search at K = 4): exactly the coarse
    subsets' best tuples (the last columns of the full search), compiled == numpy;
    with no coarse plan (n_coarse = 0) the pursuit runs anyway."""
    from olsbayes.ml.atoms import atoms, default_grid
    from olsbayes.ml.fast.search import grid_search

    model = ob.Model(ob.Ring(30), 1e-2)
    scene = ob.Scene(directions=0.37 + np.radians([0.0, 60.0, 150.0, 260.0]),
                     intensities=np.linspace(1.0, 0.6, 4))
    data = model.simulate(scene, rng=23, size=40)
    g = atoms(model, default_grid(model))
    n_p = len(plans(g, 4, 6))
    full = grid_search(g, data, 4, search_options(4, n_coarse=6))
    only = grid_search(g, data, 4, search_options(4, n_coarse=6, pursuit=False))
    assert only[0].shape == (40, n_p, 4)
    for a, b in zip(only, full):
        np.testing.assert_array_equal(a, b[:, -n_p:])
    ref = grid_search_numpy(g, data, 4, search_options(4, n_coarse=6, pursuit=False))
    assert np.mean(np.all(ref[0] == only[0], axis=(1, 2))) >= 0.99
    np.testing.assert_array_equal(
        grid_search(g, data, 4, search_options(4, n_coarse=0, pursuit=False))[0],
        grid_search(g, data, 4, search_options(4, n_coarse=0))[0])


def test_compiled_search_batch_equals_loop():
    from olsbayes.ml.atoms import atoms, default_grid
    from olsbayes.ml.fast.search import grid_search

    model = ob.Model(ob.Ring(30), 1e-2)
    scene = ob.Scene(directions=[0.4, 2.5, -1.9], intensities=[1.0, 0.7, 0.5])
    data = model.simulate(scene, rng=22, size=8)
    g = atoms(model, default_grid(model))
    full = grid_search(g, data, 3, search_options(3))
    for i in range(8):
        one = grid_search(g, data[i : i + 1], 3, search_options(3))
        for a, b in zip(full, one):
            np.testing.assert_array_equal(a[i], b[0])


def test_tuple_plans_each_distinct_subset_once():
    """The farthest-point subsets requested (24 at K = 4 on a 30-ring's default grid,
    some of them coinciding) are all planned, each distinct one exactly once."""
    from olsbayes.ml.atoms import atoms, cached_default_grid
    from olsbayes.ml.fast.coarse import coarse_size, coarse_subsets

    model = ob.Model(ob.Ring(30), 0.01)
    g = atoms(model, cached_default_grid(model))
    requested = coarse_subsets(g, coarse_size(*g.shape, 4, 5_000), 24)
    planned = [tuple(p.subset) for p in plans(g, 4, 24)]
    assert len(planned) == len(set(planned))
    assert set(planned) == {tuple(s) for s in requested}


@pytest.mark.parametrize("lazy", [False, True])
def test_coarse_subsets_are_distinct_on_a_uniform_ring(lazy, monkeypatch):
    """On a 1000-ring the 1024 atoms are nearly uniform and 24 evenly spaced seeds
    give 3 distinct farthest-point subsets; the repeats are drawn again from other
    seeds of their slots: 24 distinct subsets, each a farthest-point sampling."""
    from olsbayes.ml.atoms import atoms, cached_default_grid
    from olsbayes.ml.fast import coarse

    model = ob.Model(ob.Ring(1000), 0.01)
    g = np.array(atoms(model, cached_default_grid(model)))
    if lazy:
        monkeypatch.setattr(coarse, "LAZY_SAMPLING_ENTRIES", g.size - 1)
    size = coarse.coarse_size(*g.shape, 4, 5_000)
    subsets = coarse.coarse_subsets(g, size, 24)
    assert len({tuple(s) for s in subsets}) == len(subsets) == 24
    u = g / np.linalg.norm(g, axis=1)[:, None]
    far = np.sqrt(np.maximum(2.0 - 2.0 * u @ u.T, 0.0))  # unit-atom distances (M, M)

    def farthest_from(seed: int, sub: np.ndarray) -> bool:
        """Whether sub is a farthest-point sampling seeded at ``seed`` (ties to 1e-9)."""
        dist, rest = far[seed].copy(), set(sub) - {seed}
        while rest:
            top = dist.max()
            nxt = [i for i in rest if dist[i] >= top - 1e-9]
            if not nxt:
                return False
            rest.remove(nxt[0])
            dist = np.minimum(dist, far[nxt[0]])
        return True

    for sub in subsets:
        assert any(farthest_from(seed, sub) for seed in sub)


def test_four_sources_on_a_1000_ring_reach_the_optimum():
    """A scene whose fit, with 3 distinct coarse subsets, ended 1500 nats below LM
    from the truth; with 24 it reaches that optimum."""
    from olsbayes.ml.lm import refine_batch

    model = ob.Model(ob.Ring(1000), 0.01)
    truth = model.pack(ob.Scene(directions=np.radians([-130.79, -1.71, 29.28, 67.94]),
                                intensities=[0.849, 0.595, 0.928, 0.829]))
    data = model.simulate(truth, rng=18)
    fit = ob.fit_ml(model, data, 4, warn=False)
    at_truth = refine_batch(model, data[None], truth[None]).x[0]
    assert fit.log_likelihood >= model.log_likelihood(at_truth, data) - 1e-6


def _tuple_case(k: int, dtype):
    """A coarse plan, data and every tuple's own least-squares solve (float64)."""
    from olsbayes.ml.atoms import atoms, cached_default_grid

    model = ob.Model(ob.Ring(30), 0.05)
    rng = np.random.default_rng(3)
    scene = ob.Scene(directions=rng.uniform(0, 2 * np.pi, k),
                     intensities=np.linspace(1.0, 0.3, k))
    data = model.simulate(scene, rng=rng, size=12)
    g = atoms(model, cached_default_grid(model))
    plan = plans(g, k, 1, dtype=dtype)[0]
    corr = data @ plan.atoms.T
    a = plan.atoms[plan.combos]  # (C, K, N)
    b = corr[:, plan.combos]  # (T, C, K)
    coef = np.linalg.solve(a @ np.swapaxes(a, 1, 2), b[..., None])[..., 0]
    return data, plan, corr, coef, np.einsum("tck,tck->tc", b, coef)


@pytest.mark.parametrize("k", [2, 3, 4, 5])
def test_tuple_scores_equal_least_squares(k):
    """The tuple scores by prefix extension (block elimination), in float64 == each
    tuple's own least-squares solve: RSS drop b' G^-1 b where all intensities
    G^-1 b >= 0, else -inf; and the compiled search (K = 5: the generic loops) picks
    a tuple of the largest score."""
    from olsbayes.ml._numba import tuples as tk
    from olsbayes.ml.fast.search import _DENSE, _plan_views

    data, plan, corr, coef, ref = _tuple_case(k, np.float64)
    sc = tuple_scores(plan, corr)
    margin = 1e-9 * np.abs(coef).max(axis=2)  # sign decisions within rounding may differ
    clear = np.all(np.abs(coef) > margin[..., None], axis=2)
    feasible = np.all(coef >= 0, axis=2)
    assert clear.mean() > 0.99
    np.testing.assert_array_equal(np.isfinite(sc)[clear], feasible[clear])
    np.testing.assert_allclose(sc[clear & feasible], ref[clear & feasible], rtol=1e-9)
    out = np.zeros((data.shape[0], 1, k), np.int64)
    tk.tuple_trials(*_plan_views(plan), _DENSE, data, out, 0, -1)
    pick = np.array([np.flatnonzero(np.all(plan.subset[plan.combos] == o, axis=1))[0]
                     for o in out[:, 0]])
    top = np.max(sc, axis=1)
    np.testing.assert_allclose(sc[np.arange(data.shape[0]), pick], top, rtol=1e-12)


def test_float32_tuple_scores_within_rounding_bound():
    """K = 4 plans score in float32 by default: each score is within the first-order
    rounding bound of the block elimination (inputs and every operation rounded,
    eps = 2^-24) of the float64 least-squares score, and feasibility agrees wherever
    every intensity is further from 0 than its own bound."""

    data, plan, corr, coef, ref = _tuple_case(4, None)
    assert plan.ext.dtype == np.float32
    km, eps = 3, np.finfo(np.float32).eps / 2
    p64 = [np.asarray(x, float) for x in (plan.prefix_inv, plan.ext)]
    owner = np.repeat(np.arange(plan.prefixes.shape[1]), np.diff(plan.ext_ptr))
    bp = np.abs(corr[:, plan.prefixes[:, owner]])  # (T, K-1, C) |b_p|
    big_f = np.einsum("ijc,tjc->tic", np.abs(p64[0][..., owner]), bp)  # sum_j |a_ij b_j|
    w, isc = np.abs(p64[1][:km]), np.abs(p64[1][km])
    r_mag = np.abs(corr[:, plan.columns[km]]) + np.einsum("ic,tic->tc", w, bp)
    d_rr = (km + 2) * eps * r_mag  # error of r = b_d - w . b_p
    d_cd = d_rr * isc + eps * np.abs(coef[..., -1])
    bound = ((2 * km + 2) * eps * np.einsum("tic,tic->tc", bp, big_f)
             + 2 * np.abs(coef[..., -1]) * d_rr + 3 * eps * np.abs(ref))
    d_coef = np.concatenate([(km + 2) * eps * big_f + w * d_cd[:, None], d_cd[:, None]], 1)
    clear = np.all(np.abs(coef) > np.moveaxis(d_coef, 1, 2), axis=2)
    feasible = np.all(coef >= 0, axis=2)
    sc = tuple_scores(plan, corr)
    assert sc.dtype == np.float32 and clear.mean() > 0.99
    np.testing.assert_array_equal(np.isfinite(sc)[clear], feasible[clear])
    both = clear & feasible
    assert np.all(np.abs(sc[both] - ref[both]) <= bound[both])


@pytest.mark.parametrize("k", [2, 3, 4])
def test_blocked_tuple_search_equals_per_trial(k):
    """Tuple search over blocks of trials (K = 2..4) == one trial at a time, exactly,
    for the best tuple and for the best tuple of a second mode (outside the best's
    basins), and both == the numpy reference tuple_search; correlations from the ring
    atoms' arcs pick the same tuples."""
    from olsbayes.ml._numba import tuples as tk
    from olsbayes.ml.atoms import atoms, cached_default_grid
    from olsbayes.ml.fast.search import _DENSE, _plan_arcs, _plan_views, arc_views

    model = ob.Model(ob.Ring(30), 0.05)
    rng = np.random.default_rng(8)
    scene = ob.Scene(directions=rng.uniform(0, 2 * np.pi, k),
                     intensities=np.linspace(1.0, 0.3, k))
    data = model.simulate(scene, rng=rng, size=2 * tk.TUPLE_BLOCK + 5)
    grid = cached_default_grid(model)
    g = atoms(model, grid)
    arcs = arc_views(g, model.array.normals, grid)
    for plan in plans(g, k, 3):
        views = _plan_views(plan)
        out = np.zeros((data.shape[0], 2, k), np.int64)
        tk.tuple_trials(*views, _DENSE, data, out, 0, 1)
        one = np.zeros_like(out)
        tk._per_trial(*views, _DENSE, data, one, 0, 1)
        np.testing.assert_array_equal(out, one)
        by_arcs = np.zeros_like(out)
        tk.tuple_trials(*views, _plan_arcs(plan, arcs), data, by_arcs, 0, 1)
        np.testing.assert_array_equal(by_arcs, out)
        best, second = tuple_search(plan, data, distinct=True)
        np.testing.assert_array_equal(out[:, 0], best)
        np.testing.assert_array_equal(out[:, 1], second)
        np.testing.assert_array_equal(tuple_search(plan, data), best)
        unit = g / np.linalg.norm(g, axis=1, keepdims=True)
        corr = np.einsum("tan,tbn->tab", unit[best], unit[second])  # (T, K, K)
        moved = np.any(best != second, axis=1)
        assert moved.mean() > 0.5
        assert np.all(corr[moved] <= 0.95)  # no atom of a second mode in a best's basin


def test_search_gram_route_equals_atom_route(monkeypatch):
    """The search's projections through the atoms' Gram matrix (M <= GRAM_ATOMS) pick
    the same candidates as projecting with the atoms themselves (rounding only)."""
    from olsbayes.ml.atoms import atoms, cached_default_grid
    from olsbayes.ml.fast import search

    model = ob.Model(ob.Ring(30), 1e-2)
    ang = 0.37 + 2 * np.pi * np.arange(3) / 3 + 0.13 * np.arange(3)
    data = model.simulate(ob.Scene(directions=ang, intensities=[1.0, 0.8, 0.6]), rng=4, size=200)
    g = atoms(model, cached_default_grid(model))
    a = search.grid_search(g, data, 3, search_options(3))
    monkeypatch.setattr(search, "GRAM_ATOMS", 0)
    monkeypatch.setattr(search, "_VIEWS", {})
    b = search.grid_search(g, data, 3, search_options(3))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_allclose(a[2], b[2], rtol=1e-9)


def test_gram_neighbour_lists_equal_the_unit_atom_lists():
    """The basins from the Gram matrix (large atom sets) == those from the unit atoms'
    dot products (the same correlations up to rounding, none of them at 0.95 exactly)."""
    from olsbayes.ml._numba import search as sk
    from olsbayes.ml.atoms import atoms, cached_default_grid
    from olsbayes.ml.fast.search import _gram_neighbours

    for model in (ob.Model(ob.Ring(30), 1e-2), ob.Model(ob.Sphere.fibonacci(40), 1e-2)):
        g = atoms(model, cached_default_grid(model))
        gnorm2 = np.einsum("mn,mn->m", g, g)
        unit = np.ascontiguousarray(g / np.sqrt(gnorm2)[:, None])
        ptr_a, idx_a = sk.neighbours(unit)
        ptr_b, idx_b = _gram_neighbours(g @ g.T, gnorm2)
        np.testing.assert_array_equal(ptr_a, ptr_b)
        np.testing.assert_array_equal(idx_a, idx_b)


def test_gram_farthest_point_sampling_is_farthest_point_sampling():
    """Coarse subsets picked on the Gram matrix (atom sets of more than
    GRAM_SAMPLING_ENTRIES entries): each atom added is (to rounding) the live atom
    farthest from those chosen before it, as the unit-atom sampling picks them."""
    from olsbayes.ml.atoms import atoms, cached_default_grid
    from olsbayes.ml.fast.coarse import coarse_subsets

    model = ob.Model(ob.Sphere.fibonacci(100), 1e-2)
    g = atoms(model, cached_default_grid(model))
    u = g / np.linalg.norm(g, axis=1)[:, None]
    for sub in coarse_subsets(g, 40, 3, gram=g @ g.T):
        assert len(set(sub)) == 40
    # replay the greedy order of one subset: seed, then farthest points
    (sub,) = coarse_subsets(g, 12, 1, gram=g @ g.T)
    chosen = [0]
    dist = np.linalg.norm(u - u[0], axis=1)
    for _ in range(11):
        far = dist.max()
        nxt = [i for i in sub if i not in chosen and dist[i] >= far - 1e-9]
        assert nxt, "an atom of the subset is not a farthest point"
        chosen.append(nxt[0])
        dist = np.minimum(dist, np.linalg.norm(u - u[nxt[0]], axis=1))
    assert sorted(chosen) == list(sub)


@pytest.mark.parametrize("lazy", [False, True])
def test_large_unit_atom_farthest_point_sampling_is_farthest_point_sampling(lazy, monkeypatch):
    """Atom sets beyond GRAM_ATOMS atoms and GRAM_SAMPLING_ENTRIES entries (a
    plate's 3-D grid) take correlations by matrix-vector products, and beyond
    LAZY_SAMPLING_ENTRIES (here lowered to this plate's size) bring distances up to
    date lazily: each atom added is still (to rounding) the live atom farthest from
    those chosen before it; dead atoms are never chosen."""
    from olsbayes.ml.atoms import GRAM_ATOMS, atoms, cached_default_grid
    from olsbayes.ml.fast import coarse
    from olsbayes.ml.fast.coarse import GRAM_SAMPLING_ENTRIES, coarse_subsets

    model = ob.Model(ob.Plate.grid(12, 12, 1.0), 1e-2)
    g = atoms(model, cached_default_grid(model))
    g = np.vstack([np.zeros((3, g.shape[1])), g])  # atoms no sub-sensor sees: never chosen
    assert g.shape[0] > GRAM_ATOMS and g.size > GRAM_SAMPLING_ENTRIES
    if lazy:
        monkeypatch.setattr(coarse, "LAZY_SAMPLING_ENTRIES", g.size - 1)
        monkeypatch.setattr(coarse, "_unit_distances", None)  # the lazy path needs none
    norm = np.linalg.norm(g, axis=1)
    live = np.flatnonzero(norm > 1e-12 * norm.max())
    u = g[live] / norm[live, None]
    subsets = coarse_subsets(g, 40, 2)
    for j, sub in enumerate(subsets):
        chosen = [j * live.size // 2]
        dist = np.linalg.norm(u - u[chosen[0]], axis=1)
        for _ in range(39):
            far = dist.max()
            nxt = [i for i in np.searchsorted(live, sub)
                   if i not in chosen and dist[i] >= far - 1e-9]
            assert nxt, "an atom of the subset is not a farthest point"
            chosen.append(nxt[0])
            dist = np.minimum(dist, np.linalg.norm(u - u[nxt[0]], axis=1))
        assert sorted(live[chosen]) == list(sub)


def test_coarse_size_is_the_largest_size_within_the_budget():
    """coarse_size (bisection) == the largest size <= min(M, 2N) with C(size, K) <= budget."""
    import itertools
    from math import comb

    from olsbayes.ml.fast.coarse import coarse_size

    for m, n, k, budget in itertools.product([3, 10, 128, 1024, 2048], [2, 16, 30, 300],
                                             range(2, 9), [1, 10, 3_000, 5_000, 10**6]):
        size = min(m, 2 * n)
        while size > k and comb(size, k) > budget:
            size -= 1
        assert coarse_size(m, n, k, budget) == (size if size > k else 0)


def test_default_grids_are_capped_for_large_arrays():
    """Rings: max(128, 4N) angles up to RING_ATOMS_MAX; spheres: 4N directions clipped to
    SPHERE_ATOMS -- so the Fig. 2 sphere (N = 300) keeps its 1200 directions."""
    from olsbayes.ml.atoms import RING_ATOMS_MAX, SPHERE_ATOMS, default_grid

    ring = {n: default_grid(ob.Model(ob.Ring(n), 1e-2)).shape[0] for n in (16, 30, 256, 300, 5000)}
    assert ring == {16: 128, 30: 128, 256: 1024, 300: RING_ATOMS_MAX, 5000: RING_ATOMS_MAX}
    sphere = {n: default_grid(ob.Model(ob.Sphere.fibonacci(n), 1e-2)).shape[0]
              for n in (20, 300, 5000)}
    assert sphere == {20: SPHERE_ATOMS[0], 300: 1200, 5000: SPHERE_ATOMS[1]}


def test_a_large_search_set_up_says_so_once_per_model(monkeypatch, capsys):
    """Atoms of more than NOTICE_ENTRIES entries print one stderr line when they are
    built, none when the model reuses them; smaller ones print nothing."""
    from olsbayes.ml import atoms as atoms_module

    def building(err: str) -> list[str]:
        return [line for line in err.splitlines() if line.startswith("olsbayes: building")]

    data = ob.Model(ob.Ring(40), 1e-2).simulate(
        ob.Scene(directions=[0.3], intensities=[1.0]), rng=1)
    ob.fit_ml(ob.Model(ob.Ring(40), 1e-2), data, n_sources=1)
    assert building(capsys.readouterr().err) == []
    monkeypatch.setattr(atoms_module, "NOTICE_ENTRIES", 40 * 100)  # the 40-ring's >= 128 atoms
    model = ob.Model(ob.Ring(40), 1e-2)
    for _ in range(2):
        ob.fit_ml(model, data, n_sources=1)
    (line,) = building(capsys.readouterr().err)
    assert "candidate locations x 40 sub-sensors" in line


def test_a_search_with_a_costly_gram_matrix_says_so_once_per_model(monkeypatch, capsys):
    """Atoms of at most GRAM_ATOMS whose Gram matrix costs more than NOTICE_GRAM
    multiply-adds (M^2 N; a 10,000-sphere's first fit) print the set-up line too, once
    per model; beyond GRAM_ATOMS (no Gram matrix) only the atoms' entries count."""
    from olsbayes.ml import atoms as atoms_module

    model = ob.Model(ob.Sphere.fibonacci(40), 1e-2)
    m = atoms_module.cached_default_grid(model).shape[0]
    data = model.simulate(ob.Scene(directions=[[0.3, 0.2]], intensities=[1.0]), rng=1)
    monkeypatch.setattr(atoms_module, "NOTICE_GRAM", float(m * m * 40 - 1))
    for _ in range(2):
        ob.fit_ml(model, data, n_sources=1)
    err = capsys.readouterr().err.splitlines()
    assert [e for e in err if e.startswith("olsbayes: building")] == [
        f"olsbayes: building the search over {m:,} candidate locations x 40 sub-sensors "
        "(once per model and grid; seconds) ..."]
    assert atoms_module._setup_is_long(m, 40) and not atoms_module._setup_is_long(m, 39)
    monkeypatch.setattr(atoms_module, "GRAM_ATOMS", m - 1)  # no Gram matrix: entries only
    assert not atoms_module._setup_is_long(m, 40)
    assert atoms_module._setup_is_long(atoms_module.NOTICE_ENTRIES // 40 + 1, 40)


def test_rings_whose_gram_matrix_comes_from_arcs_count_only_their_entries():
    """Beyond ARC_GRAM_SENSORS a clipped-cosine ring's Gram matrix comes from its arcs in
    O(M^2 + N): its cost no longer makes the set-up long (a 30,000-ring's first fit
    took 0.7 s where the product made it 3-3.6 s), its atoms' entries still do."""
    from olsbayes.ml import atoms as atoms_module

    n = atoms_module.ARC_GRAM_SENSORS
    by_product = atoms_module._gram_by_product
    assert by_product(ob.Model(ob.Ring(n), 1e-2))
    assert not by_product(ob.Model(ob.Ring(n + 1), 1e-2))
    assert by_product(ob.Model(ob.Ring(n + 1), 1e-2, sensitivity=ob.CosinePower(3)))
    assert by_product(ob.Model(ob.Sphere.fibonacci(n + 1), 1e-2))
    m = 1024
    many = int(atoms_module.NOTICE_GRAM / m**2) + 1  # M^2 N beyond NOTICE_GRAM, M N not
    assert atoms_module._setup_is_long(m, many) and not atoms_module._setup_is_long(
        m, many, product=False)
    assert atoms_module._setup_is_long(m, atoms_module.NOTICE_ENTRIES // m + 1, product=False)
