"""The set-up of the K-tuple search (olsbayes.ml.fast.tuples and .coarse): the same tuples and
subsets as the numpy statements they replace.

* ``_regular`` keeps a tuple when its Gram matrix has ``w_min > 1e-10 w_max``
  (eigvalsh), proving most tuples regular from their determinant instead: the kept
  tuples must be exactly eigvalsh's, also for near-collinear, repeated and dead atoms.
* The farthest-point sampling keeps each chosen atom's distances for the later
  subsets: the subsets must be those of the sampling that recomputes them.
* The tuples of a coarse subset come from one memoised array: itertools' order.
"""

from __future__ import annotations

import itertools
from math import comb

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.ml.atoms import atoms, cached_default_grid
from olsbayes.ml.fast import coarse, tuples


def _eigvalsh_keep(a: np.ndarray) -> np.ndarray:
    w = np.linalg.eigvalsh(a)
    return w[:, 0] > 1e-10 * w[:, -1]


def _grams(rng, k: int, n: int = 30) -> np.ndarray:
    """Gram matrices of K-tuples of atoms: random clipped cosines, and atoms that are
    repeated, zero, or a combination of the others up to a tiny perturbation (condition
    numbers from 1e2 to beyond 1e16, across the 1e10 bound)."""
    base = np.maximum(rng.standard_normal((40, n)), 0.0)
    mats = []
    for c in itertools.combinations(range(12), k):
        mats.append(base[list(c)])
    for eps in 10.0 ** -np.arange(0, 17, 0.5):
        for _ in range(6):
            x = np.maximum(rng.standard_normal((k, n)), 0.0)
            w = rng.standard_normal(k - 1)
            x[-1] = w @ x[:-1] + eps * rng.standard_normal(n)  # near-collinear
            mats.append(x * rng.uniform(0.1, 10.0, (k, 1)))
    x = base[:k].copy()
    x[-1] = x[0]  # a repeated atom
    mats.append(x)
    x = base[:k].copy()
    x[0] = 0.0  # an atom no sub-sensor sees
    mats.append(x)
    g = np.array(mats)
    return np.einsum("cin,cjn->cij", g, g)  # the first C(12, K): tuples of random atoms


@pytest.mark.parametrize("k", [2, 3, 4, 5])
def test_regular_tuples_are_those_eigvalsh_keeps(k, rng):
    a = _grams(rng, k)
    keep = tuples._regular(a)
    want = _eigvalsh_keep(a)
    np.testing.assert_array_equal(keep, want)
    assert 0 < want.sum() < want.size  # both kinds present
    if k <= 4:  # the determinant decides the random atoms' tuples, and only where it may
        sure = tuples._det(a) > tuples.SURE_REGULAR * np.trace(a, axis1=1, axis2=2) ** k
        assert sure[: comb(12, k)].all() and not np.any(sure & ~want)


@pytest.mark.parametrize("k", [2, 3, 4])
def test_cofactor_determinants_equal_lu(k, rng):
    a = rng.standard_normal((200, k, k))
    np.testing.assert_allclose(tuples._det(a), np.linalg.det(a), rtol=1e-12, atol=1e-12)


def _numpy_subsets(g, size, n_sets):
    """coarse_subsets' plain farthest-point sampling, every distance recomputed."""
    norm = np.linalg.norm(g, axis=1)
    live = coarse._live(norm)
    u = g[live] / norm[live, None]
    size = min(size, live.size)
    out = []
    for j in range(n_sets):
        for rank in coarse._seed_ranks(j, live.size, n_sets):
            chosen, dist = [rank], np.linalg.norm(u - u[rank], axis=1)
            for _ in range(size - 1):
                chosen.append(int(np.argmax(dist)))
                dist = np.minimum(dist, np.linalg.norm(u - u[chosen[-1]], axis=1))
            sub = live[np.sort(chosen)]
            if not any(np.array_equal(sub, s) for s in out):
                out.append(sub)
                break
    return out


@pytest.mark.parametrize("case", ["ring", "sphere", "plate"])
def test_sampling_with_kept_distances_equals_recomputing_them(case, monkeypatch):
    model = {"ring": ob.Model(ob.Ring(100), 1e-2),
             "sphere": ob.Model(ob.Sphere.fibonacci(60), 1e-2),
             "plate": ob.Model(ob.Plate.grid(6, 6, 1.0), 1e-2)}[case]
    g = atoms(model, cached_default_grid(model))
    assert g.size <= coarse.GRAM_SAMPLING_ENTRIES  # the plain route
    for size, n_sets in ((20, 24), (60, 3)):
        want = _numpy_subsets(g, size, n_sets)
        for room in (coarse.DISTANCE_ROWS_BYTES, 8 * g.shape[0] * 5):  # all rows kept; 5
            monkeypatch.setattr(coarse, "DISTANCE_ROWS_BYTES", room)
            got = coarse.coarse_subsets(g, size, n_sets)
            assert len(got) == len(want)
            for a, b in zip(got, want):
                np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("n,k", [(5, 2), (20, 4), (27, 3), (100, 2), (9, 9), (3, 4)])
def test_combinations_are_itertools_in_lexicographic_order(n, k):
    got = tuples._combinations(n, k)
    want = np.array(list(itertools.combinations(range(n), k)), dtype=np.int64).reshape(-1, k)
    np.testing.assert_array_equal(got, want)
    assert got.dtype == np.int64 and not got.flags.writeable  # shared by the plans
