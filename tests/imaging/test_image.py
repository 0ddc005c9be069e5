"""Imaging mode: closed forms vs brute force, exact samplers vs numerical integration."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from reference.moments import batch_se, box_moments_2d
from scipy import integrate, stats

import olsbayes as ob
from olsbayes.errors import ConvergenceWarning, InputError, NullSpaceWarning
from olsbayes.imaging import (
    Bounded,
    Gaussian,
    ImageOptions,
    NonNegative,
    Ridge,
    SweepMoves,
    design_matrix,
    gaussian_posterior,
    gibbs_intensities,
    hpd_interval,
    image,
    sample_truncated_gaussian,
    split_rhat,
    truncnorm_1d,
)


@pytest.fixture
def ring_problem():
    model = ob.Model(ob.Ring(8), sigma=0.3)
    dirs = np.array([0.3, 2.0])
    a = design_matrix(model, dirs)
    y = a @ np.array([0.6, 0.2]) + model.sigma * np.random.default_rng(3).standard_normal(8)
    return model, dirs, a, y


# -- design matrix ---------------------------------------------------------------
def test_design_matrix_columns_are_unit_source_responses():
    model = ob.Model(ob.Sphere.grid(5, 8), sigma=0.01)
    dirs = np.array([[0.1, 0.2], [-1.0, 0.5], [2.5, -0.4]])
    a = design_matrix(model, dirs)
    inten = np.array([0.3, 1.2, 0.7])
    x = np.column_stack([dirs, inten]).ravel()
    np.testing.assert_allclose(a @ inten, model.response(x), rtol=1e-12, atol=1e-14)


def test_antipodal_pairs_make_the_cosine_design_rank_deficient():
    # costn(c) - costn(-c) = c: a sub-sensor and its antipode see a linear function
    # of the source's unit vector, so the ring design loses rank.
    model = ob.Model(ob.Ring(8), sigma=0.01)
    dirs = np.linspace(-np.pi, np.pi, 16, endpoint=False)
    with pytest.warns(NullSpaceWarning):
        res = image(model, np.zeros(8), dirs, prior="gaussian")
    assert res.rank == np.linalg.matrix_rank(design_matrix(model, dirs)) < 8
    null = res.design.null_space
    np.testing.assert_allclose(res.design.matrix @ null, 0.0, atol=1e-10)
    np.testing.assert_allclose(res.null_fraction.sum(), 16 - res.rank, rtol=1e-10)


def test_combinations_pinned_less_well_than_the_prior_scale_warn():
    # three ring sources half a spacing apart at SNR 10: the design has full rank but
    # its smallest singular values give noise sd sigma / s above the prior's scale, so
    # those intensity combinations (and their intervals) are the prior's; three
    # spacings apart at SNR 1000 every combination is pinned and nothing warns
    h = 2 * np.pi / 30
    for sep, sigma, expect in ((0.5, 0.1, True), (3.0, 1e-3, False)):
        model = ob.Model(ob.Ring(30), sigma=sigma)
        dirs = 0.3 + sep * h * np.arange(3)
        a = design_matrix(model, dirs)
        s = np.linalg.svd(a, compute_uv=False)
        prior = ob.imaging.Gaussian(mean=1.0, sd=0.5)
        unpinned = int(np.sum(sigma / s >= prior.scale))
        assert (unpinned > 0) is expect and np.linalg.matrix_rank(a) == 3
        y = a @ np.ones(3)
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            res = image(model, y, dirs, prior)
        hits = [w for w in seen if issubclass(w.category, NullSpaceWarning)]
        assert bool(hits) is expect
        assert res.design.effective_rank == 3 - unpinned
        if expect:
            assert f"the other {unpinned} (0 of them invisible" in str(hits[0].message)


# -- Gaussian prior --------------------------------------------------------------
def test_gaussian_posterior_matches_brute_force_grid(ring_problem):
    model, dirs, a, y = ring_problem
    m0, s0 = np.array([0.5, 0.4]), np.array([0.5, 0.3])
    post = gaussian_posterior(a, y, model.sigma, m0, s0)
    g = np.linspace(-2.5, 3.5, 801)
    i1, i2 = np.meshgrid(g, g, indexing="ij")
    pts = np.stack([i1, i2], axis=-1)
    resid = y - pts @ a.T
    logp = (
        -0.5 * np.sum(resid**2, axis=-1) / model.sigma**2
        - 0.5 * len(y) * np.log(2 * np.pi * model.sigma**2)
        + stats.norm.logpdf(pts, m0, s0).sum(axis=-1)
    )
    da = (g[1] - g[0]) ** 2
    mx = logp.max()
    w = np.exp(logp - mx)
    z = w.sum() * da
    mean = np.einsum("ijk,ij->k", pts, w) * da / z
    dev = pts - mean
    cov = np.einsum("ijk,ijl,ij->kl", dev, dev, w) * da / z
    np.testing.assert_allclose(post.mean, mean, atol=1e-6)
    np.testing.assert_allclose(post.cov, cov, atol=1e-6)
    assert post.log_evidence == pytest.approx(mx + np.log(z), abs=1e-6)


def test_image_gaussian_is_the_closed_form(ring_problem):
    model, dirs, a, y = ring_problem
    res = image(model, y, dirs, Gaussian(mean=0.2, sd=0.7), options=ImageOptions(level=0.8))
    post = gaussian_posterior(a, y, model.sigma, np.full(2, 0.2), np.full(2, 0.7))
    np.testing.assert_allclose(res.mean, post.mean)
    np.testing.assert_allclose(res.sd, post.sd)
    z = stats.norm.ppf(0.9)
    np.testing.assert_allclose(res.upper - res.lower, 2 * z * post.sd)
    assert res.log_evidence == pytest.approx(post.log_evidence)


# -- truncated Gaussians ---------------------------------------------------------
@pytest.mark.parametrize(
    "m,s,lo,hi", [(0.3, 0.5, 0.0, 1.0), (0.0, 1.0, 6.0, 7.0), (2.0, 0.1, -1.0, 0.5)]
)
def test_truncnorm_1d_moments(m, s, lo, hi):
    x = truncnorm_1d(np.full(40_000, m), s, lo, hi, rng=np.random.default_rng(1))
    ref = stats.truncnorm((lo - m) / s, (hi - m) / s, m, s)
    assert np.all((x >= lo) & (x <= hi))
    se = ref.std() / np.sqrt(x.size)
    assert abs(x.mean() - ref.mean()) < 5 * se
    assert x.std() == pytest.approx(ref.std(), rel=5 * np.sqrt(1 / x.size))




@pytest.mark.parametrize("singular", [False, True])
def test_exact_hmc_matches_2d_quadrature(singular):
    if singular:  # rank-1 precision: needs the ridge surrogate + Metropolis correction
        v = np.array([1.0, 1.0])
        q, b = 8.0 * np.outer(v, v), 8.0 * 0.9 * v
    else:  # strongly correlated, mean outside the box
        q = np.linalg.inv(np.array([[0.25, 0.2], [0.2, 0.25]]))
        b = q @ np.array([1.2, -0.3])
    lo, hi = np.zeros(2), np.ones(2)
    mean, cov = box_moments_2d(q, b, lo, hi)
    run = sample_truncated_gaussian(
        q, b, lo, hi, np.full((8, 2), 0.5), 1500, rng=np.random.default_rng(7), n_burn=50,
        ridge=Ridge(1.0, np.full(2, 0.5)) if singular else None,
    )
    x = np.moveaxis(run.samples, 1, 0)  # (S, C, 2)
    assert np.all((x >= 0) & (x <= 1))
    flat = x.reshape(-1, 2)
    se = batch_se(x.mean(axis=1))
    np.testing.assert_array_less(np.abs(flat.mean(axis=0) - mean), 5 * se)
    d2 = (flat - mean) ** 2
    se2 = batch_se(((x - mean) ** 2).mean(axis=1))
    np.testing.assert_array_less(np.abs(d2.mean(axis=0) - np.diag(cov)), 5 * se2)
    if not singular:
        assert run.acceptance == 1.0  # exact dynamics, no correction needed
    assert 0.3 < run.acceptance <= 1.0


def test_gibbs_with_pair_moves_matches_2d_quadrature():
    # two strongly confused sources: their difference is barely measured
    a = np.array([[1.0, 0.95], [0.9, 1.0], [0.5, 0.45]])
    y, sigma = np.array([0.9, 0.85, 0.45]), 0.05
    q, b = a.T @ a / sigma**2, a.T @ y / sigma**2
    mean, cov = box_moments_2d(q, b, np.zeros(2), np.ones(2))
    run = gibbs_intensities(a, y, sigma, 1.0, np.full((8, 2), 0.5), 2000,
                            rng=np.random.default_rng(11), n_burn=20,
                            moves=SweepMoves(pairs=np.array([[0, 1]])))
    x = np.moveaxis(run.samples, 1, 0)  # (S, C, 2)
    se = batch_se(x.mean(axis=1))
    np.testing.assert_array_less(np.abs(x.reshape(-1, 2).mean(axis=0) - mean), 5 * se)
    se2 = batch_se(((x - mean) ** 2).mean(axis=1))
    d2 = ((x - mean) ** 2).reshape(-1, 2).mean(axis=0)
    np.testing.assert_array_less(np.abs(d2 - np.diag(cov)), 5 * se2)


def test_exact_hmc_1d_matches_scipy_truncnorm():
    m, s = 0.3, 0.5
    run = sample_truncated_gaussian(
        np.array([[1 / s**2]]), np.array([m / s**2]), np.zeros(1), np.ones(1),
        np.full((4, 1), 0.5), 3000, rng=np.random.default_rng(2), n_burn=10,
    )
    ref = stats.truncnorm(-m / s, (1 - m) / s, m, s)
    x = np.moveaxis(run.samples[..., 0], 1, 0)  # (S, C)
    se = batch_se(x.mean(axis=1))
    assert abs(x.mean() - ref.mean()) < 5 * se
    se2 = batch_se(((x - ref.mean()) ** 2).mean(axis=1))
    assert abs(np.mean((x - ref.mean()) ** 2) - ref.var()) < 5 * se2


@pytest.mark.parametrize("pairs", [None, np.array([[0, 1]])])
def test_spike_and_slab_gibbs_matches_brute_force(pairs):
    # Two intensities; the posterior mixes four spike/slab configurations.
    a = np.array([[1.0, 0.4], [0.3, 1.0], [0.5, 0.5]])
    y = np.array([0.55, 0.2, 0.35])
    sigma, i_max = 0.2, 1.0
    w = 0.3  # fixed by a very tight Beta hyperprior
    run = gibbs_intensities(a, y, sigma, i_max, np.zeros((8, 2)), 3000,
                            rng=np.random.default_rng(4), n_burn=50, spike=(3e6, 7e6),
                            moves=SweepMoves(pairs=pairs))

    def lik(x1, x2):
        return np.exp(-0.5 * np.sum((y - a @ np.array([x1, x2])) ** 2) / sigma**2)

    slab = w / i_max
    mass = {
        (0, 0): (1 - w) ** 2 * lik(0, 0),
        (1, 0): (1 - w) * slab * integrate.quad(lambda u: lik(u, 0), 0, 1)[0],
        (0, 1): (1 - w) * slab * integrate.quad(lambda u: lik(0, u), 0, 1)[0],
        (1, 1): slab**2 * integrate.dblquad(lambda u, v: lik(v, u), 0, 1, 0, 1)[0],
    }
    z = sum(mass.values())
    p_on1 = (mass[(1, 0)] + mass[(1, 1)]) / z
    mean1 = (
        (1 - w) * slab * integrate.quad(lambda u: u * lik(u, 0), 0, 1)[0]
        + slab**2 * integrate.dblquad(lambda u, v: v * lik(v, u), 0, 1, 0, 1)[0]
    ) / z
    x = np.moveaxis(run.samples, 1, 0)  # (S, C, 2)
    on1 = (x[..., 0] > 0).mean(axis=1)
    assert abs(on1.mean() - p_on1) < 5 * batch_se(on1)
    m1 = x[..., 0].mean(axis=1)
    assert abs(m1.mean() - mean1) < 5 * batch_se(m1)


# -- summaries -------------------------------------------------------------------
def test_hpd_interval_reaches_the_bound_when_mass_piles_there():
    rng = np.random.default_rng(0)
    s = np.column_stack([rng.exponential(0.05, 4000), rng.normal(0.5, 0.1, 4000)])
    lo, hi = hpd_interval(s, 0.9, np.zeros(2), np.ones(2))
    assert lo[0] == 0.0 and hi[0] == pytest.approx(stats.expon(scale=0.05).ppf(0.9), rel=0.1)
    assert lo[1] == pytest.approx(0.5 - 1.645 * 0.1, abs=0.02)


def test_split_rhat_flags_separated_chains():
    rng = np.random.default_rng(0)
    good = rng.standard_normal((4, 500, 3))
    assert np.all(np.abs(split_rhat(good) - 1) < 0.02)
    bad = good + np.array([0.0, 0.0, 3.0, 3.0])[:, None, None]
    assert np.all(split_rhat(bad) > 1.5)
    # discrete draws: chains frozen in different states are not mixed; agreeing ones are
    frozen = np.zeros((4, 50, 2))
    frozen[2:, :, 0] = 1.0
    np.testing.assert_array_equal(split_rhat(frozen), [np.inf, 1.0])


# -- the public entry point -------------------------------------------------------
def test_bounded_image_on_a_well_posed_ring():
    model = ob.Model(ob.Ring(30), sigma=0.05)
    dirs = np.array([-2.0, 0.0, 2.0])  # not antipodal: full rank
    truth = np.array([0.9, 0.0, 0.4])
    noise = model.sigma * np.random.default_rng(9).standard_normal(30)
    y = design_matrix(model, dirs) @ truth + noise
    res = image(model, y, dirs, "bounded", rng=1,
                options=ImageOptions(n_samples=400, n_burn=50, sampler="hmc"))
    assert res.rank == 3 and res.sampler == "hmc" and res.samples.shape == (4, 400, 3)
    assert res.rhat < 1.05
    assert np.all((res.samples >= 0) & (res.samples <= 1))
    assert np.all(np.abs(res.mean - truth) < 4 * res.sd + 0.02)
    assert res.lower[1] == 0.0  # the dark source's interval reaches 0
    gib = image(model, y, dirs, "bounded", rng=2,
                options=ImageOptions(n_samples=400, sampler="gibbs"))
    np.testing.assert_allclose(gib.mean, res.mean, atol=4 * res.sd.max() / np.sqrt(100))


def test_nonnegative_image_matches_2d_quadrature(ring_problem):
    # flat prior on I >= 0 (no upper bound); noise large enough that the wall at 0 matters
    # (the second intensity's posterior mean moves from 0.01 unconstrained to 0.18)
    model, dirs, a, y = ring_problem
    q, b = a.T @ a / model.sigma**2, a.T @ y / model.sigma**2
    hi = 3.5  # > 13 posterior sd above the unconstrained mean: the cut-off is immaterial
    mean, cov = box_moments_2d(q, b, np.zeros(2), np.full(2, hi))
    for sampler in ("gibbs", "hmc"):
        res = image(model, y, dirs, NonNegative(), rng=8, options=ImageOptions(
            sampler=sampler, n_samples=1500, n_chains=8, n_burn=50))
        assert res.prior == "nonnegative" and res.sampler == sampler
        assert np.all(res.samples >= 0) and np.all(np.isfinite(res.upper))
        x = np.moveaxis(res.samples, 1, 0)  # (S, C, 2)
        se = batch_se(x.mean(axis=1))
        np.testing.assert_array_less(np.abs(res.mean - mean), 5 * se)
        se2 = batch_se(((x - mean) ** 2).mean(axis=1))
        d2 = ((x - mean) ** 2).reshape(-1, 2).mean(axis=0)
        np.testing.assert_array_less(np.abs(d2 - np.diag(cov)), 5 * se2)


@pytest.mark.filterwarnings("ignore::olsbayes.errors.ConvergenceWarning")  # 20 draws per chain
def test_image_is_reproducible_with_a_seed(ring_problem):
    model, dirs, a, y = ring_problem
    opts = ImageOptions(n_samples=20, n_burn=5)
    r1 = image(model, y, dirs, rng=5, options=opts)
    r2 = image(model, y, dirs, rng=5, options=opts)
    np.testing.assert_array_equal(r1.samples, r2.samples)


def test_poorly_mixed_chains_warn():
    model = ob.Model(ob.Ring(30), sigma=0.05)
    dirs = np.linspace(-0.4, 0.4, 9)  # far closer than the sub-sensor spacing
    y = design_matrix(model, dirs) @ np.full(9, 0.5)
    with pytest.warns(ConvergenceWarning):
        # window=0: single-site + pair moves only (window moves mix this problem,
        # see test_imaging_window.py)
        image(model, y, dirs, "bounded", rng=0, options=ImageOptions(
            sampler="gibbs", n_samples=20, n_burn=0, null_warn=1.0, window=0))


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(directions=np.zeros((0, 2))), "at least one"),
        (dict(directions=np.array([[0.0, 2.0]])), "latitude"),
        (dict(directions=np.array([0.1, 0.2])), "shape"),
        (dict(directions=np.array([[0.0, 0.1, 0.2]])), "shape"),
        (dict(directions=np.array([[0.0, np.nan]])), "finite"),
        (dict(data=np.zeros(5)), "length 40"),
        (dict(prior="laplace"), "prior must be one of"),
        (dict(prior=Bounded), "prior must be one of"),
        (dict(options={"n_samples": 10}), "options must be an olsbayes.imaging.ImageOptions"),
        (dict(options=ImageOptions(n_samples=1)), "n_samples"),
    ],
)
def test_bad_inputs_raise_input_error(kwargs, match):
    model = ob.Model(ob.Sphere.grid(5, 8), sigma=0.01)
    args = dict(model=model, data=np.zeros(40), directions=np.array([[0.0, 0.0]]))
    args.update(kwargs)
    with pytest.raises(InputError, match=match):
        image(**args)


def test_unseen_direction_raises():
    plate = ob.Model(ob.Plate.grid(3, 3), sigma=0.01)
    with pytest.raises(InputError, match="z > 0"):
        image(plate, np.zeros(9), np.array([[0.0, 0.0, -1.0]]))
    hemi = ob.Model(ob.Sphere.grid(3, 6, np.pi / 4, lon_range=(-0.5, 0.5)), sigma=0.01)
    with pytest.raises(InputError, match="seen by no sub-sensor"):
        image(hemi, np.zeros(18), np.array([[np.pi, 0.0]]))


# -- Fig. 2 scene and sky maps ---------------------------------------------------
def test_olss_scene_and_the_antipodal_rank_collapse():
    from olsbayes.imaging.olss import fig2_sphere, olss_bitmap, olss_directions

    bm = olss_bitmap()
    assert bm.shape == (16, 19) and bm.sum() == 68
    # the paper-like mask: 12-row letters, 73 bright pixels, the same columns
    tall = olss_bitmap(letter_rows=12)
    assert tall.shape == (16, 19) and tall.sum() == 73
    assert np.count_nonzero(tall.any(axis=1)) == 12 and np.count_nonzero(bm.any(axis=1)) == 11
    np.testing.assert_array_equal(tall.any(axis=0), bm.any(axis=0))
    with pytest.raises(InputError, match="letter_rows must be 11 or 12"):
        olss_bitmap(letter_rows=13)
    dirs = olss_directions("endpoints")
    assert dirs.shape == (304, 2)
    assert np.isclose(np.abs(dirs[:, 0]).max(), np.pi / 2)
    assert np.isclose(np.abs(dirs[:, 1]).max(), np.pi / 3)
    assert dirs[0, 1] > 0 > dirs[-1, 1]  # bitmap row 0 is north
    ranks = {}
    for conv in ("grid", "linspace"):
        a = design_matrix(ob.Model(fig2_sphere(conv), 0.01), dirs)
        ranks[conv] = np.linalg.matrix_rank(a)
    # 20 distinct meridians: every sub-sensor has an antipode, costn(c) - costn(-c) = c
    assert ranks["grid"] < ranks["linspace"] < 300


def test_sky_maps_return_figures():
    import matplotlib.pyplot as plt

    from olsbayes.plotting import plot_image_result, plot_sky, plot_sphere_response

    model = ob.Model(ob.Sphere.grid(5, 8), sigma=0.01)
    dirs = np.array([[0.1, 0.2], [1.0, -0.3], [-2.0, 0.4]])
    y = design_matrix(model, dirs) @ np.array([1.0, 0.0, 0.5])
    for proj in ("mollweide", "equirectangular"):
        fig = plot_sphere_response(model, y, projection=proj)
        assert fig.axes
        plt.close(fig)
    res = image(model, y, dirs, prior="gaussian")
    fig = plot_image_result(res, truth=[1.0, 0.0, 0.5], model=model, data=y)
    assert len([ax for ax in fig.axes if ax.get_title()]) == 4
    plt.close(fig)
    with pytest.raises(InputError, match="projection"):
        plot_sky([0.0], [0.0], [1.0], projection="hammer")
    with pytest.raises(InputError, match="projection"):  # not a name: no ambiguous truth value
        plot_sky([0.0], [0.0], [1.0], projection=np.array(["mollweide", "mollweide"]))
    with pytest.raises(InputError, match="equal length"):
        plot_sky([0.0, 1.0], [0.0], [1.0])


def test_sky_map_is_readable_colour_bar_neutral_background_and_separate_ticks():
    """A perceptual colormap on a neutral background (the brightest value is not drawn
    in the background's colour), a colour bar, and tick labels that do not overlap."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import to_rgb

    from olsbayes.plotting import plot_sphere_response

    model = ob.Model(ob.Sphere.grid(9, 18), sigma=0.01)
    dirs = np.array([[0.1, 0.2], [2.0, -0.3]])
    y = design_matrix(model, dirs) @ np.array([1.0, 0.4])
    fig = plot_sphere_response(model, y, projection="mollweide", label="reading")
    ax, cax = fig.axes[0], fig.axes[-1]
    assert cax is not ax and cax.get_ylabel() == "reading"  # the colour bar
    art = ax.collections[0]
    assert art.get_cmap().name in ("viridis", "cividis", "magma", "inferno", "plasma")
    background = np.array(to_rgb(ax.get_facecolor()))
    assert np.ptp(background) < 1e-9 and 0.2 < background[0] < 0.9  # neutral grey
    for value in (art.norm.vmin, art.norm.vmax):  # neither end of the scale is the background
        assert np.abs(np.array(art.get_cmap()(art.norm(value))[:3]) - background).max() > 0.1
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    for labels in (ax.get_xticklabels(), ax.get_yticklabels()):
        boxes = [t.get_window_extent(renderer) for t in labels if t.get_text()]
        assert len(boxes) >= 3
        assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])
    plt.close(fig)
