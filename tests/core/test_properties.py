"""Property-based tests (hypothesis) of the Eq. 1 core and the CRLB."""

from __future__ import annotations

import warnings

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from olsbayes import CosinePower, Model, Ring, Scene, Sphere, crlb
from olsbayes.bounds import SINGULAR_RTOL
from olsbayes.errors import OlsBayesWarning

# derandomize: the examples are a fixed function of the test (CI must not flake on a
# new random draw); the properties still run over 60 varied cases each.
SETTINGS = settings(max_examples=60, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])

angles = st.floats(-np.pi, np.pi, allow_nan=False)
intensity = st.floats(0.0, 10.0, allow_nan=False)
n_sensors = st.integers(3, 64)
laws = st.sampled_from([None, CosinePower(2.0), CosinePower(5.5)])


@st.composite
def ring_case(draw, max_k=4):
    n = draw(n_sensors)
    k = draw(st.integers(1, max_k))
    theta = draw(arrays(float, k, elements=angles))
    inten = draw(arrays(float, k, elements=intensity))
    return n, theta, inten


def _flat(theta, inten):
    return np.column_stack([theta, inten]).ravel()


@SETTINGS
@given(case=ring_case(), law=laws)
def test_ring_response_nonnegative(case, law):
    n, theta, inten = case
    model = Model(Ring(n), 0.1, law)
    assert np.all(model.response(_flat(theta, inten)) >= 0.0)


@SETTINGS
@given(lon=arrays(float, 3, elements=angles),
       lat=arrays(float, 3, elements=st.floats(-np.pi / 2, np.pi / 2)),
       inten=arrays(float, 3, elements=intensity), law=laws)
def test_sphere_response_nonnegative(lon, lat, inten, law):
    model = Model(Sphere.fibonacci(40), 0.1, law)
    x = np.column_stack([lon, lat, inten]).ravel()
    assert np.all(model.response(x) >= 0.0)


@SETTINGS
@given(case=ring_case(), shift=angles, law=laws)
def test_ring_response_invariant_to_common_rotation(case, shift, law):
    """Rotating sensors and sources together leaves every reading unchanged."""
    n, theta, inten = case
    base = Model(Ring(n), 0.1, law).response(_flat(theta, inten))
    turned = Model(Ring(n, offset=shift), 0.1, law).response(_flat(theta + shift, inten))
    # rounding of the rotated unit vectors moves c by ~1e-15; g is Lipschitz (p <= 5.5)
    np.testing.assert_allclose(turned, base, rtol=0, atol=1e-12 * (1 + inten.sum()))


@SETTINGS
@given(case=ring_case(), scale=st.floats(0.0, 100.0), law=laws)
def test_ring_response_linear_in_intensities(case, scale, law):
    n, theta, inten = case
    model = Model(Ring(n), 0.1, law)
    mu = model.response(_flat(theta, inten))
    np.testing.assert_allclose(model.response(_flat(theta, scale * inten)), scale * mu,
                               rtol=1e-12, atol=1e-300)
    # additivity over sources
    singles = sum(model.response(_flat(theta[i:i + 1], inten[i:i + 1]))
                  for i in range(theta.size))
    np.testing.assert_allclose(mu, singles, rtol=1e-12, atol=1e-13 * (1 + inten.sum()))


@SETTINGS
@given(n=n_sensors, k=st.integers(1, 3), w=st.integers(1, 5), seed=st.integers(0, 2**32 - 1))
def test_batched_equals_looped(n, k, w, seed):
    rng = np.random.default_rng(seed)
    model = Model(Ring(n), 0.1)
    x = np.stack([rng.uniform(-np.pi, np.pi, (w, k)), rng.uniform(0, 3, (w, k))], -1)
    x = x.reshape(w, -1)
    data = rng.normal(size=n)
    batch_mu, batch_ll = model.response(x), model.log_likelihood(x, data)
    for i in range(w):
        np.testing.assert_allclose(batch_mu[i], model.response(x[i]), rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(batch_ll[i], model.log_likelihood(x[i], data), rtol=1e-12)


@SETTINGS
@given(case=ring_case(max_k=2), factor=st.floats(1e-3, 1e3))
def test_crlb_scales_with_sigma(case, factor):
    n, theta, inten = case
    scene = Scene(directions=theta, intensities=inten)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OlsBayesWarning)  # singular / kink cases included
        a = crlb(Model(Ring(n), 0.01), scene)
        b = crlb(Model(Ring(n), 0.01 * factor), scene)
    finite = np.isfinite(a.std)
    np.testing.assert_array_equal(finite, np.isfinite(b.std))
    # Exact in exact arithmetic; each pseudo-inverse has a relative forward error of
    # about kappa * eps, kappa the condition number of the Fisher matrix on its
    # non-null eigenspace (a near-zero intensity makes kappa large: 1e7 seen).
    w = np.linalg.eigvalsh(a.fisher)
    kept = w[w > SINGULAR_RTOL * w.max()]
    kappa = kept.max() / kept.min()
    rtol = 1e-12 + 4 * kappa * np.finfo(float).eps
    np.testing.assert_allclose(b.std[finite], factor * a.std[finite], rtol=rtol)


@SETTINGS
@given(case=ring_case(), turns=arrays(int, 4, elements=st.integers(-50, 50)),
       seed=st.integers(0, 2**32 - 1))
def test_wrapping_ring_angles_never_changes_the_likelihood(case, turns, seed):
    n, theta, inten = case
    model = Model(Ring(n), 0.05)
    data = model.simulate(_flat(theta, inten), rng=seed)
    wrapped = theta + 2 * np.pi * turns[: theta.size]
    ll, ll_wrapped = model.log_likelihood(_flat(theta, inten), data), model.log_likelihood(
        _flat(wrapped, inten), data)
    # 2*pi*m is inexact in floating point: |d theta| <= 50 * 2 pi * eps ~ 7e-14 rad, which
    # moves each reading by <= I * 7e-14 and chi^2 / 2 by <= sum|resid| I 7e-14 / sigma^2
    resid = np.abs(data - model.response(_flat(theta, inten))).sum()
    tol = 1e-12 + (resid + 1.0) * (1 + inten.sum()) * 1e-13 / 0.05**2
    assert abs(ll - ll_wrapped) <= tol
