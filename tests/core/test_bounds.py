"""Exact CRLB vs the paper's closed forms (Eq. 3, Eq. 4), the costn kink, singular Fisher.

Why Eq. 3 is exact on an even ring: for one source at theta the clipped cosine
lights the sub-sensors with |phi_n - theta| < pi/2.  The Fisher matrix is
``[[I^2 sum sin^2, -I sum sin cos], [., sum cos^2]] / sigma^2`` over the lit
set.  sin^2, cos^2 and sin cos have period pi, and for even N with no sub-sensor
on the horizon the lit set is N/2 consecutive, equally spaced angles spanning
exactly one period, so the sums are N/4, N/4 and 0: the bounds are
2 sigma / (sqrt(N) I) and 2 sigma / sqrt(N) -- Eq. 3 with equality.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from olsbayes import (
    CosinePower,
    InputError,
    KinkWarning,
    Model,
    Plate,
    ResolutionWarning,
    Ring,
    Scene,
    SensorArray,
    Sphere,
    crlb,
    crlb_eq3,
    crlb_eq4,
)
from olsbayes.bounds import bound_covariance, kink_sources


def _ratio(n: int, theta: float, sigma: float = 0.01, intensity: float = 1.0):
    res = crlb(Model(Ring(n), sigma), Scene(directions=[theta], intensities=[intensity]))
    th3, i3 = crlb_eq3(n, sigma, intensity)
    return res.direction_std[0] / th3, res.intensity_std[0] / i3, res


def test_exact_crlb_equals_eq3_on_ring_30():
    r_theta, r_int, res = _ratio(30, 0.37)
    assert r_theta == pytest.approx(1.0, abs=1e-12)
    assert r_int == pytest.approx(1.0, abs=1e-12)
    # the covariance terms vanish, as the paper says
    assert abs(res.cov[0, 1]) < 1e-12 * np.sqrt(res.cov[0, 0] * res.cov[1, 1])


@pytest.mark.parametrize("n", [4, 10, 30, 64, 200])
@pytest.mark.parametrize("theta", [0.37, -2.9, 1.0])
@pytest.mark.parametrize("sigma,intensity", [(0.01, 1.0), (1e-4, 0.2), (0.3, 7.0)])
def test_eq3_exact_for_every_even_ring_off_the_horizon(n, theta, sigma, intensity):
    ring = Ring(n)
    gamma = np.angle(np.exp(1j * (ring.angles - theta)))
    assert np.abs(np.abs(gamma) - np.pi / 2).min() > 1e-6  # no sub-sensor on the horizon
    r_theta, r_int, _ = _ratio(n, theta, sigma, intensity)
    assert r_theta == pytest.approx(1.0, abs=1e-11)
    assert r_int == pytest.approx(1.0, abs=1e-11)


@pytest.mark.parametrize("n", [31, 101, 1001])
def test_eq3_is_only_approximate_on_odd_rings(n):
    """Odd N: the lit set holds (N +- 1)/2 sub-sensors, not one period; error O(1/N)."""
    thetas = np.linspace(-np.pi, np.pi, 41)[:-1] + 0.0123  # off every horizon
    ratios = np.array([_ratio(n, t)[0] for t in thetas])
    dev = np.abs(ratios - 1.0)
    assert dev.max() <= 1.1 / n
    assert dev.max() >= 0.5 / n


def _ring_with_exact_horizon(n: int) -> SensorArray:
    """A ring of n = 4m normals whose normals at +-pi/2 are exactly (0, +-1)."""
    ang = 2 * np.pi * np.arange(n) / n
    normals = np.column_stack([np.cos(ang), np.sin(ang)])
    normals[np.abs(normals) < 1e-12] = 0.0
    return SensorArray(normals)


def test_kink_case_sensor_exactly_on_the_horizon():
    """A sub-sensor exactly pi/2 from the source sits on the kink of costn.

    There c = 0 and dg/dc jumps from 0 to 1, so the likelihood is not
    differentiable.  The rule: the mean of the Fisher matrices with the horizon
    sub-sensors lit and dark.  On an N = 32 ring both horizon sub-sensors (pi apart)
    add sin^2 = 1 when lit: sum sin^2 = 7 dark, 9 lit, mean 8 = N/4, so Eq. 3 holds
    -- and moving the source by any eps lights exactly one of the two, giving N/4
    and Eq. 3 from both sides.  The intensity bound is unaffected (they add c^2 = 0).
    """
    n, sigma, inten = 32, 0.01, 2.0
    model = Model(_ring_with_exact_horizon(n), sigma)
    th3, i3 = crlb_eq3(n, sigma, inten)
    with pytest.warns(KinkWarning, match="90 deg"):
        res = crlb(model, Scene(directions=[0.0], intensities=[inten]))
    assert res.direction_std[0] / th3 == pytest.approx(1.0, rel=1e-12)
    assert res.intensity_std[0] / i3 == pytest.approx(1.0, rel=1e-12)
    for eps in (1e-6, -1e-6):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # off the kink: no warning
            side = crlb(model, Scene(directions=[eps], intensities=[inten]))
        # sin^2(pi/2 - eps) = 1 - eps^2: Eq. 3 up to O(eps^2)
        assert side.direction_std[0] / th3 == pytest.approx(1.0, abs=1e-10)


@pytest.mark.parametrize("n", [8, 12, 16, 30, 32])
def test_horizon_rule_does_not_depend_on_the_rounding_of_cos(n):
    """Sources placed so that sub-sensors sit on their horizon on the rounded Ring(n).

    cos(pi/2) rounds to +6e-17 for some of these placements and to -2e-16 for
    others, which once lit or darkened the horizon sub-sensors (N = 8 at 0 gave
    sqrt(N / (N + 4)) times Eq. 3, at 3 pi / 4 exactly Eq. 3; N = 30 at pi/2 gave
    sqrt(30 / 34)).  Under the mean rule every even ring gives Eq. 3 exactly, and
    the exact-normal ring of the same N the same bound.
    """
    th3 = crlb_eq3(n, 0.01, 1.0)[0]
    h = 2 * np.pi / n
    placements = [t for t in (0.0, np.pi / 2, np.pi / 4, 3 * h, np.pi / 2 + h)
                  if kink_sources(Model(Ring(n), 0.01), np.array([t, 1.0]))[0]]
    assert placements  # the case is exercised for every n
    for theta in placements:
        with pytest.warns(KinkWarning):
            ratio = _ratio(n, theta)[0]
        assert ratio == pytest.approx(1.0, abs=1e-12)
    if n % 4 == 0:
        with pytest.warns(KinkWarning):
            exact = crlb(Model(_ring_with_exact_horizon(n), 0.01),
                         Scene(directions=[0.0], intensities=[1.0]))
        assert exact.direction_std[0] / th3 == pytest.approx(1.0, abs=1e-12)


def test_horizon_rule_is_the_midpoint_of_the_one_sided_limits_on_an_odd_ring():
    """Odd N: one sub-sensor on the horizon; the Fisher matrix there is the mean of
    the two one-sided limits (the source moved off the horizon by +-eps)."""
    n = 31
    model = Model(Ring(n), 0.01)
    theta = model.array.angles[3] + np.pi / 2  # sub-sensor 3 on the horizon
    x = np.array([theta, 1.0])
    assert kink_sources(model, x)[0]
    with pytest.warns(KinkWarning):
        mid = crlb(model, Scene(directions=[theta], intensities=[1.0])).fisher
    eps = 1e-7
    sides = [model.fisher(np.array([theta + s, 1.0])) for s in (eps, -eps)]
    # the sides differ by the horizon sub-sensor's contribution (I^2 sin^2 = 1 / sigma^2)
    assert abs(sides[0][0, 0] - sides[1][0, 0]) == pytest.approx(1e4, rel=1e-6)
    # each entry moves by at most N I^2 / sigma^2 per rad: O(eps) off the horizon
    np.testing.assert_allclose(mid, 0.5 * (sides[0] + sides[1]), rtol=0,
                               atol=2 * n * eps / 0.01**2)


def test_kink_detected_on_a_standard_ring():
    """Source at pi/30 on Ring(30): sub-sensors at 96 and -84 deg lie on its horizon."""
    model = Model(Ring(30), 0.01)
    x = model.pack(Scene(directions=[np.pi / 30, 0.37], intensities=[1.0, 1.0]))
    np.testing.assert_array_equal(kink_sources(model, x), [True, False])
    with pytest.warns(KinkWarning):
        crlb(model, Scene(directions=[np.pi / 30], intensities=[1.0]))
    # a smooth law has no kink
    smooth = Model(Ring(30), 0.01, CosinePower(2.0))
    assert not kink_sources(smooth, x).any()


def test_coincident_sources_give_resolution_warning_and_inf():
    model = Model(Ring(30), 0.01)
    with pytest.warns(ResolutionWarning, match="cannot be identified"):
        res = crlb(model, Scene(directions=[0.5, 0.5], intensities=[1.0, 0.5]))
    assert not res.resolvable
    assert np.all(np.isinf(res.direction_std))
    assert res.condition == np.inf


def test_dark_source_angle_is_unidentifiable_but_intensity_is_not():
    """I = 0: the angle has zero information, the intensity keeps Eq. 3."""
    model = Model(Ring(30), 0.01)
    with pytest.warns(ResolutionWarning, match=r"theta\[0\]"):
        res = crlb(model, Scene(directions=[0.37], intensities=[0.0]))
    assert np.isinf(res.direction_std[0])
    assert res.intensity_std[0] == pytest.approx(crlb_eq3(30, 0.01, 1.0)[1], rel=1e-12)


def test_bound_covariance_marks_only_null_space_parameters():
    fisher = np.diag([4.0, 0.0, 1.0])
    cov, cond, singular = bound_covariance(fisher)
    np.testing.assert_array_equal(singular, [False, True, False])
    assert cov[0, 0] == pytest.approx(0.25) and cov[2, 2] == pytest.approx(1.0)
    assert np.isinf(cov[1, 1]) and cond == np.inf


def test_crlb_scales_linearly_with_sigma():
    scene = Scene(directions=[0.2, 2.0], intensities=[1.0, 0.4])
    a = crlb(Model(Ring(30), 0.01), scene)
    b = crlb(Model(Ring(30), 0.07), scene)
    np.testing.assert_allclose(b.std, 7.0 * a.std, rtol=1e-12)


def test_crlb_shapes_on_sphere_and_plate():
    sph = crlb(Model(Sphere.grid(15, 20), 0.01),
               Scene(directions=[[0.1, 0.2], [1.5, -0.3]], intensities=[1.0, 1.0]))
    assert sph.direction_std.shape == (2, 2) and sph.position_std is None
    assert np.all(np.isfinite(sph.direction_std))
    pl = crlb(Model(Plate.grid(6, 6, 0.5), 0.01),
              Scene(positions=[[0.2, -0.1, 1.0]], intensities=[1.0]))
    assert pl.position_std.shape == (1, 3) and pl.direction_std is None
    assert np.all(np.isfinite(pl.position_std))


def test_eq4_formula_and_random_guessing_region():
    n, sigma = 30, 1e-4
    inten = np.array([1.0, 0.5])
    ang, amp = crlb_eq4(n, sigma, inten, 0.6)
    eff = n * 0.6 / np.pi
    np.testing.assert_allclose(ang, 2 * sigma / (inten * np.sqrt(eff)), rtol=1e-14)
    assert amp == pytest.approx(2 * sigma / np.sqrt(eff), rel=1e-14)
    # separation pi: Eq. 4 reduces to Eq. 3
    np.testing.assert_allclose(crlb_eq4(n, sigma, inten, np.pi)[0],
                               crlb_eq3(n, sigma, inten)[0], rtol=1e-12)
    # n * d / pi <= 1: no better than random guessing
    ang, amp = crlb_eq4(n, sigma, 1.0, np.pi / n)
    assert np.isinf(ang) and np.isinf(amp)
    # separations are folded to [0, pi]
    np.testing.assert_allclose(crlb_eq4(n, sigma, 1.0, 2 * np.pi - 0.6)[0],
                               crlb_eq4(n, sigma, 1.0, 0.6)[0], rtol=1e-12)


def test_closed_forms_reject_bad_input():
    with pytest.raises(InputError, match="n"):
        crlb_eq3(2, 0.01, 1.0)
    with pytest.raises(InputError, match="sigma"):
        crlb_eq3(30, 0.0, 1.0)
    with pytest.raises(InputError, match="intensity"):
        crlb_eq3(30, 0.01, 0.0)
    with pytest.raises(InputError, match="separation"):
        crlb_eq4(30, 0.01, 1.0, np.nan)


@pytest.mark.parametrize("n", [29, 30, 31, 32])
def test_resolution_limits_of_two_equal_sources(n):
    """What the README says: the Fisher matrix of two equal sources dtheta apart is
    singular at every placement for dtheta < h/2 (odd N) or < h (even N), and regular at
    every placement for dtheta > h (odd N) or > 2h (even N), h = 2 pi / N; Eq. 4's
    threshold, half a spacing, is finite from h/2 on.  400 random placements each."""
    model = Model(Ring(n), 0.01)
    h = 2 * np.pi / n
    rng = np.random.default_rng(n)
    odd = n % 2 == 1

    def singular_fraction(sep_h):
        th = rng.uniform(-np.pi, np.pi, 400)
        one = np.ones_like(th)
        x = np.stack([th, one, th + sep_h * h, one], axis=1)
        return bound_covariance(model.fisher(x))[2].any(axis=-1).mean()

    below, above = (0.45, 1.02) if odd else (0.98, 2.02)
    assert singular_fraction(below) == 1.0
    assert singular_fraction(above) == 0.0
    middle = singular_fraction(0.75 if odd else 1.5)
    assert 0.3 < middle < 0.7  # in between it depends on the placement
    assert np.isinf(crlb_eq4(n, 0.01, 1.0, 0.49 * h)[0])
    assert np.isfinite(crlb_eq4(n, 0.01, 1.0, 0.51 * h)[0])
