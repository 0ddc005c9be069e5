"""The intensities integrated out: importance weights of source locations.

On Eq. 1 the readings are linear in the intensities, ``y = G(loc) I + noise``.  For
fixed locations the likelihood is Gaussian in I with mean I^ = (G^T G)^-1 G^T y and
covariance C = sigma^2 (G^T G)^-1, so

    int pi(loc, I) L(loc, I) dI = max_I L (2 pi)^(K/2) det(C)^(1/2) E_{N(I^, C)}[pi(loc, I)]

for any intensity prior.  :func:`location_log_weights` estimates the expectation
without bias from one Gaussian draw, or -- for a flat (uniform box) prior -- by
integrating exactly along C's widest direction (Rao-Blackwellised: a source split
in two close ones leaves one intensity direction far wider than the box).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["location_log_weights"]

LOG_2PI = math.log(2.0 * math.pi)


def _log_interval(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """log(Phi(b) - Phi(a)) for a <= b, on the tail that keeps precision; -inf if a >= b."""
    from scipy.special import log_ndtr  # on use: scipy is slow to import
    flip = a > 0
    lo, hi = np.where(flip, -b, a), np.where(flip, -a, b)
    la, lb = log_ndtr(lo), log_ndtr(hi)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = lb + np.log1p(-np.exp(np.minimum(la - lb, 0.0)))
    return np.where(hi > lo, out, -np.inf)


def _box_line(base: np.ndarray, v: np.ndarray, sd: np.ndarray, lo: float, hi: float
              ) -> np.ndarray:
    """log P(base + t v in [lo, hi]^K) for t ~ N(0, sd^2); shapes (n, K), (n, K), (n,)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (lo - base) / v, (hi - base) / v
    pos, neg = v > 0, v < 0
    t_lo = np.where(pos, a, np.where(neg, b, np.where((base >= lo) & (base <= hi), -np.inf,
                                                         np.inf)))
    t_hi = np.where(pos, b, np.where(neg, a, np.inf))
    return _log_interval(t_lo.max(axis=1) / sd, t_hi.min(axis=1) / sd)


def _wide_direction(cov: np.ndarray, n_iter: int = 4) -> np.ndarray:
    """Unit vectors (n, K) near the widest direction of each covariance (n, K, K).

    Power iteration from the coordinate of largest variance (fixed given cov).
    """
    j = np.argmax(np.diagonal(cov, axis1=1, axis2=2), axis=1)
    u = np.take_along_axis(cov, j[:, None, None], axis=2)[..., 0]
    for _ in range(n_iter):
        u = u / np.linalg.norm(u, axis=1, keepdims=True)
        u = np.einsum("nij,nj->ni", cov, u)
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def location_log_weights(model, data: np.ndarray, prior, loc: np.ndarray, *,
                         rng: np.random.Generator) -> np.ndarray:
    """log of  max_I L (2 pi)^(K/2) det(C)^(1/2) E_{N(I^, C)}[pi(loc, I)]  per draw, (n,).

    The intensities given the locations are N(I^, C).  For a general intensity prior
    one draw of them estimates E[pi].  For a flat one (uniform box) a direction u
    near C's widest is integrated exactly: with s = u.x and c = C u / (u' C u), the
    draw x = y + s c splits into y independent of s ~ N(0, u' C u), and E[pi] is
    estimated by the normal probability that the line I^ + y + s c lies in the box
    (near-coincident sources have one very wide direction that the box cuts).
    """
    n, k, d = loc.shape
    s2 = model.sigma**2
    unit = np.concatenate([loc, np.ones((n, k, 1))], axis=-1).reshape(n * k, d + 1)
    g = model.response(unit).reshape(n, k, -1)  # (n, K, N): columns of G
    gram = g @ g.swapaxes(1, 2)
    sign, logdet = np.linalg.slogdet(gram)
    diag = np.log(np.diagonal(gram, axis1=1, axis2=2)).sum(axis=1)
    # coinciding locations (a null set) make G^T G singular: weight 0
    ok = (sign > 0) & (logdet > diag - 25.0)
    gram = np.where(ok[:, None, None], gram, np.eye(k))
    cov = np.linalg.inv(gram) * s2
    cov = 0.5 * (cov + cov.swapaxes(1, 2))
    rhs = g @ data / s2
    i_hat = np.einsum("nij,nj->ni", cov, rhs)
    # the residual itself, not |y|^2 - I^.G^T y: that difference loses all precision
    # for nearly coincident sources at high SNR (ill-conditioned G^T G)
    resid = data - np.einsum("nk,nks->ns", i_hat, g)
    chi2 = np.einsum("ns,ns->n", resid, resid) / s2
    x = np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.standard_normal((n, k)))
    inten = prior.intensity
    if inten.flat:
        u = _wide_direction(cov)
        cu = np.einsum("nij,nj->ni", cov, u)
        var_s = np.sum(u * cu, axis=1)
        c = cu / var_s[:, None]
        y = x - np.sum(u * x, axis=1)[:, None] * c
        mid = np.full((n, k, 1), 0.5 * (inten.lower + inten.upper))
        flat_x = np.concatenate([loc, mid], axis=-1).reshape(n, k * (d + 1))
        log_pi = prior.log_prob(flat_x) + _box_line(i_hat + y, c, np.sqrt(var_s),
                                                     inten.lower, inten.upper)
    else:
        full = np.concatenate([loc, (i_hat + x)[..., None]], axis=-1).reshape(n, k * (d + 1))
        log_pi = prior.log_prob(full)
    log_det_c = k * math.log(s2) - np.where(ok, logdet, 0.0)
    const = -0.5 * model.n_sensors * math.log(2 * math.pi * s2) + 0.5 * k * LOG_2PI
    out = const - 0.5 * chi2 + 0.5 * log_det_c + log_pi
    return np.where(ok & np.isfinite(out), out, -np.inf)
