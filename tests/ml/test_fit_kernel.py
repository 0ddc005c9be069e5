"""The compiled statistics of a fit's result (olsbayes.ml._numba.fit) against numpy.

chi^2 and the Fisher matrix against ``Model.log_likelihood`` / ``Model.fisher`` (to
rounding), the covariances against ``bounds.bound_covariance`` and the numpy
equilibration (to the bit), and the sphere's branch-free evaluation that these
kernels share with the LM kernel against the general loop's arithmetic.
"""

from __future__ import annotations

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.ml._numba import fit as _fit_kernel


@pytest.mark.parametrize("geometry", ["ring", "sphere", "plate"])
def test_chi2_fisher_matches_model(geometry):
    """The compiled chi^2 and Fisher matrix (used for MLResult) == Model's, to rounding."""
    if geometry == "ring":
        model = ob.Model(ob.Ring(30), 1e-2, ob.CosinePower(1.5))
        scene = ob.Scene(directions=[0.4, 2.5], intensities=[1.0, 0.6])
    elif geometry == "sphere":
        model = ob.Model(ob.Sphere.fibonacci(60), 1e-2)
        scene = ob.Scene(directions=[[0.4, 0.2], [2.5, -0.5]], intensities=[1.0, 0.6])
    else:
        model = ob.Model(ob.Plate.grid(5, 5, pitch=1.0), 1e-3)
        scene = ob.Scene(positions=[[2.0, 2.5, 3.0]], intensities=[10.0])
    truth = model.pack(scene)
    data = model.simulate(scene, rng=23, size=6)
    x = truth + 0.01 * np.random.default_rng(24).standard_normal((6, truth.size))
    chi2, fisher = _fit_kernel.chi2_fisher(model, x, data)
    ll = model.log_likelihood(x, data)
    const = -model.n_sensors * (np.log(model.sigma) + 0.5 * np.log(2 * np.pi))
    np.testing.assert_allclose(-0.5 * chi2 / model.sigma**2 + const, ll, rtol=1e-12)
    ref = model.fisher(x)
    np.testing.assert_allclose(fisher, ref, rtol=0, atol=1e-12 * np.abs(ref).max())


def test_compiled_covariances_match_numpy():
    from olsbayes.bounds import SINGULAR_RTOL, bound_covariance

    model = ob.Model(ob.Ring(30), 1e-2)
    x = np.array([[0.4, 1.0, 2.5, 0.6],  # regular
                  [0.4, 1.0, 0.4, 0.6],  # coincident sources: singular Fisher
                  [0.4, 1.0, 2.5, 0.0]])  # zero intensity: its angle unidentified
    fisher = model.fisher(x)
    a = _fit_kernel.covariances(fisher, SINGULAR_RTOL)
    b = bound_covariance(fisher)[0]
    np.testing.assert_array_equal(np.isinf(a), np.isinf(b))
    assert np.isinf(a[1:]).any() and not np.isinf(a[0]).any()
    fin = np.isfinite(b)
    np.testing.assert_allclose(a[fin], b[fin], rtol=1e-9, atol=1e-12 * np.abs(b[fin]).max())
    # the regular matrix takes the Cholesky route, the singular ones the eigenvalues
    ok = [_fit_kernel._chol_inverse(f, np.zeros((4, 4)), np.empty((4, 4)), SINGULAR_RTOL)
          for f in fisher]
    assert ok == [True, False, False]


def test_compiled_sphere_cosine_evaluation_is_the_general_arithmetic():
    """The sphere's branch-free evaluation (clipped cosine), through the fit's statistics
    kernel: chi^2 bit for bit that of the general loop's operations (response rows summed
    in order), the Fisher matrix that of its Jacobian (0 at unlit sensors), to rounding;
    at a pole too."""
    model = ob.Model(ob.Sphere.fibonacci(300), 1e-2)
    nrm = model.array.normals.T
    rng = np.random.default_rng(5)
    for k in (1, 4):
        x = np.column_stack([rng.uniform(-4, 4, k), rng.uniform(-1.6, 1.6, k),
                             rng.uniform(0, 2, k)])
        x[0, 1] = np.pi / 2  # a source at the pole
        x, s = x.ravel(), rng.normal(size=300)
        chi2, fisher = _fit_kernel.chi2_fisher(model, x[None], s[None])
        resp, rows = np.zeros(300), []
        for j in range(k):
            lon, lat, inten = x[3 * j : 3 * j + 3]
            cla, sla, clo, slo = np.cos(lat), np.sin(lat), np.cos(lon), np.sin(lon)
            c = cla * clo * nrm[0] + cla * slo * nrm[1] + sla * nrm[2]
            lit = c > 0
            rows += [np.where(lit, inten * (-cla * slo * nrm[0] + cla * clo * nrm[1]), 0),
                     np.where(lit, inten * (-sla * clo * nrm[0] - sla * slo * nrm[1]
                                            + cla * nrm[2]), 0),
                     np.where(lit, c, 0.0)]
            resp = resp + rows[-1] * inten
        r = s - resp
        assert chi2[0] == np.cumsum(r * r)[-1]  # a plain sum in order
        jac = np.array(rows)
        np.testing.assert_allclose(fisher[0], jac @ jac.T / 1e-4, rtol=1e-12,
                                   atol=1e-12 * np.abs(fisher[0]).max())


def test_compiled_equilibration_equals_numpy_to_the_bit():
    """The kernel equilibrates and scales back as bounds.equilibrate does in numpy."""
    from olsbayes.bounds import SINGULAR_RTOL, equilibrate

    rng = np.random.default_rng(0)
    for p, scale in [(2, 1e-6), (4, 1.0), (8, 1e6)]:
        a = rng.normal(size=(50, p, p)) * scale
        fisher = a @ a.transpose(0, 2, 1)
        fisher[::7, 0, :] = fisher[::7, :, 0] = 0.0  # a zero diagonal
        fisher[::5, 1], fisher[::5, :, 1] = fisher[::5, 0], fisher[::5, :, 0]  # singular
        f, d = equilibrate(fisher)
        out = np.empty(f.shape)
        _fit_kernel._cov_all(np.ascontiguousarray(f), SINGULAR_RTOL, out)
        want = out * d[:, :, None] * d[:, None, :]
        got = _fit_kernel.covariances(fisher, SINGULAR_RTOL)
        np.testing.assert_array_equal(got, want)
        assert np.isinf(got[::5]).any()
