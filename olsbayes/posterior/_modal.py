"""The multimodal run: one ensemble per mode, evidence weights, one pooled result.

The method is described in :mod:`olsbayes.posterior.multimodal`; this module
runs it and decides when the automatic choice uses it.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import InputError
from ..ml import MLResult
from ._assemble import MAX_STORED_DRAWS, _kept_steps, assemble
from ._logpost import LogPosterior, cut_shift
from ._run import make_sampler, posterior_bar, run_ensemble
from ._start import start_coordinates
from .modes import ModeReport, find_modes
from .multimodal import (
    PooledChain,
    mode_evidence,
    mode_walkers,
    nearest_mode,
    pool_labels,
    trigger_reason,
)

__all__ = ["check_multimodal_start", "mode_plan", "sample_modes"]


def check_multimodal_start(options, start: object) -> None:
    """``multimodal=True`` needs a start point (None, an MLResult or a point)."""
    if options.multimodal and (isinstance(start, str) or (isinstance(start, np.ndarray)
                                                          and start.ndim == 2)):
        raise InputError("start: the multimodal sampler (options.multimodal=True) starts from "
                         "the ML point or a given point; got 'prior' or a walker ensemble")


def mode_plan(model, data: np.ndarray, prior, start: object, options
              ) -> tuple[np.ndarray, np.ndarray, str] | None:
    """The modes (M, P_model), their log posteriors (M,) and the reason; None: one mode.

    ``options.multimodal``: False never; True always (also with one mode); None
    when :func:`~.multimodal.trigger_reason` names a reason and the search finds
    more than one mode.  Only a start point (an MLResult or a point) is searched.
    """
    if options.multimodal is False:
        return None
    p_model = model.n_params(prior.n_sources)
    if isinstance(start, MLResult):
        centre, gap = np.asarray(start.params, dtype=float), float(start.rival_gap)
    elif isinstance(start, np.ndarray) and start.ndim == 1:
        centre, gap = start[:p_model].copy(), np.nan
    else:
        return None
    reason = "requested" if options.multimodal else trigger_reason(
        model, centre, gap, options.modes)
    if not reason:
        return None
    modes, lp = find_modes(model, data, prior, centre, options.modes)
    if modes.shape[0] < 2 and not options.multimodal:
        return None
    return modes, lp, reason


def _run_modes(logpost: LogPosterior, walkers: list[np.ndarray], options, gen,
               progress: bool) -> tuple[list, bool]:
    """Each mode's ensemble, run to the options' criteria: (samplers, all converged)."""
    samplers, converged = [], True
    for w in walkers:
        sampler = make_sampler(logpost, w.shape[0], options, gen)
        with posterior_bar(progress, options) as bar:
            ok = run_ensemble(sampler, start_coordinates(logpost, w), logpost, options, bar)
        if options.n_steps is not None:
            tau = np.max(sampler.get_autocorr_time(tol=0))
            ok = bool(options.n_steps >= options.tau_multiple * tau)
        converged = converged and ok
        samplers.append(sampler)
    return samplers, converged


def _kept(sampler, tau: np.ndarray, options) -> tuple[np.ndarray, np.ndarray]:
    """A run's kept draws (n, P) in sampler coordinates and their log densities (n,)."""
    keep = _kept_steps(tau, sampler.iteration, options)[0]
    z = sampler.get_chain()[keep]
    p = z.shape[-1]
    return z.reshape(-1, p), sampler.get_log_prob()[keep].reshape(-1)


def _pool(samplers: list, logpost: LogPosterior, modes: np.ndarray, options, gen
          ) -> tuple[PooledChain, np.ndarray]:
    """Pooled draws (:mod:`~.multimodal`): each cell's draws from its own mode's run.

    Returns the pooled chain and the rows (M, 4): log Z, its se, the share of the
    run that stayed in its cell, the cell's weight.
    """
    prior = logpost.prior
    model = logpost.model
    kept, rows = [], []
    taus = np.array([np.asarray(s.get_autocorr_time(tol=0), dtype=float) for s in samplers])
    for m, sampler in enumerate(samplers):
        z, lp = _kept(sampler, taus[m], options)
        cell = nearest_mode(model, prior, logpost.to_params(z), modes) == m
        log_z, se = mode_evidence(logpost, z, options.modes.evidence_draws, gen)
        kept.append((z[cell], lp[cell]))
        rows.append([log_z, se, cell.mean(), 0.0])
    rows = np.array(rows)
    with np.errstate(divide="ignore"):
        log_w = rows[:, 0] + np.log(rows[:, 2])
    if not np.any(np.isfinite(log_w)):  # no run stayed in its own cell: evidences alone
        log_w = rows[:, 0]
    rows[:, 3] = np.exp(log_w - np.max(log_w))
    rows[:, 3] /= rows[:, 3].sum()
    n_walkers = samplers[0].get_chain().shape[1]
    n_draws = min(max(len(z) for z, _ in kept) // n_walkers + 1, MAX_STORED_DRAWS)
    label = pool_labels(rows[:, 3], n_draws, n_walkers, gen)
    chain = np.empty((n_draws, n_walkers, prior.n_params))
    log_prob = np.empty((n_draws, n_walkers))
    for m, (z, lp) in enumerate(kept):
        sel = label == m
        pick = ((np.arange(sel.sum()) + 0.5) * len(z) / max(sel.sum(), 1)).astype(int)
        chain[sel], log_prob[sel] = z[pick], lp[pick]
    tau = np.max(taus, axis=0)
    acc = np.array([s.acceptance_fraction for s in samplers])  # (M, W)
    main = np.array([np.bincount(label[:, j], minlength=len(samplers)).argmax()
                     for j in range(n_walkers)])
    return PooledChain(chain, log_prob, tau, acc[main, np.arange(n_walkers)]), rows


def sample_modes(model, data: np.ndarray, prior, plan: tuple, centre: np.ndarray,
                 n_walkers: int, options, gens: tuple, record: dict, progress: bool
                 ) -> tuple[dict, bool, int]:
    """Run the multimodal sampler: (result fields with ``modes``, converged, calls).

    ``gens`` = (ball, mc, prior) generators; ``centre`` (P,) labels the result.
    """
    gen_ball, gen_mc, gen_prior = gens
    modes, lp, reason = plan
    walkers = [mode_walkers(model, data, prior, x, n_walkers, gen_ball) for x in modes]
    logpost = LogPosterior(model, data, prior, cut_shift(prior, np.concatenate(walkers)),
                           options.use_likelihood)
    samplers, converged = _run_modes(logpost, walkers, options, gen_mc, progress)
    pooled, rows = _pool(samplers, logpost, modes, options, gen_mc)
    flat = dataclasses.replace(options, n_burn=0, thin=1)
    fields = assemble(model, data, logpost, pooled, centre, flat, gen_prior, record)
    fields["modes"] = ModeReport(params=modes, log_posterior=lp, log_evidence=rows[:, 0],
                                 evidence_se=rows[:, 1], stayed=rows[:, 2], weight=rows[:, 3],
                                 reason=reason)
    return fields, converged, logpost.n_calls
