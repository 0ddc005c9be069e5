"""Block HMC moves and the convergence-driven run of the box priors."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy import integrate

import olsbayes as ob
from olsbayes.errors import ConvergenceWarning, InputError
from olsbayes.imaging import Bounded, ImageOptions, NonNegative
from olsbayes.imaging.block import block_move, block_step, loose_block
from olsbayes.imaging.chains import ConvergenceRule, RunLength, box_gibbs
from olsbayes.imaging.sparse import SweepMoves
from olsbayes.imaging.truncated import trajectory


def _box_gaussian():
    """A 2-D box-truncated Gaussian with a near-null direction (e1 - e2 barely seen)."""
    a = np.array([[1.0, 1.0], [1.0, 0.9], [0.5, 0.55]])
    y = np.array([1.1, 1.0, 0.55])
    return a, y, 0.2


def _exact_moments(a, y, sigma, hi):
    """Mean and second moments of exp(-|A x - y|^2 / 2 sigma^2) on [0, hi]^2 by quadrature."""
    def dens(x1, x0):
        r = a @ np.array([x0, x1]) - y
        return np.exp(-0.5 * (r @ r) / sigma**2)

    def moment(f):
        return integrate.dblquad(lambda x1, x0: f(x0, x1) * dens(x1, x0), 0, hi, 0, hi,
                                 epsabs=1e-12, epsrel=1e-10)[0]

    z = moment(lambda x0, x1: 1.0)
    mean = np.array([moment(lambda x0, x1: x0), moment(lambda x0, x1: x1)]) / z
    second = np.array([moment(lambda x0, x1: x0 * x0), moment(lambda x0, x1: x1 * x1),
                       moment(lambda x0, x1: x0 * x1)]) / z
    return mean, second


def test_block_moves_alone_keep_the_box_truncated_gaussian_exact():
    """Only block moves (both intensities in the block): draws of a 2-D box-truncated
    Gaussian match its quadrature moments within 4 Monte Carlo standard errors
    (batch means over 20 batches of the 4 x 1500 draws)."""
    a, y, sigma = _box_gaussian()
    rng = np.random.default_rng(11)
    move = block_move(a, y, sigma, np.array([0, 1]), 1.0)
    x = np.full((4, 2), 0.5)
    draws = np.empty((4, 1500, 2))
    acc = 0
    for i in range(1500):
        acc += block_step(x, move, 1.0, rng=rng)[0]
        draws[:, i] = x
    f = np.stack([draws[..., 0], draws[..., 1], draws[..., 0] ** 2, draws[..., 1] ** 2,
                  draws[..., 0] * draws[..., 1]], axis=-1)  # (C, S, 5)
    batches = f.reshape(4, 20, 75, 5).mean(axis=2).reshape(80, 5)
    est, se = batches.mean(axis=0), batches.std(axis=0, ddof=1) / np.sqrt(80)
    mean, second = _exact_moments(a, y, sigma, 1.0)
    exact = np.concatenate([mean, second])
    assert acc / 6000 > 0.5
    assert np.all(np.abs(est - exact) < 4 * se + 1e-12), (est, exact, se)


def test_gibbs_with_the_block_keeps_the_target_exact_on_a_small_box():
    """Gibbs sweeps plus the block move chosen from a pilot (box_gibbs): moments of
    the 2-D box-truncated Gaussian within 4 batch-means standard errors."""
    a, y, sigma = _box_gaussian()
    rng = np.random.default_rng(5)
    run = box_gibbs(a, y, sigma, 1.0, np.full((4, 2), 0.5), rng=rng,
                    length=RunLength(n_burn=40, n_samples=1500),
                    moves=SweepMoves(pairs=np.array([[0, 1]])), block=0.02, scale=1.0)
    assert run.block.tolist() == [0, 1] and run.samples.shape == (4, 1500, 2)
    d = run.samples
    f = np.stack([d[..., 0], d[..., 1], d[..., 0] ** 2, d[..., 1] ** 2, d[..., 0] * d[..., 1]],
                 axis=-1)
    batches = f.reshape(4, 20, 75, 5).mean(axis=2).reshape(80, 5)
    est, se = batches.mean(axis=0), batches.std(axis=0, ddof=1) / np.sqrt(80)
    mean, second = _exact_moments(a, y, sigma, 1.0)
    assert np.all(np.abs(est - np.concatenate([mean, second])) < 4 * se + 1e-12)


def test_the_compiled_trajectory_follows_the_numpy_one():
    rng = np.random.default_rng(0)
    m = rng.standard_normal((6, 6))
    cov = np.linalg.inv(m @ m.T + 0.5 * np.eye(6))
    x, mu = rng.random((5, 6)), rng.standard_normal((5, 6))
    v = rng.standard_normal((5, 6)) @ np.linalg.cholesky(cov).T
    lo, hi = np.zeros(6), np.ones(6)
    from olsbayes.imaging._block_kernel import trajectories_compiled

    ref, n_ref = trajectory(x.copy(), mu, v.copy(), cov, lo, hi, np.pi / 2, 20_000)
    got, n_got = trajectories_compiled(x.copy(), mu, v.copy(), cov, lo, hi, np.pi / 2, 20_000)
    assert np.array_equal(n_ref, n_got) and n_ref.min() > 0
    np.testing.assert_allclose(got, ref, atol=1e-12)
    assert np.all((got >= 0) & (got <= 1))


def _every_wall(a, v, h_lo, h_hi):
    """The unscreened scan: every coordinate's crossing times solved, earliest kept."""
    best, kb, upb = math.inf, -1, False
    for j in range(a.shape[0]):
        r = math.hypot(a[j], v[j])
        if r == 0.0:
            continue
        phi = math.atan2(v[j], a[j])
        for h, up in ((h_lo[j], False), (h_hi[j], True)):
            c = h / r
            if abs(c) < 1.0:
                t = (phi - math.acos(c) if up else phi + math.acos(c)) % (2 * math.pi)
                if 1e-12 <= t < best:
                    best, kb, upb = t, j, up
    return best, kb, upb


@pytest.mark.parametrize("seed", range(4))
def test_the_screened_wall_search_finds_what_solving_every_coordinate_finds(seed):
    """The compiled search solves only the coordinates that can reach a wall first;
    on states with coordinates on a wall, beside one and far from both, with an
    open upper side and with times left up to a full turn, it picks the same
    crossing as solving every coordinate (the bounce a trajectory takes)."""
    from olsbayes.imaging._block_kernel import _first_wall

    rng = np.random.default_rng(seed)
    same = 0
    for _ in range(400):
        dim = int(rng.integers(1, 40))
        a, v = rng.standard_normal(dim), rng.standard_normal(dim)
        h_lo = a - rng.exponential(rng.choice([1e-9, 0.1, 1.0, 3.0]), dim)
        h_hi = a + rng.exponential(rng.choice([1e-9, 0.1, 1.0, 3.0]), dim)
        on = rng.random(dim) < 0.2  # just bounced: on the lower wall, moving up
        h_lo[on], v[on] = a[on], np.abs(v[on])
        h_hi[rng.random(dim) < 0.2] = np.inf
        left = float(rng.choice([rng.uniform(0, np.pi / 2), rng.uniform(0, 2 * np.pi)]))
        t_ref, k_ref, up_ref = _every_wall(a, v, h_lo, h_hi)
        t, k, up = _first_wall(a, v, h_lo, h_hi, left)
        if t_ref < left:  # a bounce: the very crossing
            assert (k, up) == (k_ref, up_ref) and t == pytest.approx(t_ref, rel=1e-14)
            same += 1
        else:  # no bounce before the trajectory ends
            assert t >= left
    assert same > 100  # most states bounce


def test_loose_block_picks_the_intensities_with_a_wide_pilot_spread():
    draws = np.zeros((2, 10, 3))
    draws[:, :, 1] = np.linspace(0, 1, 10)
    assert loose_block(draws, 0.02).tolist() == [1]


def _ring():
    model = ob.Model(ob.Ring(8), sigma=0.3)
    y = model.simulate(np.array([-1.0, 0.5, 1.5, 0.5]), rng=np.random.default_rng(1))
    return model, y, [-1.0, 1.5]


def test_the_default_run_stops_when_converged():
    """No n_samples: the chains stop at the first check that meets R-hat <= 1.01 and
    bulk and tail ESS >= ess_min; the draws then meet both."""
    model, y, dirs = _ring()
    opts = ImageOptions(ess_min=100.0, n_chains=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConvergenceWarning)
        res = ob.imaging.image(model, y, dirs, Bounded(i_max=3.0), rng=2, options=opts,
                               progress=False)
    from olsbayes.imaging.chains import chain_diagnostics

    d = chain_diagnostics(res.samples)
    assert res.samples.shape[1] == 100  # the first check already met the rule
    assert d["rhat"] <= 1.01 and min(d["ess_bulk"], d["ess_tail"]) >= 100


def test_the_bound_from_the_readings_keeps_the_posterior_exact():
    """Prior "bounded" without i_max: the bound comes from the readings (several times
    the intensities), the chains' jitter and block surrogate from the mode's largest
    intensity.  Moments of the 2-D box-truncated Gaussian on [0, i_max] within 4
    batch-means standard errors (20 batches of the 4 x 1500 draws)."""
    model, y, dirs = _ring()
    res = ob.imaging.image(model, y, dirs, "bounded", rng=7, progress=False,
                           options=ImageOptions(n_samples=1500, n_burn=40))
    assert res.i_max > 4 * res.mode.max()  # the derived bound is a loose ceiling
    assert 0.5 < res.acceptance < 1.0  # block moves were made, most accepted
    d = res.samples
    f = np.stack([d[..., 0], d[..., 1], d[..., 0] ** 2, d[..., 1] ** 2, d[..., 0] * d[..., 1]],
                 axis=-1)
    batches = f.reshape(4, 20, 75, 5).mean(axis=2).reshape(80, 5)
    est, se = batches.mean(axis=0), batches.std(axis=0, ddof=1) / np.sqrt(80)
    a = ob.imaging.design_matrix(model, dirs)
    mean, second = _exact_moments(a, y, model.sigma, res.i_max)
    assert np.all(np.abs(est - np.concatenate([mean, second])) < 4 * se + 1e-12)


def test_the_run_warns_when_it_hits_its_cap():
    model, y, dirs = _ring()
    opts = ImageOptions(ess_min=1e6, max_samples=150, n_chains=2)
    with pytest.warns(ConvergenceWarning, match="max_samples = 150"):
        res = ob.imaging.image(model, y, dirs, NonNegative(scale=2.0), rng=2, options=opts,
                               progress=False)
    assert res.samples.shape == (2, 150, 2)


@pytest.mark.filterwarnings("ignore::olsbayes.errors.ConvergenceWarning")  # 37 short draws
def test_an_explicit_n_samples_gives_exactly_that_many_draws():
    model, y, dirs = _ring()
    res = ob.imaging.image(model, y, dirs, Bounded(i_max=3.0), rng=2, progress=False,
                           options=ImageOptions(n_samples=37, n_burn=10, n_chains=3))
    assert res.samples.shape == (3, 37, 2)


def test_the_convergence_rule_stops_at_the_cap_with_its_diagnostics():
    a, y, sigma = _box_gaussian()
    rule = ConvergenceRule(rhat_max=1.01, ess_min=1e9, max_samples=130)
    bar = _Bar()
    run = box_gibbs(a, y, sigma, 1.0, np.full((2, 2), 0.5), rng=np.random.default_rng(1),
                    length=RunLength(n_burn=10, rule=rule),
                    moves=SweepMoves(pairs=np.zeros((0, 2), dtype=int)), block=0.02, scale=1.0,
                    bar=bar)
    assert run.samples.shape[1] == 130 and run.converged is False
    assert len(bar.lines) == 2 and "R-hat" in bar.lines[-1]
    assert bar.sweeps == 10 + 130  # burn-in and kept sweeps, one update each


class _Bar:
    """A progress bar that records what it is told."""

    def __init__(self):
        self.lines, self.sweeps = [], 0

    def update(self, n=1):
        self.sweeps += n

    def set_postfix_str(self, line):
        self.lines.append(line)


def test_box_gibbs_refuses_an_after_sweep_of_the_caller():
    a, y, sigma = _box_gaussian()
    with pytest.raises(ob.InputError, match="moves.after_sweep"):
        box_gibbs(a, y, sigma, 1.0, np.full((2, 2), 0.5), rng=np.random.default_rng(1),
                  length=RunLength(n_burn=10, n_samples=5),
                  moves=SweepMoves(after_sweep=lambda x: None), block=0.02, scale=1.0)


@pytest.mark.parametrize("kwargs,match", [
    (dict(block=-0.1), "block must be a finite number >= 0"),
    (dict(block=np.inf), "block must be a finite number >= 0"),
    (dict(block=True), "block must be"),
    (dict(ess_min=0.0), "ess_min must be"),
    (dict(max_samples=3), "max_samples must be"),
    (dict(max_samples=2.5), "max_samples must be"),
])
def test_the_new_options_refuse_bad_values(kwargs, match):
    with pytest.raises(InputError, match=match):
        ImageOptions(**kwargs)


@pytest.mark.parametrize("opts,match", [
    (ImageOptions(n_samples=50, ess_min=100.0), "ess_min = 100.0 does not apply"),
    (ImageOptions(n_samples=50, max_samples=100), "with n_samples = 50"),
    (ImageOptions(sampler="hmc", block=0.1), "block = 0.1 does not apply"),
    (ImageOptions(n_samples=0, block=0.1), "with n_samples = 0"),
])
def test_options_the_run_would_ignore_are_refused(opts, match):
    model, y, dirs = _ring()
    with pytest.raises(InputError, match=match):
        ob.imaging.image(model, y, dirs, Bounded(i_max=3.0), options=opts)
