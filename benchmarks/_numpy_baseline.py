"""A plain-numpy ML fitter of distant sources: dense grid, greedy pursuit, Gauss-Newton.

What a competent user would write without olsbayes, for the benchmarks' baseline:
the unit responses of a dense grid of directions precomputed once per array; per
data vector, K greedy steps of orthogonal matching pursuit (the grid direction
best correlated with the residual, then least-squares intensities of all chosen
directions) and a few damped Gauss-Newton steps on all 2K (ring) or 3K (sphere)
parameters with the analytic Jacobian of Eq. 1 (clipped cosine), intensities kept
>= 0.
"""

from __future__ import annotations

import numpy as np

__all__ = ["NumpyGridFitter"]


def _units(loc: np.ndarray, dim: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """Unit source directions (K, D) and their derivatives per location coordinate."""
    if dim == 2:
        c, s = np.cos(loc[:, 0]), np.sin(loc[:, 0])
        return np.column_stack([c, s]), [np.column_stack([-s, c])]
    lon, lat = loc[:, 0], loc[:, 1]
    cl, sl, co, so = np.cos(lat), np.sin(lat), np.cos(lon), np.sin(lon)
    u = np.column_stack([cl * co, cl * so, sl])
    return u, [np.column_stack([-cl * so, cl * co, np.zeros_like(cl)]),
               np.column_stack([-sl * co, -sl * so, cl])]


class NumpyGridFitter:
    """Grid + pursuit + Gauss-Newton fits of K distant sources, plain numpy.

    Parameters
    ----------
    normals : ndarray, shape (N, D)
        Unit normals of the sub-sensors (D = 2: ring angles, D = 3: lon/lat).
    grid : ndarray, shape (M, D - 1)
        Candidate directions (angles, or lon/lat pairs), rad.
    n_gn : int
        Gauss-Newton steps at most.
    """

    def __init__(self, normals: np.ndarray, grid: np.ndarray, n_gn: int = 10):
        self.nrm = np.asarray(normals, float)
        self.dim = self.nrm.shape[1]
        self.grid = np.asarray(grid, float).reshape(len(grid), -1)
        u, _ = _units(self.grid, self.dim)
        self.atoms = np.maximum(u @ self.nrm.T, 0.0)  # (M, N)
        self.norm2 = np.einsum("mn,mn->m", self.atoms, self.atoms)
        self.n_gn = n_gn
        self._near: np.ndarray | None = None

    def response(self, x: np.ndarray) -> np.ndarray:
        """Readings (N,) of the sources x (K * (D - 1 + 1),)."""
        b = x.reshape(-1, self.dim)
        u, _ = _units(b[:, :-1], self.dim)
        return b[:, -1] @ np.maximum(u @ self.nrm.T, 0.0)

    def _jacobian(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        b = x.reshape(-1, self.dim)
        u, du = _units(b[:, :-1], self.dim)
        c = u @ self.nrm.T  # (K, N)
        lit = c > 0
        cols = []
        for k in range(b.shape[0]):
            for d in du:
                cols.append(b[k, -1] * np.where(lit[k], d[k] @ self.nrm.T, 0.0))
            cols.append(np.maximum(c[k], 0.0))
        return b[:, -1] @ np.maximum(c, 0.0), np.column_stack(cols)

    def pursuit(self, s: np.ndarray, k: int, first: int | None = None) -> np.ndarray:
        """K greedy grid directions and their least-squares intensities, flat (P,).

        ``first``: the first direction's grid index instead of the greedy choice.
        """
        idx, r = [], s
        if first is not None:
            idx.append(first)
            inten = np.linalg.lstsq(self.atoms[idx].T, s, rcond=None)[0]
            r = s - inten @ self.atoms[idx]
        for _ in range(k - len(idx)):
            c = self.atoms @ r
            score = np.where(c > 0, c * c / self.norm2, -np.inf)
            score[idx] = -np.inf
            idx.append(int(np.argmax(score)))
            inten = np.linalg.lstsq(self.atoms[idx].T, s, rcond=None)[0]
            r = s - inten @ self.atoms[idx]
        return np.column_stack([self.grid[idx], np.maximum(inten, 0.0)]).ravel()

    def fit(self, s: np.ndarray, k: int, starts: int = 1) -> tuple[np.ndarray, float]:
        """Fit K sources to readings s (N,): parameters (P,) and chi^2 (sum of squares).

        ``starts`` R > 1: R pursuits, the r-th forced to take the r-th best-correlated
        atom first (then greedy), each refined; the best chi^2 wins.
        """
        if starts == 1:
            return self.refine(s, self.pursuit(s, k))
        fits = [self.refine(s, self.pursuit(s, k, first=f)) for f in self.firsts(s, starts)]
        return min(fits, key=lambda f: f[1])

    def firsts(self, s: np.ndarray, r: int) -> list[int]:
        """The R best-correlated atoms of s, none within cosine 0.95 of one before it."""
        if self._near is None:  # once per array: which atoms are that close, (M, M)
            unit = self.atoms / np.sqrt(self.norm2)[:, None]
            self._near = unit @ unit.T > 0.95
        c = self.atoms @ s
        blocked = c <= 0
        chosen: list[int] = []
        for a in np.argsort(-c * c / self.norm2):
            if len(chosen) == r:
                break
            if not blocked[a]:
                chosen.append(int(a))
                blocked |= self._near[a]
        return chosen

    def refine(self, s: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, float]:
        """Damped Gauss-Newton from x (P,) on readings s (N,): parameters and chi^2."""
        resid = s - self.response(x)
        chi2 = float(resid @ resid)
        inten = np.arange(self.dim - 1, x.size, self.dim)
        for _ in range(self.n_gn):
            _, jac = self._jacobian(x)
            step = np.linalg.lstsq(jac, resid, rcond=None)[0]
            for _ in range(6):  # halve the step until chi^2 falls
                new = x + step
                new[inten] = np.maximum(new[inten], 0.0)
                r_new = s - self.response(new)
                c_new = float(r_new @ r_new)
                if c_new < chi2:
                    break
                step = 0.5 * step
            else:
                break
            done = chi2 - c_new <= 1e-10 * chi2
            x, resid, chi2 = new, r_new, c_new
            if done:
                break
        return x, chi2
