"""Coarse atom subsets for the K-tuple search: farthest-point sampling of the atoms.

The exhaustive tuple search (:mod:`~olsbayes.ml.fast.tuples`) runs on subsets of
``size`` atoms, small enough for C(size, K) tuples to fit a budget
(:func:`coarse_size`).  Each subset spreads its atoms over the response manifold:
greedy farthest-point sampling on the unit-normalised atoms, from a different seed
per subset (:func:`coarse_subsets`).  The distances come from the atoms, from their
Gram matrix when it is at hand (large atom sets), or lazily through a heap of
bounds (very large atom sets without one).
"""

from __future__ import annotations

import functools
import heapq
from collections.abc import Callable, Iterator
from math import comb

import numpy as np

__all__ = ["coarse_size", "coarse_subsets", "GRAM_SAMPLING_ENTRIES", "LAZY_SAMPLING_ENTRIES",
           "DISTANCE_ROWS_BYTES", "RESEEDS"]


@functools.lru_cache(maxsize=256)
def coarse_size(m: int, n: int, k: int, budget: int) -> int:
    """Largest coarse size <= min(M, 2 N) with C(size, K) <= budget (0 if < K + 1).

    C(size, K) grows with size (size >= K), so the largest one is found by bisection.
    """
    lo, hi = k, min(m, 2 * n)  # C(lo, K) = 1 <= budget; the answer is in [lo, hi]
    if hi <= k:
        return 0
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if comb(mid, k) <= budget:
            lo = mid
        else:
            hi = mid - 1
    return lo if lo > k else 0


#: Atom matrices with more entries (M N) than this, of at most
#: :data:`~olsbayes.ml.atoms.GRAM_ATOMS` atoms (whose Gram matrix the search forms
#: anyway, at most 32 MiB), run the farthest-point sampling on their Gram matrix:
#: O(M) per step instead of O(M N).
GRAM_SAMPLING_ENTRIES = 500_000
#: Atom matrices with more entries than this and no Gram matrix sample lazily: a
#: step of the plain sampling then reads more than 32 MB of atoms, and the lazy one
#: is the faster (``benchmarks/first_fit.py``; docs/performance.md).
LAZY_SAMPLING_ENTRIES = 4_000_000
#: Memory for the distances of the atoms chosen so far, shared by the subsets of one
#: plain sampling (:func:`_plain_sampler`): a 1024-atom grid keeps 4096 rows.
DISTANCE_ROWS_BYTES = 32 * 2**20


def _live(norm: np.ndarray) -> np.ndarray:
    """Indices of the atoms with a response (norm above rounding of the largest)."""
    return np.flatnonzero(norm > 1e-12 * max(norm.max(), 1e-300))


def _unit_distances(g: np.ndarray, gram: np.ndarray | None):
    """``dist(i) -> (M_live,)``: distances of the live unit atoms to live atom i, and live.

    From the unit atoms themselves, or (``gram`` given) from the normalised
    correlations ``c``: ``|u_a - u_b| = sqrt(2 - 2 c_ab)``.  Unit atoms of more than
    :data:`GRAM_SAMPLING_ENTRIES` entries (and no Gram matrix) take the correlations
    one matrix-vector product at a time: no (M, N) temporary per step.
    """
    if gram is None:
        norm = np.linalg.norm(g, axis=1)
    else:
        norm = np.sqrt(np.maximum(np.diag(gram), 0.0))
    live = _live(norm)
    if gram is None:
        u = g[live] / norm[live, None]
        if u.size > GRAM_SAMPLING_ENTRIES:
            return (lambda i: np.sqrt(np.maximum(2.0 - 2.0 * (u @ u[i]), 0.0))), live
        return (lambda i: np.linalg.norm(u - u[i], axis=1)), live
    inv = 1.0 / norm[live]
    corr = gram[np.ix_(live, live)] * inv[:, None] * inv[None, :]
    return (lambda i: np.sqrt(np.maximum(2.0 - 2.0 * corr[i], 0.0))), live


def _lazy_farthest(g: np.ndarray, inv: np.ndarray, seed: int, dist: np.ndarray,
                   size: int) -> list[int]:
    """Farthest-point sampling of the unit atoms ``g * inv[:, None]`` (M, N).

    ``dist`` (M,): the atoms' distances to atom ``seed`` (dead atoms, ``inv`` = 0,
    at -1: never chosen); updated in place.  An atom's distance to the chosen atoms
    only shrinks as atoms are added, so a distance not yet brought up to date is an
    upper bound.  The atoms sit in a max-heap of such bounds; the top one is
    brought up to date (its correlations with the atoms chosen since its last
    update) and chosen if it still heads the heap, ties going to the lower index as
    with ``argmax`` -- the same atoms as the plain sampling up to rounding.  On a
    32 x 32 plate's 39,690 atoms about 70 atoms per step are brought up to date
    instead of all of them, and the atoms are neither copied nor normalised.
    """
    chosen = [int(seed)]
    units = np.empty((size, g.shape[1]))  # the chosen unit atoms, in order
    units[0] = g[seed] * inv[seed]
    applied = np.ones(g.shape[0], np.int64)  # chosen atoms already in dist[x]
    heap = list(zip((-dist).tolist(), range(g.shape[0])))
    heapq.heapify(heap)
    while len(chosen) < size:
        _, x = heapq.heappop(heap)
        if applied[x] < len(chosen):
            corr = (units[applied[x]:len(chosen)] @ g[x]) * inv[x]
            dist[x] = min(dist[x], np.sqrt(np.maximum(2.0 - 2.0 * corr, 0.0)).min())
            applied[x] = len(chosen)
        if heap and (-dist[x], x) > heap[0]:  # another atom may now be farther
            heapq.heappush(heap, (-dist[x], x))
        else:
            units[len(chosen)] = g[x] * inv[x]
            chosen.append(x)
    return chosen


def _lazy_sampler(g: np.ndarray, size: int, n_sets: int) -> tuple[Callable, int]:
    """(sample, L): :func:`_lazy_farthest` from the live atom of a rank, and L live atoms.

    The distances from the ``n_sets`` first seeds (``j L / n_sets``) come in one pass.
    """
    norm = np.sqrt(np.einsum("mn,mn->m", g, g))
    live = _live(norm)
    inv = np.zeros_like(norm)
    inv[live] = 1.0 / norm[live]
    first = live[np.arange(n_sets) * live.size // n_sets]
    rows = dict(zip(first.tolist(),
                    np.sqrt(np.maximum(2.0 - 2.0 * (g[first] @ g.T) * inv[first, None] * inv,
                                       0.0))))
    size = min(size, live.size)

    def sample(rank: int) -> np.ndarray:
        seed = int(live[rank])
        row = rows.pop(seed, None)
        if row is None:
            row = np.sqrt(np.maximum(2.0 - 2.0 * (g @ g[seed]) * inv[seed] * inv, 0.0))
        row[inv == 0.0] = -1.0
        row[seed] = 0.0
        return np.sort(_lazy_farthest(g, inv, seed, row, size))

    return sample, live.size


def _plain_sampler(g: np.ndarray, size: int, gram: np.ndarray | None) -> tuple[Callable, int]:
    """(sample, L): farthest-point sampling from the live atom of a rank, L live atoms.

    The subsets share many atoms (and a repeated seed repeats a whole subset), so
    each atom's distances are computed once and kept while they fit in
    :data:`DISTANCE_ROWS_BYTES`: the same numbers from fewer rows (on a 300-ring at
    K = 4 251 rows instead of 540, on an 8 x 8 plate 91 instead of 480).
    """
    distance, live = _unit_distances(g, gram)
    size = min(size, live.size)
    rows: dict[int, np.ndarray] = {}
    room = DISTANCE_ROWS_BYTES // (8 * max(live.size, 1))

    def row(i: int) -> np.ndarray:
        d = rows.get(i)
        if d is None:
            d = distance(i)
            if len(rows) < room:
                rows[i] = d
        return d

    def sample(rank: int) -> np.ndarray:
        chosen = [rank]
        dist = row(rank)
        for _ in range(size - 1):
            nxt = int(np.argmax(dist))
            chosen.append(nxt)
            dist = np.minimum(dist, row(nxt))
        return live[np.sort(chosen)]

    return sample, live.size


#: Seeds tried in all for a subset whose sampling repeats an earlier subset.
RESEEDS = 16
_GOLDEN = (5**0.5 - 1) / 2


def _seed_ranks(j: int, n_live: int, n_sets: int) -> Iterator[int]:
    """Ranks (among the live atoms) at which subset j may be seeded, in order.

    First ``j L / n_sets``; then points of its slot ``[j L / n_sets, (j + 1) L /
    n_sets)`` at the golden-ratio fractions ``frac(r phi)``, r = 1, 2, ...
    """
    base, width = j * n_live // n_sets, n_live / n_sets
    yield base
    for r in range(1, RESEEDS):
        yield (base + int((r * _GOLDEN) % 1.0 * width)) % n_live


def coarse_subsets(g: np.ndarray, size: int, n_sets: int = 1,
                   gram: np.ndarray | None = None) -> list[np.ndarray]:
    """Up to ``n_sets`` distinct subsets of ``size`` atoms, spread over the response manifold.

    Farthest-point sampling on the unit-normalised atoms (rows of g, shape
    (M, N)), subset j seeded at the live atom of rank ``j * M_live / n_sets``.
    The subsets differ in placement but are not regular shifted grids: on a
    30-ring's 128-atom grid with 20 atoms per subset their gaps range from about
    11 to 25 deg; regular shifted grids reached the global optimum less often.
    A seed can give a subset an earlier seed gave: on rings of 1000 or more
    sub-sensors, whose 1024 atoms are nearly uniform, 24 evenly spaced seeds give
    only 3 distinct subsets (21 on a 300-ring).  Such a subset is drawn again from
    further seeds of its slot (:func:`_seed_ranks`, at most :data:`RESEEDS` in
    all) and left out if every one repeats.  Atoms with zero response (sources
    no sub-sensor sees) are skipped.  With ``gram`` (M, M), the atoms' Gram
    matrix, the distances come from it (equal up to rounding).
    """
    if gram is None and g.size > LAZY_SAMPLING_ENTRIES:  # no (M, N) temporary
        sample, n_live = _lazy_sampler(g, size, n_sets)
    else:
        sample, n_live = _plain_sampler(g, size, gram)
    out: list[np.ndarray] = []
    for j in range(n_sets):
        for rank in _seed_ranks(j, n_live, n_sets):
            sub = sample(rank)
            if not any(np.array_equal(sub, u) for u in out):
                out.append(sub)
                break
    return out
