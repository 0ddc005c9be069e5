"""The paper's baseline: multi-start global optimisation with a quasi-Newton method.

M pseudo-random starting points drawn from the whole parameter space (uniform
directions on the circle or sphere, uniform positions in the candidate volume,
uniform intensities), each refined by L-BFGS-B (quasi-Newton with bounds) on
the negative log-likelihood with its analytic gradient; the best optimum wins.
Its cost grows with the number of starts M needed to hit the global basin,
which grows exponentially with K.  Kept as the reference for the benchmark.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import integer
from ..bounds import kink_sources
from ..model import Model
from .lm import z_floor
from .outcome import FitOutcome

__all__ = ["MultistartOptions", "fit_multistart", "random_starts"]


@dataclass(frozen=True)
class MultistartOptions:
    """Options of ``fit_ml(method="multistart")``, the paper's baseline.

    Attributes
    ----------
    n_starts : int
        Pseudo-random starts per data vector (1..100,000).
    max_iter : int
        Iteration cap of each L-BFGS-B run (>= 1).
    """

    n_starts: int = 20
    max_iter: int = 500

    def __post_init__(self) -> None:
        object.__setattr__(self, "n_starts", integer("n_starts", self.n_starts, low=1,
                                                     high=100_000))
        object.__setattr__(self, "max_iter", integer("max_iter", self.max_iter, low=1,
                                                     high=100_000))


def random_starts(
    model: Model, data: np.ndarray, n_sources: int, n: int, grid: np.ndarray,
    *, rng: np.random.Generator,
) -> np.ndarray:
    """``n`` pseudo-random starting vectors for one data vector, shape (n, P)."""
    k = n_sources
    if model.kind == "angle":
        loc = rng.uniform(-np.pi, np.pi, size=(n, k, 1))
        gref = 1.0
    elif model.kind == "lonlat":
        lon = rng.uniform(-np.pi, np.pi, size=(n, k))
        lat = np.arcsin(rng.uniform(-1.0, 1.0, size=(n, k)))
        loc = np.stack([lon, lat], axis=-1)
        gref = 1.0
    else:
        lo, hi = grid.min(axis=0), grid.max(axis=0)
        loc = rng.uniform(lo, hi, size=(n, k, 3))
        gref = 1.0 / float(np.median(grid[:, 2])) ** 2
    imax = 2.0 * max(float(np.max(data)), model.sigma) / gref
    inten = rng.uniform(0.0, imax, size=(n, k, 1))
    return np.concatenate([loc, inten], axis=-1).reshape(n, -1)


def _bounds(model: Model, k: int) -> list[tuple[float | None, float | None]]:
    if model.kind == "angle":
        per = [(None, None), (0.0, None)]
    elif model.kind == "lonlat":
        per = [(None, None), (-np.pi / 2, np.pi / 2), (0.0, None)]
    else:
        per = [(None, None), (None, None), (z_floor(model), None), (0.0, None)]
    return per * k


def _objective(model: Model, s: np.ndarray):
    scale = 0.5 / model.sigma**2

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        r = s - model.response(x)
        return scale * float(r @ r), -2.0 * scale * (model.jacobian(x).T @ r)

    return fun


def _fit_one(
    model: Model, s: np.ndarray, k: int, starts: np.ndarray, max_iter: int
) -> tuple[np.ndarray, float, bool, int, np.ndarray, np.ndarray]:
    """Best of the starts, and every start's optimum.

    Returns x, chi^2, converged, evaluations, and every start's optimum (x (M, P),
    chi^2 (M,), inf where the start did not converge).
    """
    from scipy.optimize import minimize  # on use: scipy is slow to import
    fun, bounds = _objective(model, s), _bounds(model, k)
    best, nev = None, 0
    xs, chi2s = np.empty((len(starts), model.n_params(k))), np.empty(len(starts))
    for j, x0 in enumerate(starts):
        res = minimize(
            fun, x0, jac=True, method="L-BFGS-B", bounds=bounds,
            options={"maxiter": max_iter, "ftol": 1e-13, "gtol": 1e-9},
        )
        nev += 2 * int(res.nfev)
        xs[j] = res.x
        chi2s[j] = 2.0 * model.sigma**2 * float(res.fun) if _converged(model, res) else np.inf
        if best is None or res.fun < best.fun:
            best = res
    chi2 = 2.0 * model.sigma**2 * float(best.fun)
    return best.x, chi2, _converged(model, best), nev, xs, chi2s


def _converged(model: Model, res) -> bool:
    """L-BFGS-B success, or a line search that failed at a genuine optimum.

    L-BFGS-B ends with ``ABNORMAL`` (no decrease along its direction) both at a
    smooth optimum known to working precision (negligible gradient,
    |grad| <= 1e-4 (1 + |f|) in log-likelihood units) and at a minimum on the kink
    of the clipped cosine (a sub-sensor 90 deg from a source, where the gradient
    jumps); both count as converged.
    """
    if res.success:
        return True
    if res.status != 2:
        return False
    small = float(np.max(np.abs(res.jac))) <= 1e-4 * (1 + abs(res.fun))
    return small or bool(np.any(kink_sources(model, res.x, atol=1e-5)))


def fit_multistart(model: Model, data: np.ndarray, n_sources: int, grid: np.ndarray,
                   options: MultistartOptions, *, rng: np.random.Generator) -> FitOutcome:
    """Multi-start L-BFGS-B fits of a batch ``data`` (T, N), one data vector at a time.

    Starts for data vector i are drawn from ``rng`` in order, so the result of a
    batch equals a loop of single fits that share one Generator sequentially.
    ``grid`` (M, d): the box of the random positions on a plate.
    """
    n_starts, max_iter = options.n_starts, options.max_iter
    t, p = data.shape[0], model.n_params(n_sources)
    x, chi2 = np.empty((t, p)), np.empty(t)
    conv, nev = np.empty(t, bool), np.empty(t, np.int64)
    alt_x, alt_chi2 = np.empty((t, n_starts, p)), np.empty((t, n_starts))
    for i in range(t):
        starts = random_starts(model, data[i], n_sources, n_starts, grid, rng=rng)
        x[i], chi2[i], conv[i], nev[i], alt_x[i], alt_chi2[i] = _fit_one(
            model, data[i], n_sources, starts, max_iter)
    return FitOutcome(x=x, chi2=chi2, converged=conv, n_evaluations=nev,
                      alternatives=(alt_x, alt_chi2))
