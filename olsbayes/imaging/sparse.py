"""Single-site Gibbs samplers for box and spike-and-slab intensity priors.

Model ``y = A I + e``, ``e ~ N(0, sigma^2 1)``.  Each intensity has the prior

* ``"bounded"`` (``spike=None``): uniform on [0, i_max] (i_max may be inf:
  the flat ``"nonnegative"`` prior);
* ``"sparse"`` (``spike=(a_w, b_w)``): ``(1 - w) delta_0 + w U(0, i_max)`` -- a dark
  pixel with probability 1 - w, otherwise any intensity up to i_max -- with a
  hyperprior ``w ~ Beta(a_w, b_w)`` so the data decide how sparse the scene is.

Given all other intensities, the likelihood of ``I_k`` is Gaussian with
precision ``|a_k|^2 / sigma^2`` and mean ``m_k = I_k + a_k . r / |a_k|^2``
(``r`` the residual), so ``(z_k, I_k)`` is drawn exactly from its conditional:
first the spike/slab indicator with the slab's truncated-Gaussian integral in
closed form, then ``I_k`` from a 1-D truncated normal.  All chains are updated
together (vectorised over chains); the residual is kept up to date in O(N).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .._validation import positive_pair
from ..errors import InputError
from .truncated import truncnorm_1d
from .window import WindowMoves, combine, coordinate_moves, window_sweep

__all__ = ["GibbsSamples", "SweepMoves", "gibbs_intensities", "log_ndtr_diff"]


@dataclass(frozen=True)
class GibbsSamples:
    """Draws of the single-site Gibbs sampler.

    Attributes
    ----------
    samples : ndarray, shape (n_chains, n_samples, K)
        Intensity draws.
    weight : ndarray, shape (n_chains, n_samples)
        Draws of the slab weight w (all ones without a spike).
    """

    samples: np.ndarray
    weight: np.ndarray


@dataclass(frozen=True)
class SweepMoves:
    """The moves of a Gibbs sweep besides the single-site draws.

    Attributes
    ----------
    pairs : ndarray of int, shape (P, 2), optional
        Source pairs (k, l) that also get an exact move along ``e_k - e_l`` each
        sweep -- neighbours whose difference the array barely sees, the slow
        directions of single-site Gibbs.  Only pairs with distinct columns.
    windows : WindowMoves, optional
        Exact moves along the slow eigen-directions of local windows of pixels
        (:mod:`olsbayes.imaging.window`), once each per sweep; box priors only.
        With them the single-site, pair and window moves of a sweep run together
        in compiled code, in one random order.
    after_sweep : callable, optional
        Called with the intensities ``x`` (C, K) after the moves of every sweep;
        it may move them in place by an exact move of its own (e.g.
        :func:`olsbayes.imaging.block.block_step`).  Box priors only.
    """

    pairs: np.ndarray | None = None
    windows: WindowMoves | None = None
    after_sweep: Callable[[np.ndarray], object] | None = None


def log_ndtr_diff(alpha: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """log(Phi(beta) - Phi(alpha)) for alpha <= beta, accurate in both tails."""
    from scipy.special import log_ndtr  # on use: scipy is slow to import
    upper = alpha > 0  # use Phi(beta) - Phi(alpha) = Phi(-alpha) - Phi(-beta)
    lo = np.where(upper, -beta, alpha)
    hi = np.where(upper, -alpha, beta)
    l_hi, l_lo = log_ndtr(hi), log_ndtr(lo)
    return l_hi + np.log1p(-np.exp(np.minimum(l_lo - l_hi, 0.0)))


def _site(x, r, k, a_k, norm2, sigma, i_max, log_w, log_1mw, spike, rng):
    """Exact draw of (z_k, I_k) given the rest, for every chain; updates x, r in place."""
    from scipy.special import expit  # on use: scipy is slow to import
    m = x[:, k] + (r @ a_k) / norm2
    s = sigma / np.sqrt(norm2)
    new = truncnorm_1d(m, s, 0.0, i_max, rng=rng)
    if spike:
        log_slab = (
            log_w - np.log(i_max) + np.log(s * np.sqrt(2 * np.pi))
            + log_ndtr_diff(-m / s, (i_max - m) / s) + 0.5 * (m / s) ** 2
        )  # relative to the spike's likelihood exp(-m^2 / (2 s^2))
        on = rng.random(m.shape) < expit(log_slab - log_1mw)
        new = np.where(on, new, 0.0)
    r -= np.outer(new - x[:, k], a_k)
    x[:, k] = new


def _pair(x, r, k, j, d_kl, norm2, sigma, i_max, spike, rng):
    """Exact moves trading intensity between sources k and j, for every chain.

    Both in the slab: a Gibbs draw along ``e_k - e_j``.  With the spike prior and
    exactly one of the two dark: a Metropolis swap of the two values (an
    involution that keeps the prior, accepted on the likelihood ratio).
    """
    t_lo = np.maximum(-x[:, k], x[:, j] - i_max)
    t_hi = np.minimum(i_max - x[:, k], x[:, j])
    rd = r @ d_kl
    t = truncnorm_1d(rd / norm2, sigma / np.sqrt(norm2), t_lo, t_hi, rng=rng)
    if spike:
        on_k, on_j = x[:, k] > 0, x[:, j] > 0
        swap = x[:, j] - x[:, k]
        log_acc = (swap * rd - 0.5 * swap**2 * norm2) / sigma**2
        ok = (on_k != on_j) & (np.log(rng.random(t.shape)) < log_acc)
        t = np.where(on_k & on_j, t, np.where(ok, swap, 0.0))
    r -= np.outer(t, d_kl)
    x[:, k] = np.clip(x[:, k] + t, 0.0, i_max)
    x[:, j] = np.clip(x[:, j] - t, 0.0, i_max)


def _pairs(pairs: object, k: int) -> np.ndarray:
    """``moves.pairs`` checked: integer indices of shape (P, 2) in [0, k)."""
    if pairs is None:
        return np.zeros((0, 2), dtype=int)
    arr = np.asarray(pairs)
    if arr.size == 0:
        return np.zeros((0, 2), dtype=int)
    if arr.ndim != 2 or arr.shape[1] != 2 or not np.issubdtype(arr.dtype, np.integer):
        raise InputError(f"moves.pairs must be integers of shape (P, 2); got dtype {arr.dtype} "
                         f"and shape {arr.shape}")
    if arr.min() < 0 or arr.max() >= k:
        raise InputError(f"moves.pairs must index the {k} intensities, in [0, {k - 1}]; got "
                         f"[{arr.min()}, {arr.max()}]")
    return arr.astype(int)


def gibbs_intensities(
    a: np.ndarray,
    y: np.ndarray,
    sigma: float,
    i_max: float,
    x0: np.ndarray,
    n_samples: int,
    *,
    rng: np.random.Generator,
    n_burn: int = 100,
    moves: SweepMoves | None = None,
    spike: tuple[float, float] | None = None,
    step: Callable[[], object] | None = None,
) -> GibbsSamples:
    """Run the single-site Gibbs sampler (random scan order per sweep).

    Parameters
    ----------
    a : ndarray, shape (N, K)
        Design matrix (no all-zero column).
    y : ndarray, shape (N,)
    sigma : float
    i_max : float
        Upper bound of the slab (inf for a flat nonnegative prior; then
        ``spike`` must be None).
    x0 : ndarray, shape (C, K)
        Starting intensities of C chains inside [0, i_max].
    n_samples, n_burn : int
        Kept and discarded sweeps per chain.
    moves : SweepMoves, optional
        Pair, window and extra moves of every sweep (default: none).
    spike : (float, float), optional
        The Beta hyperprior (a_w, b_w) of the slab weight w, adding the point
        mass at 0 with weight 1 - w (the ``"sparse"`` prior); None: the box prior.
    step : callable, optional
        Called after every sweep (a progress bar's ``update``).
    """
    moves = SweepMoves() if moves is None else moves
    windows, after_sweep = moves.windows, moves.after_sweep
    if spike is not None and windows is not None and windows.n_moves:
        raise InputError("moves.windows: window moves need the box prior (spike=None); got "
                         f"spike={spike!r}")
    if spike is not None and after_sweep is not None:
        raise InputError("moves.after_sweep: extra moves need the box prior (spike=None); got "
                         f"spike={spike!r}")
    x = np.array(x0, dtype=float)
    c, k = x.shape
    r = y - x @ a.T
    norm2 = np.einsum("nk,nk->k", a, a)
    cols = np.ascontiguousarray(a.T)
    # the slab weight's Beta hyperprior, or None for the box prior
    w_prior = None if spike is None else positive_pair("spike", spike)
    sparse = w_prior is not None
    w = np.full(c, 0.5) if sparse else np.ones(c)
    out = np.empty((c, n_samples, k))
    w_out = np.empty((c, n_samples))
    pairs = _pairs(moves.pairs, k)
    d_pairs = cols[pairs[:, 0]] - cols[pairs[:, 1]]
    n_pairs = np.einsum("pn,pn->p", d_pairs, d_pairs)
    compiled = None
    if windows is not None:  # box prior: every move of the sweep in the compiled kernel
        compiled = combine(coordinate_moves(a, pairs), windows)
    for sweep in range(n_burn + n_samples):
        log_w = np.log(w)
        log_1mw = np.log1p(-w) if sparse else None
        if compiled is not None:
            window_sweep(x, r, compiled, sigma, i_max, rng=rng)
        for j in rng.permutation(k) if compiled is None else ():
            _site(x, r, j, cols[j], norm2[j], sigma, i_max, log_w, log_1mw, sparse, rng)
        for p in rng.permutation(pairs.shape[0]) if compiled is None else ():
            if n_pairs[p] > 0:
                _pair(x, r, pairs[p, 0], pairs[p, 1], d_pairs[p], n_pairs[p], sigma, i_max,
                      sparse, rng)
        if after_sweep is not None:
            after_sweep(x)
        if sparse:
            n_on = np.count_nonzero(x, axis=1)
            w = rng.beta(w_prior[0] + n_on, w_prior[1] + k - n_on)
        r = y - x @ a.T  # refresh the residual against round-off drift
        kept = sweep - n_burn
        if kept >= 0:
            out[:, kept] = x
            w_out[:, kept] = w
        if step is not None:
            step()
    return GibbsSamples(out, w_out)
