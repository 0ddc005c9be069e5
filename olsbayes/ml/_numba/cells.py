"""Linear cells of the clipped cosine on a ring, for the LM runs' stop at known optima (:mod:`.lm`).

While no source crosses a sub-sensor's horizon (inside one *linear cell*) the
readings of a ring with the clipped cosine are linear in the source phasors
(I cos a, I sin a), and the cell is a product of convex cones, so chi^2 is convex
there.  :func:`_cell` records the visibility pattern of a known optimum (the
sub-sensors that see each source); :func:`_known_cell` tells whether an LM
iterate shares the pattern of one.
"""

from __future__ import annotations

import math

import numba

__all__: list[str] = []


@numba.njit(cache=True)
def _cell(nrm, x, vis):  # pragma: no cover - compiled
    """Fill vis[a, q]: whether sub-sensor q sees source a of the angle fit x.

    Returns False if a source is within 1e-9 of a sub-sensor's horizon (the cell is
    then ambiguous), else True.
    """
    for a in range(x.size // 2):
        u0, u1 = math.cos(x[2 * a]), math.sin(x[2 * a])
        for q in range(nrm.shape[1]):
            c = u0 * nrm[0, q] + u1 * nrm[1, q]
            if abs(c) < 1e-9:
                return False
            vis[a, q] = c > 0.0
    return True


@numba.njit(cache=True)
def _known_cell(jt, known_vis, known_ok, n_known):  # pragma: no cover - compiled
    """Index of a known optimum whose linear cell holds the iterate of Jacobian jt, else -1.

    Ring, clipped cosine: the intensity rows of jt are max(cos, 0).

    Inside a cell the readings are linear in the phasors (I cos a, I sin a) and the
    cell is a product of convex cones, so chi^2 there is convex: a converged
    optimum inside its cell (``known_ok``: no source on a horizon) is the cell's
    only minimum, where a run entering the cell ends unless it leaves it again.
    """
    k, n = known_vis.shape[1], known_vis.shape[2]
    for j in range(n_known):
        same = known_ok[j]
        for a in range(k):
            if not same:
                break
            for q in range(n):
                if (jt[2 * a + 1, q] > 0.0) != known_vis[j, a, q]:
                    same = False
                    break
        if same:
            return j
    return -1
