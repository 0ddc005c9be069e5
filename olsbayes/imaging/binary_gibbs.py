"""Posterior sampling for the two-level prior by exact block Gibbs on windows of bits.

Model ``y = A I + e``, ``e ~ N(0, sigma^2 1)``, ``I = i_max * s`` with bits
``s_k`` independent a priori, ``P(s_k = 1) = p``.  Up to a constant the log
posterior is (as in :mod:`olsbayes.imaging.binary`)

    L(s) = -|y - A I|^2 / (2 sigma^2) + n_bright log p + (K - n_bright) log(1 - p).

A block update takes a window ``B`` of ``w`` neighbouring sources and draws
its ``2^w`` bit patterns from their exact conditional given the other bits
(heat bath): with ``c = A_B^T r`` (``r`` the residual) and ``G = A_B^T A_B``
the conditional log weight of a pattern ``t`` relative to the current ``b`` is

    i_max (t - b)^T c / sigma^2 - i_max^2 (t^T G t - 2 t^T G b) / (2 sigma^2)
    + n_bright(t) log(p / (1 - p))          (terms free of t dropped).

Every window update leaves the posterior invariant and includes every single
flip, pair swap and local checkerboard of the window, so the chain can leave
the local optima of the MAP search.  Cost per window and chain:
O(N w + 2^w w); ``w`` <= 12.

Not offered in :mod:`olsbayes.imaging` (:data:`WITHDRAWN`): where the readings
are precise, one flip moves the log posterior by ``i_max^2 |a_k|^2 / (2
sigma^2)`` -- thousands of nats at the Fig. 2 noise -- so every window update
keeps the pattern it has, chains stay where they start, and chains from
dispersed starts freeze in different patterns.  The exact sampler stays here for
experiments on noisy problems, where it matches enumeration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["BinaryGibbs", "two_level_gibbs", "credible_sets", "WITHDRAWN"]

#: Names no longer offered by :mod:`olsbayes.imaging`, and why (the measured split R-hat).
WITHDRAWN = {
    name: "the two-level block Gibbs sampler does not mix at sigma = 0.01 on the Fig. 2 "
          "problem: 4 chains from random bit patterns keep, after 300 sweeps, 41 % "
          "('grid' sensors) and 36 % ('linspace') of the 304 bits different (split R-hat inf) "
          "and chains from the MAP scene never leave it; the two-level posterior is "
          "reported by its MAP scene (image(prior=TwoLevel(...))); "
          "olsbayes.imaging.binary_gibbs keeps the sampler for experiments"
    for name in ("two_level_gibbs", "BinaryGibbs")
}

_MAX_WIDTH = 12


@dataclass(frozen=True)
class BinaryGibbs:
    """Draws of the two-level posterior.

    Attributes
    ----------
    bits : ndarray of bool, shape (C, S, K)
        Bit patterns (True = bright) of C chains, S kept sweeps each.
    log_posterior : ndarray, shape (C, S)
        L of each kept pattern (the module's L, constant dropped).
    best : ndarray of bool, shape (K,)
        Highest-L pattern visited (burn-in included).
    best_log_posterior : float
    """

    bits: np.ndarray
    log_posterior: np.ndarray
    best: np.ndarray
    best_log_posterior: float

    @property
    def p_bright(self) -> np.ndarray:
        """Posterior probability that each source is bright, shape (K,)."""
        return self.bits.reshape(-1, self.bits.shape[-1]).mean(axis=0)


def credible_sets(p_bright: np.ndarray, level: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
    """Smallest per-source credible sets of {dark, bright}: (contains 0, contains 1).

    The more probable value is always in the set; the other joins it when the
    more probable one alone has probability < level.
    """
    p = np.asarray(p_bright, dtype=float)
    both = np.maximum(p, 1.0 - p) < level
    return (p <= 0.5) | both, (p > 0.5) | both


def _log_post(bits, r, sigma, logit_p, log_1mp):
    n_on = bits.sum(axis=-1)
    k = bits.shape[-1]
    return -0.5 * np.sum(r**2, axis=-1) / sigma**2 + n_on * logit_p + k * log_1mp


def two_level_gibbs(
    a: np.ndarray,
    y: np.ndarray,
    sigma: float,
    i_max: float,
    s0: np.ndarray,
    groups: np.ndarray,
    n_samples: int,
    *,
    rng: np.random.Generator,
    p_bright: float = 0.5,
    n_burn: int = 100,
) -> BinaryGibbs:
    """Exact block-Gibbs sampler of the two-level posterior.

    Parameters
    ----------
    a : ndarray, shape (N, K)
    y : ndarray, shape (N,)
    sigma, i_max : float
    s0 : array_like of bool, shape (C, K)
        Starting bit patterns of C chains (e.g. the MAP scene / i_max).
    groups : ndarray of int, shape (G, w)
        Windows (e.g. :func:`olsbayes.imaging.core.neighbour_groups`); w <= 12;
        duplicate windows are used once.  Windows of one source are single-site Gibbs.
    n_samples, n_burn : int
        Kept and discarded sweeps (each sweep updates every window once, random order).
    rng : Generator
    p_bright : float in (0, 1)

    Returns
    -------
    BinaryGibbs
    """
    groups = np.unique(np.sort(np.asarray(groups, dtype=int), axis=1), axis=0)
    w = groups.shape[1]
    if not 1 <= w <= _MAX_WIDTH:
        raise InputError(f"groups must have 1 to {_MAX_WIDTH} columns; got {w}")
    bits = np.array(s0, dtype=bool)
    c, k = bits.shape
    pats = ((np.arange(2**w)[:, None] >> np.arange(w)) & 1).astype(float)  # (2^w, w)
    logit_p, log_1mp = np.log(p_bright / (1 - p_bright)), np.log1p(-p_bright)
    gram = np.einsum("nbi,nbj->bij", a[:, groups], a[:, groups])  # (G, w, w)
    quad = np.einsum("si,bij,sj->bs", pats, gram, pats)  # t^T G t per window, (G, 2^w)
    prior = pats.sum(axis=1) * logit_p
    r = y - i_max * bits @ a.T
    out = np.empty((c, n_samples, k), dtype=bool)
    lp_out = np.empty((c, n_samples))
    lp = _log_post(bits, r, sigma, logit_p, log_1mp)
    best_lp, best = lp.max(), bits[np.argmax(lp)].copy()
    inv2s2 = 0.5 / sigma**2
    for sweep in range(n_burn + n_samples):
        for g in rng.permutation(groups.shape[0]):
            idx = groups[g]
            ab = a[:, idx]
            b = bits[:, idx].astype(float)  # (C, w)
            cvec = r @ ab  # (C, w)
            gb = b @ gram[g]  # (C, w)
            logw = (2.0 * i_max * (pats @ (cvec + i_max * gb).T)
                    - i_max**2 * quad[g][:, None]) * inv2s2 + prior[:, None]  # (2^w, C)
            logw -= logw.max(axis=0)
            cdf = np.cumsum(np.exp(logw), axis=0)
            u = rng.random(c) * cdf[-1]
            pick = np.minimum(np.sum(cdf < u, axis=0), 2**w - 1)
            new = pats[pick]  # (C, w)
            r -= i_max * (new - b) @ ab.T
            bits[:, idx] = new > 0.5
        r = y - i_max * bits @ a.T  # refresh against round-off drift
        lp = _log_post(bits, r, sigma, logit_p, log_1mp)
        if lp.max() > best_lp:
            best_lp, best = lp.max(), bits[np.argmax(lp)].copy()
        if sweep >= n_burn:
            out[:, sweep - n_burn] = bits
            lp_out[:, sweep - n_burn] = lp
    return BinaryGibbs(out, lp_out, best, float(best_lp))
