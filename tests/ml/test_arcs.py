"""Ring atoms as arcs of lit sub-sensors (olsbayes.ml.fast.search.arc_views): the
search's correlations G @ s from prefix sums in O(M + N), equal to the atoms' own
products to rounding, used only where the atoms are the clipped cosine of a ring."""

from __future__ import annotations

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.ml import atoms as atoms_module
from olsbayes.ml import fit_ml
from olsbayes.ml._numba.search import _arc_correlations, arc_gram
from olsbayes.ml.atoms import atoms, cached_default_grid
from olsbayes.ml.fast import search


def planar(angles):
    """A planar array (a ring of any layout) of sub-sensors facing ``angles``."""
    angles = np.asarray(angles, float)
    return ob.SensorArray(np.column_stack([np.cos(angles), np.sin(angles)]))


RINGS = {
    "uniform 30": lambda: ob.Ring(30),
    "uniform 1000": lambda: ob.Ring(1000),
    "odd 7": lambda: ob.Ring(7),
    "irregular, a repeated angle": lambda: planar(np.concatenate(
        [np.random.default_rng(2).uniform(-np.pi, np.pi, 40), [0.5, 0.5]])),
}


def correlations(arcs, s):
    n = s.size
    out = np.empty(arcs[3].size)
    _arc_correlations(s, arcs, np.empty(2 * n + 1), np.empty(2 * n + 1), out)
    return out


@pytest.mark.parametrize("ring", list(RINGS))
@pytest.mark.parametrize("grid", ["default", "random"])
def test_arc_correlations_equal_the_atoms_products(ring, grid):
    """For uniform, odd and irregular rings (two sub-sensors at one angle) and for the
    default grid or arbitrary angles (some exactly on a sub-sensor's horizon), the
    correlations from the arcs equal G @ s to 1e-13 of the largest."""
    model = ob.Model(RINGS[ring](), 1e-2)
    if grid == "default":
        angles = cached_default_grid(model)
    else:
        phi = np.arctan2(model.array.normals[:, 1], model.array.normals[:, 0])
        rand = np.random.default_rng(5).uniform(-np.pi, np.pi, 200)
        angles = np.concatenate([rand, phi[:5] + np.pi / 2, phi[:5] - np.pi / 2])[:, None]
    g = atoms(model, angles)
    arcs = search.arc_views(g, model.array.normals, angles)
    assert arcs[3].size == g.shape[0]
    data = model.simulate(ob.Scene(directions=[0.3, 2.0, -2.2], intensities=[1.0, 0.6, 0.3]),
                          rng=3, size=5)
    for s in data:
        ref = g @ s
        np.testing.assert_allclose(correlations(arcs, s), ref, rtol=0,
                                   atol=1e-13 * np.max(np.abs(ref)))


def test_atoms_of_another_law_or_array_are_not_taken_for_arcs():
    """cos^3 atoms on a ring are not the clipped cosine: correlated directly (empty
    arcs); so are sphere atoms (no arcs asked for)."""
    model = ob.Model(ob.Ring(30), 1e-2, sensitivity=ob.CosinePower(3))
    grid = cached_default_grid(model)
    assert search.arc_views(atoms(model, grid), model.array.normals, grid)[3].size == 0
    assert search.arc_views(np.ones((3, 4)), None, None) is search._DENSE


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_fits_with_arcs_equal_fits_with_the_atoms(k, monkeypatch):
    """Fits whose search correlates through the arcs reach the same optima as fits that
    multiply by the atoms (100 data vectors of a 300-ring, sigma = 0.01): the
    correlations differ by rounding, which can only flip exact ties of the search."""
    model = ob.Model(ob.Ring(300), 1e-2)
    ang = 0.37 + 2 * np.pi * np.arange(k) / k + 0.13 * np.arange(k)
    data = model.simulate(ob.Scene(directions=ang, intensities=np.linspace(1.0, 0.6, k)),
                          rng=17, size=100)
    arcs = fit_ml(model, data, k, warn=False)
    monkeypatch.setattr(search, "arc_views", lambda *a: search._DENSE)
    dense = fit_ml(model, data, k, warn=False)
    np.testing.assert_allclose(arcs.log_likelihood, dense.log_likelihood, rtol=0, atol=1e-8)
    assert np.mean(np.all(np.isclose(arcs.params, dense.params, rtol=0, atol=1e-8),
                          axis=1)) >= 0.99


GRAM_RINGS = {**RINGS, "uniform 3001": lambda: ob.Ring(3001),
              "an 80 deg fan": lambda: planar(np.linspace(-0.7, 0.7, 25))}


@pytest.mark.parametrize("ring", list(GRAM_RINGS))
@pytest.mark.parametrize("grid", ["default", "random"])
def test_arc_gram_equals_the_atoms_products(ring, grid):
    """The atoms' Gram matrix from their arcs (two runs of shared sub-sensors where
    two arcs wrap round each other) equals G @ G.T to 1e-13 of its largest entry, on
    the rings and grids above, a ring beyond the size where fits use it, and a fan of
    sub-sensors facing 80 deg, whose atoms light all of them or none."""
    array = GRAM_RINGS[ring]()
    model = ob.Model(array, 1e-2)
    angles = cached_default_grid(model)
    if grid == "random":
        phi = np.arctan2(model.array.normals[:, 1], model.array.normals[:, 0])
        rand = np.random.default_rng(6).uniform(-np.pi, np.pi, 200)
        angles = np.concatenate([rand, phi[:5] + np.pi / 2, phi[:5] - np.pi / 2])[:, None]
    g = atoms(model, angles)
    arcs = search.arc_views(g, model.array.normals, angles)
    out = np.empty((g.shape[0], g.shape[0]))
    arc_gram(arcs, out)
    ref = g @ g.T
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-13 * np.max(ref))
    np.testing.assert_array_equal(out, out.T)


def test_large_rings_fit_through_the_arcs_gram(monkeypatch):
    """Beyond ARC_GRAM_SENSORS sub-sensors the search's Gram matrix comes from the
    arcs and the unit atoms, which no scan reads, are not formed; fits of 20 data
    vectors of a 3001-ring (K = 2, 3) reach the optima of fits through G @ G.T."""
    model = ob.Model(ob.Ring(3001), 1e-2)
    grid = cached_default_grid(model)
    g = atoms(model, grid)
    arcs = search.arc_views(g, model.array.normals, grid)
    views = search._atom_views(g, arcs)
    assert views[3].shape == (g.shape[0], 0)
    out = np.empty_like(views[1])
    arc_gram(arcs, out)
    np.testing.assert_array_equal(views[1], out)
    for k in (2, 3):
        ang = 0.4 + 2 * np.pi * np.arange(k) / k + 0.2 * np.arange(k)
        data = model.simulate(ob.Scene(directions=ang, intensities=np.linspace(1.0, 0.5, k)),
                              rng=k, size=20)
        by_arcs = fit_ml(model, data, k, warn=False)
        with monkeypatch.context() as mp:
            mp.setattr(atoms_module, "ARC_GRAM_SENSORS", 10**9)
            by_product = fit_ml(model, data, k, warn=False)
        np.testing.assert_allclose(by_arcs.log_likelihood, by_product.log_likelihood,
                                   rtol=0, atol=1e-8)
        np.testing.assert_allclose(by_arcs.params, by_product.params, rtol=0, atol=1e-8)
