"""Sphere atoms over a spanning tree (olsbayes.ml.fast.search.tree_views): the search's
correlations G @ s from each atom's lit hemisphere, updated along the tree's edges,
equal to the atoms' own products to rounding, used only where the atoms are the
clipped cosine of a sphere and the tree saves work."""

from __future__ import annotations

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.geometry import lonlat_to_unit
from olsbayes.ml import fit_ml
from olsbayes.ml._numba.hemispheres import tree_correlations
from olsbayes.ml.atoms import atoms, cached_default_grid
from olsbayes.ml.fast import search


def _irregular():
    """Random normals, one of them repeated and one its opposite."""
    rng = np.random.default_rng(4)
    u = lonlat_to_unit(rng.uniform(-np.pi, np.pi, 60), np.arcsin(rng.uniform(-1, 1, 60)))
    return ob.SensorArray(np.concatenate([u, u[:1], -u[1:2]]))


SPHERES = {
    "fibonacci 16": lambda: ob.Sphere.fibonacci(16),
    "fibonacci 1000": lambda: ob.Sphere.fibonacci(1000),
    "irregular, a repeated and an opposite normal": _irregular,
}


def correlations(tree, s):
    out = np.empty(tree[0].size)
    tree_correlations(s, tree, np.empty((tree[0].size, 3)), out)
    return out


def _on_horizons(normals):
    """Directions (lon, lat) exactly on the horizons of the first sub-sensors."""
    n = normals[:5]
    t = np.cross(n, [0.0, 0.0, 1.0]) + np.cross(n, [1.0, 0.0, 0.0]) * 1e-3
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    t -= np.sum(t * n, axis=1, keepdims=True) * n
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return np.column_stack([np.arctan2(t[:, 1], t[:, 0]), np.arcsin(np.clip(t[:, 2], -1, 1))])


@pytest.mark.parametrize("sphere", list(SPHERES))
@pytest.mark.parametrize("grid", ["default", "dense random"])
def test_tree_correlations_equal_the_atoms_products(sphere, grid):
    """For Fibonacci and irregular spheres (a repeated and an opposite normal), on the
    default grid or on 3000 random directions with some exactly on a sub-sensor's
    horizon, the tree's correlations equal G @ s to 1e-13 of the largest."""
    model = ob.Model(SPHERES[sphere](), 1e-2)
    if grid == "default":
        lonlat = cached_default_grid(model)
    else:
        rng = np.random.default_rng(5)
        lonlat = np.concatenate([np.column_stack([rng.uniform(-np.pi, np.pi, 3000),
                                                  np.arcsin(rng.uniform(-1, 1, 3000))]),
                                 _on_horizons(model.array.normals)])
    g = atoms(model, lonlat)
    tree = search.tree_views(g, model.array.normals, lonlat)
    assert tree[0].size == g.shape[0]
    assert tree[3].size <= search._TREE_SHARE * g.size
    data = model.simulate(ob.Scene(directions=[[0.3, 0.2], [2.0, -0.5], [-2.2, 1.0]],
                                   intensities=[1.0, 0.6, 0.3]), rng=3, size=5)
    for s in data:
        ref = g @ s
        np.testing.assert_allclose(correlations(tree, s), ref, rtol=0,
                                   atol=1e-13 * np.max(np.abs(ref)))


def test_atoms_of_another_law_or_array_get_no_tree():
    """cos^3 atoms on a sphere are not the clipped cosine, a few scattered atoms
    would cost more over a tree than directly, and a tree of more atoms than
    _TREE_ATOMS would cost seconds to build: all are correlated directly (empty
    tree); so are ring atoms (no tree asked for)."""
    model = ob.Model(ob.Sphere.fibonacci(100), 1e-2, sensitivity=ob.CosinePower(3))
    grid = cached_default_grid(model)
    assert search.tree_views(atoms(model, grid), model.array.normals, grid)[0].size == 0
    plain = ob.Model(ob.Sphere.fibonacci(100), 1e-2)
    few = np.array([[0.0, 0.0], [2.0, 0.5], [-2.0, -0.5], [1.0, 1.2]])
    assert search.tree_views(atoms(plain, few), plain.array.normals, few)[0].size == 0
    rng = np.random.default_rng(6)
    many = np.column_stack([rng.uniform(-np.pi, np.pi, search._TREE_ATOMS + 1),
                            np.arcsin(rng.uniform(-1, 1, search._TREE_ATOMS + 1))])
    small = ob.Model(ob.Sphere.fibonacci(8), 1e-2)
    assert search.tree_views(atoms(small, many), small.array.normals, many)[0].size == 0
    assert search.tree_views(np.ones((3, 4)), None, None) is search._NO_TREE


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_fits_with_the_tree_equal_fits_with_the_atoms(k, monkeypatch):
    """Fits whose search correlates over the tree reach the same optima as fits that
    multiply by the atoms (60 data vectors of the Fig. 2 sphere, 300 sub-sensors,
    sigma = 0.01): the correlations differ by rounding, which can only flip exact
    ties of the search."""
    model = ob.Model(ob.Sphere.fibonacci(300), 1e-2)
    lon = 0.37 + 2 * np.pi * np.arange(k) / k
    lat = np.linspace(-0.6, 0.7, k)
    data = model.simulate(ob.Scene(directions=np.column_stack([lon, lat]),
                                   intensities=np.linspace(1.0, 0.6, k)), rng=19, size=60)
    tree = fit_ml(model, data, k, warn=False)
    monkeypatch.setattr(search, "tree_views", lambda *a: search._NO_TREE)
    dense = fit_ml(model, data, k, warn=False)
    np.testing.assert_allclose(tree.log_likelihood, dense.log_likelihood, rtol=0, atol=1e-8)
    assert np.mean(np.all(np.isclose(tree.params, dense.params, rtol=0, atol=1e-8),
                          axis=1)) >= 0.98
