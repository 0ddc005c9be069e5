"""Exact sampling of box-truncated multivariate normals.

Target density on the box ``lower <= x <= upper`` (bounds may be infinite)::

    p(x) ∝ exp(-x^T Q x / 2 + b^T x),   Q symmetric positive semi-definite.

:func:`sample_truncated_gaussian` runs the exact Hamiltonian Monte Carlo of
Pakman & Paninski (2014, J. Comput. Graph. Stat. 23:518): with the Gaussian's
covariance as mass matrix every coordinate moves on ``x(t) = mu + a cos t +
v sin t``, so wall hitting times are closed form and a trajectory is followed
exactly, bouncing off the walls (no step size, no discretisation error).  All
bookkeeping happens in x-space: a bounce on wall k reflects the velocity by
``v <- v - 2 v_k S[:, k] / S[k, k]`` with ``S = Q^{-1}`` (O(K) per bounce).

A singular ``Q`` (the imaging design matrix has a null space) has no
covariance.  We then run the exact dynamics of a surrogate with precision
``Q + ridge * 1`` centred on ``centre`` and correct with a Metropolis step on the
ratio target / surrogate ``= exp(ridge * |x - centre|^2 / 2)``: the surrogate
flow is reversible and volume preserving, so the chain is exact for the
target.  Trajectories with more than ``max_bounces`` bounces are rejected
(symmetric in time, so this also keeps detailed balance).

:func:`truncnorm_1d` draws from univariate truncated normals, vectorised, by
inversion in log space (accurate far in the tails).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .._validation import integer, positive_float
from ..errors import InputError

__all__ = ["Dynamics", "Ridge", "TruncatedSamples", "sample_truncated_gaussian", "trajectory",
           "truncnorm_1d"]

_TINY_T = 1e-12


@dataclass(frozen=True)
class Ridge:
    """The surrogate of a singular precision: ``Q + strength * 1`` centred on ``centre``.

    Attributes
    ----------
    strength : float
        Ridge added to every diagonal element of Q (> 0); the draws are then
        Metropolis-corrected (module notes).
    centre : ndarray, shape (K,), optional
        Centre of the ridge (default 0).
    """

    strength: float
    centre: np.ndarray | None = None

    def __post_init__(self) -> None:
        positive_float("Ridge.strength", self.strength)


@dataclass(frozen=True)
class Dynamics:
    """Length and bounce cap of each exact-HMC trajectory.

    Attributes
    ----------
    t_total : float
        Trajectory length (pi/2 decorrelates the untruncated Gaussian fully).
    max_bounces : int
        Trajectories with more bounces are rejected (module notes).
    """

    t_total: float = np.pi / 2
    max_bounces: int = 20_000

    def __post_init__(self) -> None:
        positive_float("Dynamics.t_total", self.t_total)
        integer("Dynamics.max_bounces", self.max_bounces, low=1)


@dataclass(frozen=True)
class TruncatedSamples:
    """Draws of a truncated Gaussian.

    Attributes
    ----------
    samples : ndarray, shape (n_chains, n_samples, K)
    acceptance : float
        Fraction of accepted trajectories (1 when no ridge was needed).
    mean_bounces : float
        Average number of wall bounces per trajectory.
    """

    samples: np.ndarray
    acceptance: float
    mean_bounces: float


def truncnorm_1d(
    mean: np.ndarray, sd: np.ndarray, lower: np.ndarray, upper: np.ndarray, *,
    rng: np.random.Generator,
) -> np.ndarray:
    """Draws of N(mean, sd^2) truncated to [lower, upper], broadcast elementwise.

    Works on the standardised interval ``[alpha, beta]``; intervals in the upper
    tail are mirrored to the lower tail so the log-CDF inversion stays accurate.
    """
    from scipy.special import log_ndtr, ndtri_exp  # on use: scipy is slow to import
    mean, sd, lower, upper = np.broadcast_arrays(
        *(np.asarray(v, dtype=float) for v in (mean, sd, lower, upper))
    )
    alpha, beta = (lower - mean) / sd, (upper - mean) / sd
    flip = alpha + beta > 0  # interval mostly above the mean: mirror it
    lo = np.where(flip, -beta, alpha)
    hi = np.where(flip, -alpha, beta)
    log_lo, log_hi = log_ndtr(lo), log_ndtr(hi)
    u = rng.random(mean.shape)
    # log(Phi(lo) + u (Phi(hi) - Phi(lo))) in log space (Phi(hi) >= Phi(lo))
    with np.errstate(divide="ignore"):  # empty interval lo == hi: diff = -inf, z = lo
        diff = np.log1p(-np.exp(np.minimum(log_lo - log_hi, 0.0)))  # log(1 - Phi(lo)/Phi(hi))
    logp = np.logaddexp(log_lo, np.log(np.maximum(u, 1e-300)) + log_hi + diff)
    z = ndtri_exp(np.minimum(logp, 0.0))
    z = np.clip(z, lo, hi)
    z = np.where(flip, -z, z)
    return mean + sd * z


def _hit_times(a, v, h_lo, h_hi):
    """Earliest wall crossing per chain: (t, index, is_upper), shapes (C,)."""
    r = np.hypot(a, v)
    phi = np.arctan2(v, a)
    with np.errstate(invalid="ignore", divide="ignore"):
        c_lo = h_lo / r
        c_hi = h_hi / r
    tau = 2 * np.pi
    t_lo = np.where(np.abs(c_lo) < 1, np.mod(phi + np.arccos(np.clip(c_lo, -1, 1)), tau), np.inf)
    t_hi = np.where(np.abs(c_hi) < 1, np.mod(phi - np.arccos(np.clip(c_hi, -1, 1)), tau), np.inf)
    t_lo[t_lo < _TINY_T] = np.inf
    t_hi[t_hi < _TINY_T] = np.inf
    both = np.concatenate([t_lo, t_hi], axis=1)  # (C, 2K)
    j = np.argmin(both, axis=1)
    t = both[np.arange(both.shape[0]), j]
    k = a.shape[1]
    return t, j % k, j >= k


def trajectory(
    x: np.ndarray, mu: np.ndarray, v: np.ndarray, cov: np.ndarray, lower: np.ndarray,
    upper: np.ndarray, t_total: float, max_bounces: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Follow the exact dynamics of C chains for time ``t_total``.

    Parameters
    ----------
    x, v : ndarray, shape (C, K)
        Start positions (inside the box) and velocities.
    mu : ndarray, shape (K,) or (C, K)
        Mean of the (untruncated) Gaussian, shared or one per chain.
    cov : ndarray, shape (K, K)
        Its covariance (the mass matrix's inverse).
    lower, upper : ndarray, shape (K,)
        The box.
    t_total : float
    max_bounces : int

    Returns
    -------
    x_end : ndarray, shape (C, K)
        End positions; NaN rows for trajectories stopped at ``max_bounces``.
    n_bounces : ndarray of int, shape (C,)
    """
    c = x.shape[0]
    mu = np.broadcast_to(mu, x.shape)
    a = x - mu
    x_end = x.copy()
    t_left = np.full(c, t_total)
    nb = np.zeros(c, dtype=int)
    active = np.arange(c)
    sdiag = np.diag(cov)
    while active.size:
        aa, vv, mm = a[active], v[active], mu[active]
        t, k, up = _hit_times(aa, vv, lower - mm, upper - mm)
        done = t >= t_left[active]
        if np.any(done):
            td = t_left[active[done]][:, None]
            x_end[active[done]] = mm[done] + aa[done] * np.cos(td) + vv[done] * np.sin(td)
        go = ~done
        idx, t, k, up = active[go], t[go][:, None], k[go], up[go]
        if idx.size:
            aa, vv, mm = aa[go], vv[go], mm[go]
            xs = mm + aa * np.cos(t) + vv * np.sin(t)
            vel = -aa * np.sin(t) + vv * np.cos(t)
            rows = np.arange(idx.size)
            xs[rows, k] = np.where(up, upper[k], lower[k])
            vk = vel[rows, k]
            vel = vel - (2.0 * vk / sdiag[k])[:, None] * cov[k]
            a[idx], v[idx] = xs - mm, vel
            t_left[idx] -= t[:, 0]
            nb[idx] += 1
            over = nb[idx] > max_bounces
            if np.any(over):
                x_end[idx[over]] = np.nan  # rejected below
                idx = idx[~over]
        active = idx
    return x_end, nb


def sample_truncated_gaussian(
    precision: np.ndarray,
    linear: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    x0: np.ndarray,
    n_samples: int,
    *,
    rng: np.random.Generator,
    n_burn: int = 50,
    ridge: Ridge | None = None,
    dynamics: Dynamics = Dynamics(),
    step: Callable[[], object] | None = None,
) -> TruncatedSamples:
    """Exact HMC draws of ``exp(-x^T Q x / 2 + b^T x)`` on a box.

    Parameters
    ----------
    precision : ndarray, shape (K, K)
        Q, symmetric positive semi-definite.
    linear : ndarray, shape (K,)
        b.
    lower, upper : ndarray, shape (K,)
        Box bounds (may be -inf / inf; lower < upper).
    x0 : ndarray, shape (C, K)
        Starting points of C independent chains, strictly inside the box.
    n_samples : int
        Draws kept per chain (after ``n_burn`` discarded trajectories).
    rng : numpy.random.Generator
    ridge : Ridge, optional
        Surrogate ridge, needed when Q is singular (module notes); None: none.
    dynamics : Dynamics
        Trajectory length and bounce cap.
    step : callable, optional
        Called after every trajectory (a progress bar's ``update``).
    """
    k = precision.shape[0]
    strength, centre = (0.0, None) if ridge is None else (float(ridge.strength), ridge.centre)
    centre = np.zeros(k) if centre is None else np.asarray(centre, dtype=float)
    if centre.shape != (k,):
        raise InputError(f"ridge.centre must have shape ({k},) (one entry per coordinate); "
                         f"got {centre.shape}")
    q = precision + strength * np.eye(k)
    lq = np.linalg.cholesky(q)
    eye = np.eye(k)
    lq_inv = np.linalg.solve(lq, eye)  # Q_s = lq lq^T ; S = lq_inv^T lq_inv
    cov = lq_inv.T @ lq_inv
    mu = cov @ (linear + strength * centre)
    x = np.array(x0, dtype=float)
    c = x.shape[0]
    out = np.empty((c, n_samples, k))
    n_acc = n_traj = bounces = 0
    for it in range(n_burn + n_samples):
        v = rng.standard_normal((c, k)) @ lq_inv  # rows ~ N(0, S)
        x_new, nb = trajectory(x, mu, v, cov, lower, upper, dynamics.t_total,
                                dynamics.max_bounces)
        ok = np.all(np.isfinite(x_new), axis=1)
        if strength > 0:
            d_new = np.sum((np.where(ok[:, None], x_new, x) - centre) ** 2, axis=1)
            d_old = np.sum((x - centre) ** 2, axis=1)
            ok &= np.log(rng.random(c)) < 0.5 * strength * (d_new - d_old)
        x = np.where(ok[:, None], x_new, x)
        n_acc += int(ok.sum())
        n_traj += c
        bounces += int(nb.sum())
        if it >= n_burn:
            out[:, it - n_burn] = x
        if step is not None:
            step()
    return TruncatedSamples(out, n_acc / n_traj, bounces / n_traj)
