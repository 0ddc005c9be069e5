"""Gaussian (Fisher) errors near the resolution limit: fit_ml warns where they fail.

The calibration map (analyses/calibration_map.py) shows Fisher intervals far from
their nominal coverage for sources less than about 1.5 sensor spacings apart and for
weak sources; fit_ml then issues a NearResolutionWarning (a ResolutionWarning), and
nothing for well-separated sources at SNR 100.  Scenes and seeds are fixed.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.antipodal import antipodal_pairs, pair_offsets, source_pairs
from olsbayes.resolution import (
    ANTIPODAL_DOUBT,
    RESOLUTION_SPACINGS,
    WEAK_SDS,
    antipodal_doubts,
    gaussian_doubts,
    min_separation,
    source_distances,
    weak_sources,
)

H = 2 * np.pi / 30  # sensor spacing of the ring of 30


def _fit(sigma: float, theta: list[float], inten: list[float], seed: int):
    """fit_ml on one simulated scene with every warning recorded."""
    model = ob.Model(ob.Ring(30), sigma)
    x = np.column_stack([theta, inten]).ravel()
    data = model.simulate(x, rng=np.random.default_rng(seed))
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        res = ob.fit_ml(model, data, len(theta), rng=1)
    quiet = ob.fit_ml(model, data, len(theta), rng=1, warn=False)
    np.testing.assert_array_equal(res.params, quiet.params)  # a warning changes nothing
    return res, [w for w in seen if issubclass(w.category, ob.OlsBayesWarning)]


def test_close_pair_warns_with_the_consequence_and_the_alternative():
    # two sources 1.4 spacings apart at SNR 100: the fit is regular, no rival optimum
    # within 3 nats, yet the pair is below the resolution limit
    res, seen = _fit(0.01, [0.2, 0.2 + 1.4 * H], [0.75, 1.16], 720)
    assert [w.category for w in seen] == [ob.NearResolutionWarning]
    msg = str(seen[0].message)
    assert "sensor spacings apart" in msg and "covered the truth far less often" in msg
    assert "sample_posterior" in msg and "select_k(method='auto')" in msg
    assert np.all(np.isfinite(res.std))
    assert issubclass(ob.NearResolutionWarning, ob.ResolutionWarning)


def test_weak_source_warns():
    # two sources half a spacing apart at SNR 10: the fit splits off a source of
    # intensity ~0.06, a few sd above zero
    _, seen = _fit(0.1, [0.2, 0.2 + 0.5 * H], [0.98, 1.11], 996)
    assert [w.category for w in seen] == [ob.NearResolutionWarning]
    assert f"less than {WEAK_SDS:g} sd above zero" in str(seen[0].message)


@pytest.mark.parametrize("sigma", [1e-2, 1e-3])
def test_well_separated_sources_do_not_warn(sigma):
    _, seen = _fit(sigma, [0.35, 0.35 + 3 * H], [1.0, 0.9], 0)
    assert seen == []


def test_doubts_of_a_batch_from_estimates_and_covariances():
    model = ob.Model(ob.Ring(30), 0.01)
    x = np.array([[0.3, 1.0, 0.3 + 1.2 * H, 1.0],   # close
                  [0.3, 1.0, 0.3 + 4.0 * H, 0.025],  # weak: I = 2.5 sd
                  [0.3, 1.0, 0.3 + 4.0 * H, 1.0],   # fine
                  [0.3, 1.0, 0.3 + 0.5 * H, 1.0]])  # no finite errors: left to the fit
    cov = np.tile(np.diag([1e-4, 1e-4, 1e-4, 1e-4]), (4, 1, 1))
    cov[3, 1, 1] = np.inf
    d = gaussian_doubts(model, x, cov)
    np.testing.assert_array_equal(d["close"], [True, False, False, False])
    np.testing.assert_array_equal(d["weak"], [False, True, False, False])
    np.testing.assert_allclose(d["separation"], [1.2, 4.0, 4.0, 0.5], rtol=1e-9)
    assert RESOLUTION_SPACINGS == 1.5 and WEAK_SDS == 3.0
    # per source: the weak intensity of row 1, and the infinite sd of row 3 (weak
    # there, though gaussian_doubts leaves rows without finite errors to the fit)
    np.testing.assert_array_equal(weak_sources(model, x, cov),
                                  [[False, False], [False, True], [False, False], [True, False]])


def test_sampling_a_close_pair_from_its_ml_start_warns():
    """sample_posterior's own ML start carries the warning to the sampler's user."""
    model = ob.Model(ob.Ring(30), 0.01)
    x = np.column_stack([[0.2, 0.2 + 1.4 * H], [0.75, 1.16]]).ravel()
    data = model.simulate(x, rng=np.random.default_rng(720))
    opts = ob.SamplerOptions(n_steps=200, rhat_max=None)
    with pytest.warns(ob.NearResolutionWarning, match="one source fewer"):
        ob.sample_posterior(model, data, 2, options=opts, rng=2, progress=False)


def test_antipodal_doubts_from_the_estimates():
    """Four sources with a pair within one spacing of antipodal, or two such pairs: doubt."""
    model = ob.Model(ob.Ring(30), 0.01)

    def row(theta):
        return np.column_stack([theta, np.ones(len(theta))]).ravel()

    pi = np.pi
    k4_near = row([0.1, 0.1 + pi - 0.6 * H, 1.4, -2.3])      # one pair 0.6 spacings off
    k4_far = row([0.1, 0.1 + pi - 1.3 * H, 1.4, -2.3])       # nearest pair 1.3 off
    assert list(antipodal_doubts(model, np.stack([k4_near, k4_far]))) == [True, False]
    k2 = row([0.4, 0.4 + pi - 0.6 * H])                        # one pair, two sources
    k3_two = row([0.4, 0.4 + pi - 0.3 * H, 0.4 + pi + 0.5 * H])  # two pairs share a source
    assert list(antipodal_doubts(model, np.stack([k2]))) == [False]
    assert list(antipodal_doubts(model, k3_two[None])) == [True]
    sphere = ob.Model(ob.Sphere.fibonacci(20), 0.01)
    assert not antipodal_doubts(sphere, np.array([[0.1, 0.2, 1.0, 0.1 + pi, -0.2, 1.0]])).any()
    assert ANTIPODAL_DOUBT == 1.0


@pytest.mark.parametrize("k", [1, 2, 3, 5])
def test_batched_pair_measures_equal_the_per_scene_ones(k):
    """pair_offsets (T, pairs) is antipodal_pairs' offset row by row; min_separation
    over the pairs is the smallest off-diagonal angle of the full matrix."""
    rng = np.random.default_rng(k)
    model = ob.Model(ob.Ring(30), 0.01)
    x = np.stack([np.column_stack([rng.uniform(-np.pi, np.pi, k), np.ones(k)]).ravel()
                  for _ in range(40)])
    if k > 1:  # source 1 near the antipode of source 0 in five rows
        x[:5, 2] = x[:5, 0] + np.pi + rng.uniform(-2, 2, 5) * H
    off = pair_offsets(model, x)
    i, j = source_pairs(k)
    assert off.shape == (40, k * (k - 1) // 2)
    for row, o in zip(x, off):
        near = {(a, b): v for a, b, v in antipodal_pairs(model, row, within=2.0)}
        assert near == {(a, b): v for a, b, v in zip(i, j, o) if abs(v) < 2.0}
    theta = x[:, 0::2]
    full = np.abs(np.angle(np.exp(1j * (theta[:, :, None] - theta[:, None, :]))))
    full[:, np.arange(k), np.arange(k)] = np.inf
    np.testing.assert_allclose(min_separation(model, x), full.min(axis=(1, 2)) / H,
                               rtol=1e-13, atol=1e-13)


def test_sphere_source_distances_keep_every_digit_of_close_pairs():
    """source_distances on a sphere equals the haversine formula of the same points to
    1e-15 rad (the rounding of the unit vectors) plus 1e-13 relative, for pairs 1e-9 to
    3 rad apart; arccos of the dot product errs by up to ~1e-8 rad near 0."""
    rng = np.random.default_rng(4)
    model = ob.Model(ob.Sphere.fibonacci(40), 0.01)
    lon0, lat0 = rng.uniform(-np.pi, np.pi, 60), rng.uniform(-1.4, 1.4, 60)
    sep = np.logspace(-9, np.log10(3.0), 60)
    bearing = rng.uniform(0, 2 * np.pi, 60)
    lat1 = np.arcsin(np.sin(lat0) * np.cos(sep) + np.cos(lat0) * np.sin(sep) * np.cos(bearing))
    lon1 = lon0 + np.arctan2(np.sin(bearing) * np.sin(sep) * np.cos(lat0),
                             np.cos(sep) - np.sin(lat0) * np.sin(lat1))
    x = np.column_stack([lon0, lat0, np.ones(60), lon1, lat1, np.ones(60)])
    hav = np.sin((lat1 - lat0) / 2) ** 2 + np.cos(lat0) * np.cos(lat1) * np.sin(
        (lon1 - lon0) / 2) ** 2
    ref = 2 * np.arcsin(np.sqrt(hav))
    np.testing.assert_allclose(source_distances(model, x)[:, 0], ref, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(ref, sep, rtol=1e-6)  # the pairs are the separations asked for


def test_four_sources_with_a_near_antipodal_pair_warn():
    """fit_ml says that the Fisher errors of such a fit are not to be trusted."""
    theta = [0.1, 0.1 + np.pi - 0.4 * H, 1.4, -2.3]
    _, seen = _fit(1e-3, theta, [1.0, 0.8, 1.2, 0.9], 11)
    antipodal = [w for w in seen if w.category is ob.AntipodalWarning]
    assert len(antipodal) == 1
    assert "covered the truth less often than stated" in str(antipodal[0].message)


@pytest.mark.parametrize("kind", ["ring", "sphere"])
def test_compiled_covariance_doubts_equal_the_numpy_ones(kind):
    """fit_ml's compiled tests of the covariances flag exactly the rows numpy flags:
    regular, weak, singular (inf), overflowed (NaN), zero and negative variances."""
    from olsbayes.ml.honesty import _doubts

    if kind == "ring":
        model, width = ob.Model(ob.Ring(30), sigma=0.01), 2
    else:
        model, width = ob.Model(ob.Sphere.fibonacci(60), sigma=0.01), 3
    rng = np.random.default_rng(4)
    t, p = 400, 3 * width
    x = rng.uniform(0.0, 1.0, (t, p))
    a = rng.normal(size=(t, p, p)) * 0.01
    cov = a @ a.transpose(0, 2, 1)
    rows = rng.permutation(t)
    cov[rows[:40], 1, 1] = np.inf  # a singular Fisher matrix
    cov[rows[40:80], 0, 1] = np.nan  # an overflowed one
    cov[rows[80:120], width - 1, width - 1] = 0.0
    cov[rows[120:160], 2 * width - 1, 2 * width - 1] = -1e-6
    cov[rows[160:240], width - 1, width - 1] = (x[rows[160:240], width - 1] / WEAK_SDS) ** 2 * (
        1 + rng.uniform(-1e-15, 1e-15, 80))  # at the weak threshold, to rounding
    doubt, no_std = _doubts(model, x, cov)
    want = gaussian_doubts(model, x, cov)
    for key in ("close", "weak"):
        np.testing.assert_array_equal(doubt[key], want[key])
    np.testing.assert_array_equal(doubt["separation"], want["separation"])
    with np.errstate(invalid="ignore"):
        sd = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    np.testing.assert_array_equal(no_std, ~np.isfinite(sd).all(axis=1))
    assert doubt["weak"].any() and not doubt["weak"].all() and no_std.sum() >= 80
