"""Matching exchangeable sources: pair costs and the best permutation, against brute force."""

import itertools

import numpy as np
import pytest

from olsbayes import exchange
from olsbayes.circular import wrap_angle


def _costs_by_hand(a, b, periodic, scale):
    """cost[..., i, j] = sum_c (diff_c / scale[j, c])^2, one source pair at a time."""
    k = a.shape[-2]
    out = np.empty(a.shape[:-2] + (k, k))
    for i, j in itertools.product(range(k), range(k)):
        d = a[..., i, :] - b[..., j, :]
        d = np.where(periodic, wrap_angle(d), d) / scale[j]
        out[..., i, j] = np.sum(d * d, axis=-1)
    return out


@pytest.mark.parametrize("k, w", [(1, 2), (2, 2), (3, 3), (4, 2), (5, 1)])
def test_pair_costs_are_circular_scaled_squared_distances(k, w):
    rng = np.random.default_rng(k * 10 + w)
    a = rng.uniform(-4, 4, (2, 9, k, w))
    b = rng.uniform(-4, 4, (k, w))
    periodic = np.arange(w) == 0
    scale = rng.uniform(0.1, 2.0, (k, w))
    got = exchange.pair_costs(a, b, periodic, scale)
    np.testing.assert_allclose(got, _costs_by_hand(a, b, periodic, scale), rtol=1e-14)
    np.testing.assert_allclose(exchange.pair_costs(a, b, periodic),
                               _costs_by_hand(a, b, periodic, np.ones((k, w))), rtol=1e-14)


def _best_by_hand(cost):
    """The first permutation (lexicographic order) of least total, for each draw."""
    k = cost.shape[-1]
    perms = list(itertools.permutations(range(k)))
    out = np.empty(cost.shape[:-1], dtype=np.int64)
    for s in np.ndindex(cost.shape[:-2]):
        totals = [sum(cost[s][p[j], j] for j in range(k)) for p in perms]
        out[s] = perms[int(np.argmin(totals))]
    return out


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5, 6])
def test_best_permutation_is_the_least_total_with_ties_to_the_first(k, monkeypatch):
    rng = np.random.default_rng(k)
    cost = rng.integers(0, 4, (3, 7, k, k)).astype(float)  # small integers: many ties
    monkeypatch.setattr(exchange, "_TOTALS_CHUNK", 5 * len(exchange.permutations(k)))
    np.testing.assert_array_equal(exchange.best_permutation(cost), _best_by_hand(cost))


def test_best_permutation_beyond_exhaustive_uses_the_assignment_solver():
    k = exchange.MAX_EXHAUSTIVE + 1
    rng = np.random.default_rng(8)
    truth = np.stack([rng.permutation(k) for _ in range(4)])
    cost = rng.uniform(1, 2, (4, k, k))
    for s, p in enumerate(truth):  # a clearly best assignment: source p[j] takes label j
        cost[s, p, np.arange(k)] = 0.0
    np.testing.assert_array_equal(exchange.best_permutation(cost), truth)
