"""Imaging: exact window moves (slow local eigen-directions) vs quadrature."""

from __future__ import annotations

import numpy as np
import pytest
from reference.moments import batch_se

import olsbayes as ob
from olsbayes.imaging import ImageOptions, design_matrix, image
from olsbayes.imaging._window_kernel import _line, truncnorm_inv
from olsbayes.imaging.sparse import SweepMoves, gibbs_intensities
from olsbayes.imaging.truncated import truncnorm_1d
from olsbayes.imaging.window import combine, coordinate_moves, window_moves, window_sweep


def _grid_moments(a, y, sigma, hi, n=90):
    """Mean and variance of the box posterior by a midpoint grid on [0, hi]^K (K <= 3)."""
    k = a.shape[1]
    g = (np.arange(n) + 0.5) * hi / n
    pts = np.stack(np.meshgrid(*([g] * k), indexing="ij"), axis=-1).reshape(-1, k)
    logp = -0.5 * np.sum((pts @ a.T - y) ** 2, axis=1) / sigma**2
    w = np.exp(logp - logp.max())
    w /= w.sum()
    mean = w @ pts
    return mean, w @ (pts - mean) ** 2


def _check(samples, mean, var, n_se=5.0):
    x = np.moveaxis(samples, 1, 0)  # (S, C, K)
    k = x.shape[-1]
    se = batch_se(x.mean(axis=1))
    np.testing.assert_array_less(np.abs(x.reshape(-1, k).mean(axis=0) - mean), n_se * se)
    d2 = (x - mean) ** 2
    se2 = batch_se(d2.mean(axis=1))
    np.testing.assert_array_less(np.abs(d2.reshape(-1, k).mean(axis=0) - var), n_se * se2)


@pytest.mark.parametrize(
    "m,s,lo,hi",
    [(0.0, 1.0, -1.0, 1.0), (0.0, 1.0, 40.0, 41.0), (0.0, 1.0, -45.0, -40.0),
     (0.0, 1.0, -np.inf, 0.5), (0.0, 1.0, 0.5, np.inf), (5.0, 0.01, 0.0, 1.0),
     (-5.0, 0.01, 0.0, 1.0), (0.0, 1.0, 8.0, 8.0001), (0.3, 0.01, 0.0, 1.0)],
)
def test_compiled_truncnorm_is_the_same_inversion(m, s, lo, hi):
    # both invert the truncated CDF: the same uniform gives the same draw
    u = np.random.default_rng(3).random(500)
    ref = truncnorm_1d(np.full(500, m), s, lo, hi, rng=np.random.default_rng(3))
    got = np.array([truncnorm_inv(m, s, lo, hi, v) for v in u])
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-8 * s)


@pytest.mark.parametrize("where,lo,hi,tol", [
    ("centre", np.log(0.075), np.log(0.925), 2e-15),
    ("lower tail, r <= 5", -25.0, np.log(0.075), 2e-15),
    ("lower tail, r > 5", np.log(1e-300), -25.0, 2e-15),
    ("upper tail", np.log1p(-0.075), -1e-16, 2e-15),
    ("beyond 1e-300 (Newton)", -5e4, np.log(1e-300), 1e-12),
])
def test_the_log_space_normal_quantile_matches_scipy(where, lo, hi, tol):
    """z with log Phi(z) = log p, as scipy's ndtri_exp gives it: AS 241 to rounding
    where it applies, Newton's method (stopped at 1e-13 in z) beyond."""
    from scipy.special import ndtri_exp

    from olsbayes.imaging._window_kernel import _ndtri_exp

    logp = np.concatenate([np.linspace(lo, hi, 2000), -np.geomspace(-hi, -lo, 2000)])
    got = np.array([_ndtri_exp(v) for v in logp])
    ref = ndtri_exp(logp)
    np.testing.assert_array_less(np.abs(got - ref), tol * np.maximum(1.0, np.abs(ref)))


@pytest.mark.parametrize("n_chains", [1, 3, 4, 5, 9])
def test_the_chains_dot_products_are_each_chains_own_sum(n_chains):
    """Chains' residuals dotted four at a time: each sum, to the bit, as its own loop."""
    from olsbayes.imaging._window_kernel import _dots

    rng = np.random.default_rng(n_chains)
    r, row = rng.standard_normal((n_chains, 301)), rng.standard_normal(301)
    h = np.empty(n_chains)
    _dots(r, row, h)
    for c in range(n_chains):
        total = 0.0
        for a, b in zip(r[c].tolist(), row.tolist()):
            total += a * b
        assert h[c] == total


@pytest.mark.parametrize("h,lo,hi", [(3.0, 0.0, 1.0), (-40.0, -0.5, 0.25), (1e-14, 0.0, 2.0)])
def test_flat_lines_draw_the_tilted_uniform(h, lo, hi):
    # prec * width^2 < 1e-8: t ~ exp(h t) on [lo, hi], inverse CDF in closed form
    u = np.random.default_rng(4).random(200)
    got = np.array([_line(h, 1e-12, lo, hi, v) for v in u])
    p = 1.0 - u if h > 0 else u  # the kernel inverts from the heavy end: h > 0 maps u -> 1 - u
    ref = lo + np.log1p(p * np.expm1(h * (hi - lo))) / h
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9 * (hi - lo))


@pytest.mark.parametrize("case", ["confused", "null"])
def test_window_moves_alone_match_2d_quadrature(case):
    # only window moves (all eigen-directions of the 2-pixel window): exact and irreducible
    if case == "confused":
        a = np.array([[1.0, 0.95], [0.9, 1.0], [0.5, 0.45]])
    else:  # rank 1: x1 - x2 is invisible, set by the box alone (tilted-uniform draws)
        a = np.array([[1.0, 1.0], [0.5, 0.5]])
    y, sigma = np.array([0.9, 0.85, 0.45])[: a.shape[0]], 0.05
    moves = window_moves(a, np.array([[0, 1]]), sigma, slow=1e-9)
    assert moves.n_moves == 2
    rng = np.random.default_rng(21)
    x = np.full((8, 2), 0.5)
    r = y - x @ a.T
    out = np.empty((8, 3000, 2))
    for i in range(3020):
        window_sweep(x, r, moves, sigma, 1.0, rng=rng)
        if i >= 20:
            out[:, i - 20] = x
    np.testing.assert_allclose(r, y - x @ a.T, atol=1e-10)  # residual kept up to date
    assert np.all((out >= 0) & (out <= 1))
    _check(out, *_grid_moments(a, y, sigma, 1.0, n=600))


def test_gibbs_with_window_moves_matches_3d_grid():
    # three sources, rank-2 design: one exactly null direction inside the window
    a = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [0.5, 0.5, 1.0], [1.0, 1.0, 2.0]])
    truth, sigma = np.array([0.7, 0.2, 0.4]), 0.1
    y = a @ truth + sigma * np.random.default_rng(5).standard_normal(4)
    moves = window_moves(a, np.array([[0, 1, 2]]), sigma)
    assert moves.n_moves >= 1 and moves.lam.min() < 1e-20  # the null vector is kept
    # compiled path: single-site, pair and window moves in one random order
    run = gibbs_intensities(a, y, sigma, 1.0, np.full((8, 3), 0.5), 2000,
                            rng=np.random.default_rng(7), n_burn=20,
                            moves=SweepMoves(pairs=np.array([[0, 1], [1, 2]]), windows=moves))
    _check(run.samples, *_grid_moments(a, y, sigma, 1.0, n=160))


def test_coordinate_moves_are_unit_sites_and_pairs():
    a = np.array([[1.0, 2.0, 0.5], [0.0, 1.0, 3.0]])
    m = combine(coordinate_moves(a, np.array([[0, 2]])), window_moves(a, np.array([[0, 1, 2]]),
                                                                       1.0, slow=1e-9))
    assert m.n_moves == 3 + 1 + 3 and m.index.shape[1] == 3
    np.testing.assert_allclose(m.response[1], a[:, 1])  # e_1
    np.testing.assert_allclose(m.response[3], (a[:, 0] - a[:, 2]) / np.sqrt(2))
    np.testing.assert_allclose(m.lam, np.sum(m.response**2, axis=1))
    np.testing.assert_allclose(np.linalg.norm(m.vec, axis=1), 1.0)
    np.testing.assert_allclose(m.vec[:4, 2], 0.0)  # padding


def test_window_moves_on_the_half_line():
    # nonnegative prior (i_max = inf): chords open on one side, truncated normals
    a = np.array([[1.0, 0.9], [0.8, 1.0]])
    y, sigma = np.array([0.3, 0.25]), 0.2
    moves = window_moves(a, np.array([[0, 1]]), sigma, slow=1e-9)
    run = gibbs_intensities(a, y, sigma, np.inf, np.full((8, 2), 0.2), 3000,
                            rng=np.random.default_rng(9), n_burn=20,
                            moves=SweepMoves(windows=moves))
    _check(run.samples, *_grid_moments(a, y, sigma, 6.0, n=600))  # mass beyond 6: < 1e-30


def test_window_moves_are_refused_with_the_spike():
    a = np.array([[1.0, 0.9], [0.8, 1.0]])
    moves = window_moves(a, np.array([[0, 1]]), 0.1, slow=1e-9)
    with pytest.raises(ob.InputError, match="moves.windows"):
        gibbs_intensities(a, np.zeros(2), 0.1, 1.0, np.full((2, 2), 0.5), 4,
                          rng=np.random.default_rng(0), spike=(1.0, 1.0),
                          moves=SweepMoves(windows=moves))


def test_window_moves_mix_closely_spaced_sources():
    # 9 sources far closer than the sub-sensor spacing: single-site + pair Gibbs
    # has not mixed after 20 sweeps (test_poorly_mixed_chains_warn); with window
    # moves the posterior is sampled and agrees with exact HMC
    model = ob.Model(ob.Ring(30), sigma=0.05)
    dirs = np.linspace(-0.4, 0.4, 9)
    y = design_matrix(model, dirs) @ np.full(9, 0.5)
    kw = dict(n_samples=400, n_burn=40, null_warn=1.0)
    res = image(model, y, dirs, "bounded", rng=0, options=ImageOptions(sampler="gibbs", **kw))
    ref = image(model, y, dirs, "bounded", rng=1, options=ImageOptions(sampler="hmc", **kw))
    assert res.rhat < 1.1
    se = np.hypot(*(batch_se(np.moveaxis(r.samples, 1, 0).reshape(-1, 9)) for r in (res, ref)))
    np.testing.assert_array_less(np.abs(res.mean - ref.mean), 5 * se)
