"""The incremental autocorrelation time of the stopping rule equals emcee's estimate."""

from __future__ import annotations

import emcee
import numpy as np

from olsbayes.posterior._run import AutocorrTime


def _ar1(rng, n, phi, scale, offset, walkers=16):
    x = np.zeros((n, walkers, phi.size))
    x[0] = rng.standard_normal((walkers, phi.size))
    for t in range(1, n):
        x[t] = phi * x[t - 1] + np.sqrt(1 - phi**2) * rng.standard_normal((walkers, phi.size))
    return x * scale + offset


def test_incremental_tau_equals_emcee_at_every_check():
    rng = np.random.default_rng(4)
    # tau from ~1 to ~100 (windows beyond the initial lag bound), offsets far from 0
    chain = _ar1(rng, 1200, np.array([0.0, 0.5, 0.9, 0.98]), np.array([1e-3, 1.0, 5.0, 1e-2]),
                 np.array([2.4, -1.0, 0.5, 1e3]))
    track = AutocorrTime(chain[0], max_lag=4)
    for n in (2, 3, 50, 100, 300, 700, 1200):
        ref = emcee.autocorr.integrated_time(chain[:n], tol=0)
        # the same sums in another order: equal to rounding (tau in steps, ~1e-12 of it)
        np.testing.assert_allclose(track.update(chain[:n]), ref, rtol=1e-9, atol=1e-9)


def test_frozen_walker_gives_nan_as_emcee():
    chain = np.ones((200, 8, 2))
    chain[:, :, 1] += np.random.default_rng(1).standard_normal((200, 8))
    with np.errstate(invalid="ignore"):
        ref = emcee.autocorr.integrated_time(chain, tol=0)
        mine = AutocorrTime(chain[0]).update(chain)
    assert np.isnan(ref[0]) and np.isnan(mine[0])
    np.testing.assert_allclose(mine[1], ref[1], rtol=1e-9)
