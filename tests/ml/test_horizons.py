"""Sources held on sub-sensor horizons by the compiled LM (olsbayes.ml._numba.horizons).

With the clipped cosine chi^2 has a kink where a source crosses a sub-sensor's
horizon (n . u = 0).  chi^2 is smooth on either side, so a point x is a local
minimum when no direction d lowers chi^2 to first order: the cosine between the
residual r and the response change along d, r . (f(x + h d) - f(x)) / (|r| |df|),
is <= 0 for every d (a one-sided derivative for d across a horizon).  LM stops
when its step would lower chi^2 by less than ftol chi^2; the best step along one
direction lowers it by cos^2 |r|^2, so a run stopped at a minimum has every
cosine below sqrt(ftol) = 1e-5.  A run that stops short on a kink, zig-zagging
across it, leaves a descent direction along the horizon.
"""

from __future__ import annotations

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.geometry import lonlat_to_unit
from olsbayes.ml import fit_ml
from olsbayes.ml._numba import horizons
from olsbayes.ml._numba import lm as _kernel
from olsbayes.ml.lm import refine_batch

FTOL = 1e-10
#: Largest first-order descent cosine an LM stop at a minimum leaves.
COS_TOL = np.sqrt(FTOL)
ON = 1e-9


def _scenes(k: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` sphere scenes (n, 3K), sources >= 30 deg apart, I ~ U(0.5, 1)."""
    out = []
    while len(out) < n:
        lon, lat = rng.uniform(-np.pi, np.pi, k), np.arcsin(rng.uniform(-1, 1, k))
        u = lonlat_to_unit(lon, lat)
        d = np.arccos(np.clip(u @ u.T, -1.0, 1.0)) + np.pi * np.eye(k)
        if d.min() >= np.radians(30.0):
            out.append(np.column_stack([lon, lat, rng.uniform(0.5, 1.0, k)]).ravel())
    return np.array(out)


def _on_horizon(model: ob.Model, x: np.ndarray) -> np.ndarray:
    """bool (K,): source k within ON of some sub-sensor's horizon."""
    u = lonlat_to_unit(x[0::3], x[1::3])  # (K, 3)
    return np.abs(u @ model.array.normals.T).min(axis=1) <= ON


def _worst_cosine(model: ob.Model, s: np.ndarray, x: np.ndarray, h: float = 1e-7) -> float:
    """Largest descent cosine at x (P,) over +-each coordinate and, for a source on a
    horizon, 16 directions of its tangent plane."""
    p = x.size
    dirs = list(np.eye(p)) + list(-np.eye(p))
    for a in np.flatnonzero(_on_horizon(model, x)):
        for ang in np.linspace(0.0, 2 * np.pi, 16, endpoint=False):
            d = np.zeros(p)
            d[3 * a], d[3 * a + 1] = np.cos(ang) / np.cos(x[3 * a + 1]), np.sin(ang)
            dirs.append(d)
    f0 = model.response(x)
    r = s - f0
    df = model.response(x + h * np.array(dirs)) - f0  # (D, N)
    norm = np.linalg.norm(df, axis=1) * np.linalg.norm(r)
    return float(np.max(df @ r / norm))


@pytest.fixture(scope="module")
def sphere_runs():
    """LM from the truth, plain and holding horizons: Fig. 2 sphere, K = 3, 40 scenes
    at sigma = 0.03 (10 of the held runs end on a horizon, 10 plain ones stop short)."""
    model = ob.Model(ob.Sphere.grid(15, 20), 3e-2)
    rng = np.random.default_rng(11)
    x0 = _scenes(3, 40, rng)
    data = model.simulate(x0, rng=rng)
    return model, data, refine_batch(model, data, x0), refine_batch(model, data, x0, kinks=True)


def test_holding_horizons_ends_at_kink_minima(sphere_runs):
    """Runs that hold sources on horizons are as good as plain runs or better, and
    a second such run from the first (a held or frozen source may leave its
    horizon there) ends at a minimum: all descent cosines below sqrt(ftol).  Many
    end on a horizon, and plain LM stops short of the minimum on some of them."""
    model, data, plain, held = sphere_runs
    assert held.converged.all()
    assert np.all(held.chi2 <= plain.chi2 * (1 + 10 * FTOL))
    resid = data - model.response(held.x)
    np.testing.assert_allclose(held.chi2, np.einsum("tn,tn->t", resid, resid), rtol=1e-12)
    on = np.array([_on_horizon(model, x).any() for x in held.x])
    assert on.sum() >= 5  # the case at issue is common
    again = refine_batch(model, data, held.x, kinks=True)  # as the fast fit's polish
    worst = [_worst_cosine(model, s, x) for s, x in zip(data, again.x)]
    assert max(worst) <= COS_TOL
    short = [_worst_cosine(model, s, x) for s, x in zip(data, plain.x)]
    assert sum(c > COS_TOL for c in short) >= 5


def test_sphere_fits_end_at_kink_minima():
    """The fast fit's polish leaves no first-order descent direction (K = 3, 4 at
    sigma = 0.03; without it 3 and 2 of these 20 fits each stopped short), and a
    batch equals a loop of single fits."""
    model = ob.Model(ob.Sphere.grid(15, 20), 3e-2)
    rng = np.random.default_rng(12)
    for k in (3, 4):
        x0 = _scenes(k, 20, rng)
        data = model.simulate(x0, rng=rng)
        fit = fit_ml(model, data, k, warn=False)
        worst = [_worst_cosine(model, s, x) for s, x in zip(data, fit.params)]
        assert max(worst) <= COS_TOL, k
        one = [fit_ml(model, s, k, warn=False) for s in data]  # the polish's second run
        np.testing.assert_array_equal([f.params for f in one], fit.params)  # takes a subset
        np.testing.assert_array_equal([f.n_evaluations for f in one], fit.n_evaluations)


def test_sphere_crossing_lies_on_the_horizon():
    """sphere_kink: the first crossing of a step is where n_q . u = 0 (Newton's root),
    no other flipped sub-sensor is crossed before it, and horizon_normal is the unit
    gradient of n_q . u over (lon, lat)."""
    model = ob.Model(ob.Sphere.grid(15, 20), 1e-2)
    _, law, p, nrm, pos = _kernel._arrays(model)
    rng = np.random.default_rng(13)
    n_pad = (model.n_sensors + 15) // 16 * 16
    tested = 0
    while tested < 20:
        x = _scenes(2, 1, rng)[0]
        step = np.zeros(6)
        step[:2] = rng.normal(0.0, 0.1, 2)
        jt, jt2 = np.zeros((6, n_pad)), np.zeros((6, n_pad))
        jt[2, : model.n_sensors] = np.maximum(lonlat_to_unit(x[0], x[1]) @ nrm, 0.0)
        y = x + step
        jt2[2, : model.n_sensors] = np.maximum(lonlat_to_unit(y[0], y[1]) @ nrm, 0.0)
        flipped = (jt[2, : model.n_sensors] > 0) != (jt2[2, : model.n_sensors] > 0)
        if not flipped.any():
            continue
        tested += 1
        alpha, src, sub = horizons.sphere_kink(nrm, x, step, jt, jt2, np.zeros(6, np.bool_))
        assert src == 0 and 0.0 < alpha <= 1.0
        z = x + alpha * step
        assert abs(lonlat_to_unit(z[0], z[1]) @ nrm[:, sub]) <= 1e-14
        ts = np.linspace(0.0, alpha, 200)[:-1]
        c = lonlat_to_unit(x[0] + ts * step[0], x[1] + ts * step[1]) @ nrm  # (200, N)
        assert np.all((c[:, flipped] > 0) == (c[:1, flipped] > 0))  # none crossed earlier
        hc = np.zeros(6)
        assert horizons.horizon_normal(nrm, sub, z, 0, hc)
        eps = 1e-7
        grad = [(lonlat_to_unit(z[0] + e0, z[1] + e1) @ nrm[:, sub]) / eps
                for e0, e1 in ((eps, 0.0), (0.0, eps))]
        np.testing.assert_allclose(hc[:2], np.array(grad) / np.hypot(*grad), atol=1e-6)
