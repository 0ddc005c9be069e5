"""Chains of the box priors: Gibbs sweeps, block HMC and the convergence-driven run length.

:func:`box_gibbs` runs C chains of the Gibbs sampler of
:mod:`olsbayes.imaging.sparse` (single-site, neighbour-pair and window moves)
for the flat prior on ``0 <= I <= i_max``.  The first half of the burn-in is a
pilot: the intensities whose pooled pilot sd exceeds ``block`` form the loose
block, which from then on gets one exact-HMC move per sweep
(:mod:`olsbayes.imaging.block`) -- the moves that cross the wide, non-local
directions single-site moves random-walk along.  The block is fixed before
the first kept draw, so the kept chains run one fixed, exact kernel.

With a fixed ``n_samples`` exactly that many draws per chain are kept.
Without one the chains keep sampling in blocks -- 100 draws, then growing by
half each time -- until every intensity has rank-normalised split R-hat
``<= rhat_max`` and bulk and tail ESS ``>= ess_min`` (Vehtari et al. 2021;
ArviZ's values, from :mod:`olsbayes._mcmc_diagnostics`), or until
``max_samples`` draws per chain; the result says which
(:attr:`BoxRun.converged`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from .._mcmc_diagnostics import ess_bulk, ess_tail, rank_rhat
from ..errors import InputError
from .block import block_move, block_step, loose_block
from .sparse import SweepMoves, gibbs_intensities

__all__ = ["BoxRun", "ConvergenceRule", "RunLength", "box_gibbs", "chain_diagnostics"]

_FIRST = 100  # kept draws per chain before the first convergence check
_GROWTH = 1.5  # each further block makes the run this much longer


@dataclass(frozen=True)
class ConvergenceRule:
    """When the convergence-driven run stops.

    Attributes
    ----------
    rhat_max : float
        Largest rank-normalised split R-hat allowed (> 1).
    ess_min : float
        Smallest bulk and tail ESS required, every intensity (> 0).
    max_samples : int
        Cap on kept draws per chain.
    """

    rhat_max: float
    ess_min: float
    max_samples: int


@dataclass(frozen=True)
class RunLength:
    """How long the chains of :func:`box_gibbs` run.

    Attributes
    ----------
    n_burn : int
        Discarded sweeps; their first half is the pilot that picks the block.
    n_samples : int or None
        Kept draws per chain; None: the convergence-driven run of ``rule``.
    rule : ConvergenceRule or None
        When the convergence-driven run stops; needed when ``n_samples`` is None.
    """

    n_burn: int
    n_samples: int | None = None
    rule: ConvergenceRule | None = None


@dataclass(frozen=True)
class BoxRun:
    """Draws of :func:`box_gibbs` and how they were made.

    Attributes
    ----------
    samples : ndarray, shape (C, S, K)
    block : ndarray of int, shape (L,)
        Intensities moved jointly by exact HMC (empty: none loose).
    acceptance : float
        Accepted share of the block moves (1.0 without a block).
    diagnostics : dict or None
        Of the convergence-driven run: ``rhat``, ``ess_bulk``, ``ess_tail``
        (worst intensity) and ``converged``; None for a fixed ``n_samples``.
    """

    samples: np.ndarray
    block: np.ndarray
    acceptance: float
    diagnostics: dict | None = None

    @property
    def converged(self) -> bool | None:
        """Whether the convergence-driven run met its rule (None: fixed run)."""
        return None if self.diagnostics is None else bool(self.diagnostics["converged"])


def chain_diagnostics(draws: np.ndarray) -> dict:
    """Worst rank-normalised split R-hat and smallest bulk / tail ESS of (C, S, K) draws.

    ArviZ's values to rounding (:mod:`olsbayes._mcmc_diagnostics`, every intensity
    at once).  Intensities constant in every chain (no spread to measure) are
    left out of the R-hat.
    """
    draws = np.asarray(draws, dtype=float)

    def worst(v, pick):
        v = v[np.isfinite(v)]
        return float(pick(v)) if v.size else float("nan")

    return {"rhat": worst(rank_rhat(draws), np.max), "ess_bulk": worst(ess_bulk(draws), np.min),
            "ess_tail": worst(ess_tail(draws), np.min)}


def _met(diag: dict, rule: ConvergenceRule) -> bool:
    return bool(diag["rhat"] <= rule.rhat_max and diag["ess_bulk"] >= rule.ess_min
                and diag["ess_tail"] >= rule.ess_min)


def box_gibbs(
    a: np.ndarray, y: np.ndarray, sigma: float, i_max: float, x0: np.ndarray, *,
    rng: np.random.Generator, length: RunLength, moves: SweepMoves, block: float,
    scale: float, bar: Any = None,
) -> BoxRun:
    """Chains of the box prior (flat on ``[0, i_max]``) started at ``x0`` (C, K).

    Parameters
    ----------
    a, y, sigma, i_max
        Design (N, K), readings (N,), noise sd, upper bound (may be inf).
    rng : Generator
    length : RunLength
        Burn-in, and kept draws or the convergence rule.
    moves : SweepMoves
        The Gibbs sampler's pair and window moves
        (:func:`~olsbayes.imaging.sparse.gibbs_intensities`); the block move is
        this function's own ``after_sweep``.
    block : float
        Pilot-sd threshold of the loose block (intensity units); 0: no block.
    scale : float
        Intensity scale of the posterior (the block surrogate's size): the
        prior's scale, or the mode's largest intensity under a bound derived
        from the readings.
    bar : progress bar, optional
        Its ``update()`` is called after every sweep and its ``set_postfix_str``
        with a one-line status after every convergence check (a tqdm bar).
    """
    if moves.after_sweep is not None:
        raise InputError("moves.after_sweep: box_gibbs makes its own block moves; got "
                         f"{moves.after_sweep!r}")
    n_samples, n_burn = length.n_samples, length.n_burn
    step = None if bar is None else bar.update
    pilot = n_burn // 2 if block > 0 and n_burn >= 4 else 0  # too short a pilot: no block
    x = np.asarray(x0, dtype=float)
    idx = np.zeros(0, dtype=int)
    hook, tally = None, [0, 0]
    if pilot:
        draws = gibbs_intensities(a, y, sigma, i_max, x, pilot, rng=rng, n_burn=0, moves=moves,
                                  step=step).samples
        x = draws[:, -1]
        idx = loose_block(draws, block)
    if idx.size:
        move = block_move(a, y, sigma, idx, scale)

        def hook(state):
            acc, _ = block_step(state, move, i_max, rng=rng)
            tally[0] += acc
            tally[1] += state.shape[0]

    def run(start, n, burn):
        return gibbs_intensities(a, y, sigma, i_max, start, n, rng=rng, n_burn=burn,
                                 moves=replace(moves, after_sweep=hook), step=step).samples

    if n_samples is not None:
        samples, diag = run(x, n_samples, n_burn - pilot), None
    else:
        first = run(x, min(_FIRST, length.rule.max_samples), n_burn - pilot)
        samples, diag = _until_converged(first, lambda s, n: run(s, n, 0), length.rule, bar)
    acc = tally[0] / tally[1] if tally[1] else 1.0
    return BoxRun(samples, idx, acc, diag)


def _until_converged(first: np.ndarray, more: Callable[[np.ndarray, int], np.ndarray],
                     rule: ConvergenceRule, bar: Any) -> tuple[np.ndarray, dict]:
    """Extend the (C, S, K) draws ``first`` by ``more(last, n)`` until ``rule`` holds.

    The run grows by half each time, up to ``rule.max_samples`` draws per chain;
    returns every draw and the last check's diagnostics.
    """
    parts = [first]
    while True:
        done = sum(p.shape[1] for p in parts)
        diag = chain_diagnostics(np.concatenate(parts, axis=1))
        diag["converged"] = _met(diag, rule)
        if bar is not None:
            bar.set_postfix_str(f"{done} draws/chain, R-hat {diag['rhat']:.3f}, ESS bulk "
                                f"{diag['ess_bulk']:.0f} tail {diag['ess_tail']:.0f} (target "
                                f"<= {rule.rhat_max:g}, >= {rule.ess_min:g})")
        if diag["converged"] or done >= rule.max_samples:
            break
        n = min(int(np.ceil(done * (_GROWTH - 1))), rule.max_samples - done)
        parts.append(more(parts[-1][:, -1], n))
    return (np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]), diag
