"""The readings' unit is arbitrary: fits, bounds and posterior starts are covariant.

Readings, sigma and intensities scaled by one factor c leave the angles and
every log-likelihood ratio unchanged; intensities, their bounds and their
posterior spread scale by c; the log-likelihood shifts by -N log c.  Checked at
c = 1e-12 (photocurrents in A) and 1e12, where optimiser tolerances and
eigenvalue thresholds in absolute or mixed units used to break (see
``olsbayes.ml.scaling`` and ``olsbayes.bounds.equilibrate``).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.ml import fit_ml

SCALES = (1e-12, 1e12)


def _case(c: float, k: int, size: int):
    model = ob.Model(ob.Ring(30), 1e-2 * c)
    ang = 0.37 + 2 * np.pi * np.arange(k) / k + 0.13 * np.arange(k)
    if k == 4:  # the formula's K = 4 scene is ambiguous (benchmarks/ml_speed_accuracy.py)
        ang = 0.37 + np.radians([0.0, 60.0, 150.0, 260.0])
    scene = ob.Scene(directions=ang, intensities=np.linspace(1.0, 0.6, k) * c)
    unit = ob.Model(ob.Ring(30), 1e-2)
    data = unit.simulate(ob.Scene(directions=ang, intensities=np.linspace(1.0, 0.6, k)),
                         rng=np.random.default_rng(k), size=size)
    return model, scene, unit, data


@pytest.mark.parametrize("c", SCALES)
@pytest.mark.parametrize("method,k", [("fast", 1), ("fast", 2), ("fast", 4), ("exact", 2),
                                      ("multistart", 2)])
def test_fit_ml_is_covariant_in_the_readings_unit(method, k, c):
    """Same optima in any unit: angles to the LM's tolerance (ftol = 1e-10 relative in
    chi^2 moves a parameter by ~sqrt(1e-10 chi^2 / sigma^2) ~ 1e-4 Fisher std; 1e-3
    asserted), log-likelihoods to 1e-6 after the -N log c shift, intensities and
    their Fisher std times c."""
    model, _, unit, data = _case(c, k, 3 if method == "multistart" else 40)
    opts = dict(rng=0) if method == "multistart" else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ob.OlsBayesWarning)
        ref = fit_ml(unit, data, k, method=method, **opts)
        got = fit_ml(model, data * c, k, method=method, **opts)
    std = np.sqrt(np.diagonal(ref.cov, axis1=-2, axis2=-1))
    u = np.tile([1.0, c], k)
    assert np.all(np.abs(got.params / u - ref.params) <= 1e-3 * std)
    np.testing.assert_allclose(got.log_likelihood + 30 * np.log(c), ref.log_likelihood,
                               atol=1e-6)
    np.testing.assert_allclose(np.sqrt(np.diagonal(got.cov, axis1=-2, axis2=-1)) / u, std,
                               rtol=1e-6)


@pytest.mark.parametrize("c", SCALES)
def test_crlb_is_covariant_in_the_readings_unit(c):
    """The exact CRLB in units of 1e-12 (readings ~1e-12): angle bounds unchanged,
    intensity bounds times c, no spurious singularity (the raw Fisher matrix's
    eigenvalues span c^-2 there; its equilibrated form does not)."""
    model, scene, unit, _ = _case(c, 3, 1)
    ref = ob.crlb(unit, ob.Scene(directions=scene.directions, intensities=scene.intensities / c))
    with warnings.catch_warnings():
        warnings.simplefilter("error", ob.ResolutionWarning)
        got = ob.crlb(model, scene)
    assert got.resolvable
    np.testing.assert_allclose(got.direction_std, ref.direction_std, rtol=1e-9)
    np.testing.assert_allclose(got.intensity_std / c, ref.intensity_std, rtol=1e-9)
    np.testing.assert_allclose(got.condition, ref.condition, rtol=1e-6)


@pytest.mark.parametrize("c", SCALES)
def test_posterior_start_ball_is_covariant_in_the_readings_unit(c):
    """The walkers' starting ball around the ML point: its covariance is the unit-scale
    one in units of c (before, the ball's angle spread hit the prior cap at c = 1e12
    and its intensity spread at c = 1e-12), and its square root reproduces it
    entry by entry, relative to each entry's own scale."""
    from olsbayes.bounds import covariance_root
    from olsbayes.posterior._start import ball_covariance
    from olsbayes.priors import default_priors

    model, _, unit, data = _case(c, 2, 1)
    covs = []
    for m, d in ((unit, data[0]), (model, data[0] * c)):
        x = fit_ml(m, d, 2, warn=False).params
        covs.append(ball_covariance(m, default_priors(m, 2, data=d), x))
    u = np.tile([1.0, c], 2)
    np.testing.assert_allclose(covs[1] / np.outer(u, u), covs[0], rtol=1e-6,
                               atol=1e-12 * np.max(covs[0]))
    root = covariance_root(covs[1])
    sd = np.sqrt(np.diag(covs[1]))
    np.testing.assert_allclose((root @ root.T) / np.outer(sd, sd), covs[1] / np.outer(sd, sd),
                               atol=1e-12)
