"""Modes of a posterior: a deterministic search around the ML point, and its settings.

An emcee ensemble started in one mode reports that mode as the posterior: its
walkers never cross the valleys of a multimodal likelihood.  Where such valleys
are expected, :func:`find_modes` looks for the other optima before sampling.
Candidate starts, each refined by the bounded Levenberg--Marquardt fit of
:mod:`olsbayes.ml.lm`:

* the ML point itself;
* for every set of near-antipodal pairs of ring sources, the scene with those
  pairs mirrored (:func:`olsbayes.antipodal.mirror_pair`; 2 optima per pair);
* every source moved by one sensor spacing either way (the neighbouring linear
  cell of the clipped cosine) and to its antipode.

The search is repeated from every new optimum (``ModeOptions.rounds``).  Optima
are kept when their log posterior is within ``log_range`` of the best and they
are *distinct*: some location differs by more than
:data:`olsbayes.ml.rivals.DISTINCT_STD` Fisher standard deviations from every
kept optimum after matching sources.  Every kept optimum has its sources
permuted to match the ML point's (the labels of the result).

The sampler of :mod:`olsbayes.posterior.multimodal` then samples every mode and
weighs it by its evidence.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from .._store import storable
from .._validation import flag, integer, positive_float
from ..antipodal import ANTIPODAL_SPACINGS, antipodal_pairs, mirror_pair
from ..errors import InputError

__all__ = ["ModeOptions", "ModeReport", "find_modes", "mode_candidates"]


@dataclass(frozen=True)
class ModeOptions:
    """How the multimodal sampler looks for modes and moves between them.

    Attributes
    ----------
    antipodal_spacings : float
        Ring source pairs within this many sensor spacings of antipodal are
        mirrored in the search, and make the automatic choice look for modes (> 0).
    log_range : float
        Keep optima whose log posterior is within this of the best (> 0, nats);
        a mode this far down carries a weight below ``exp(-log_range)``.
    max_modes : int
        At most this many modes, the most probable first (>= 1).
    rounds : int
        Search rounds; round r starts from the optima new in round r - 1 (>= 1).
    shifts : bool
        Also start from every source moved by one sensor spacing either way and
        to its antipode (on rings; on other arrays by the mean sensor spacing).
    evidence_draws : int
        Importance-sampling draws per mode for its evidence (>= 100).
    condition_max : float
        A Fisher matrix at the ML point whose (equilibrated) condition number
        exceeds this counts as near-singular (> 1).
    crlb_alarm : bool
        Under the automatic choice, rerun with the multimodal sampler when the
        default run's posterior sd is far below the CRLB at high SNR
        (:func:`~olsbayes.posterior.audit.narrower_than_crlb`) and the search
        finds several modes.
    on_rival, on_singular : bool
        Under the automatic choice, also look for modes when the ML search found
        a rival optimum within 3 nats (``on_rival``), or when the Fisher matrix
        at the ML point is near-singular (``on_singular``).  Off by default:
        near the resolution limit such scenes have flat valleys rather than
        separated modes, and the search returns points along a valley that the
        per-mode ensembles cannot keep apart (not calibrated there, and one
        ensemble per point).  Near-antipodal pairs trigger the search unless
        two sources of the ML point are closer than the resolution limit
        (:data:`olsbayes.resolution.RESOLUTION_SPACINGS`: its configuration is
        not pinned) or a source of the pair is less than
        :data:`olsbayes.resolution.WEAK_SDS` Cramer-Rao sd above zero (the pair
        is an artefact of the ML point); the CRLB alarm always does.
    """

    antipodal_spacings: float = ANTIPODAL_SPACINGS
    log_range: float = 10.0
    max_modes: int = 8
    rounds: int = 2
    shifts: bool = True
    evidence_draws: int = 4000
    condition_max: float = 1e10
    crlb_alarm: bool = True
    on_rival: bool = False
    on_singular: bool = False

    def __post_init__(self) -> None:
        positive_float("antipodal_spacings", self.antipodal_spacings)
        positive_float("log_range", self.log_range)
        integer("max_modes", self.max_modes, low=1)
        integer("rounds", self.rounds, low=1)
        for name in ("shifts", "crlb_alarm", "on_rival", "on_singular"):
            object.__setattr__(self, name, flag(name, getattr(self, name)))
        integer("evidence_draws", self.evidence_draws, low=100)
        c = self.condition_max
        if not isinstance(c, (int, float, np.floating)) or isinstance(c, bool) or not c > 1:
            raise InputError(f"condition_max must be a number > 1; got {c!r}")


@storable
@dataclass(frozen=True, eq=False)
class ModeReport:
    """The modes a multimodal run found and sampled.

    Attributes
    ----------
    params : ndarray (M, P_model)
        The optima, sources matched to the result's labels.
    log_posterior : ndarray (M,)
        Log likelihood + log prior at each optimum (nats).
    log_evidence : ndarray (M,)
        log Z_m, the posterior mass of each mode before normalisation (nats).
    evidence_se : ndarray (M,)
        Standard errors of ``log_evidence`` (nats).
    stayed : ndarray (M,)
        Share of each mode's run that stayed in the mode's cell (nearer to it
        than to any other mode, in CRLB sd); below 1 when optima are joined.
    weight : ndarray (M,)
        ``Z_m stayed_m`` normalised: the posterior mass of each mode's cell, the
        share of the stored draws taken from it.
    reason : str
        Why the multimodal sampler ran (requested, rival optima, near-antipodal
        pair, near-singular Fisher matrix, CRLB alarm).
    """

    params: np.ndarray
    log_posterior: np.ndarray
    log_evidence: np.ndarray
    evidence_se: np.ndarray
    stayed: np.ndarray
    weight: np.ndarray
    reason: str

    @property
    def n_modes(self) -> int:
        """M, the number of modes."""
        return int(self.params.shape[0])

    def __repr__(self) -> str:
        w = np.array2string(np.asarray(self.weight), precision=3)
        return f"ModeReport(n_modes={self.n_modes}, weight={w}, reason={self.reason!r})"


def _spacing(model) -> float:
    """One sensor spacing (rad) on a ring; the mean angular spacing otherwise."""
    return 2.0 * np.pi / model.n_sensors if model.kind == "angle" else float(
        np.sqrt(4.0 * np.pi / model.n_sensors))


def mode_candidates(model, x: np.ndarray, options: ModeOptions) -> np.ndarray:
    """Starting points (C, P) of the search around one optimum ``x`` (P,)."""
    k = model.n_sources_of(x)
    w = model.n_loc + 1
    out = [x]
    pairs = [(i, j) for i, j, _ in antipodal_pairs(model, x, within=options.antipodal_spacings)]
    for r in range(1, min(len(pairs), 4) + 1):
        for subset in itertools.combinations(pairs[:4], r):
            used = [s for p in subset for s in p]
            if len(set(used)) < len(used):
                continue
            y = x
            for i, j in subset:
                y = mirror_pair(y, i, j, w)
            out.append(y)
    if options.shifts and model.kind == "angle":
        step = _spacing(model)
        for s, d in itertools.product(range(k), (-step, step, np.pi)):
            y = np.array(x, dtype=float)
            y[s * w] = (y[s * w] + d + np.pi) % (2 * np.pi) - np.pi
            out.append(y)
    return np.array(out)


def _refine(model, data: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Local optima (C, P) from ``starts`` (C, P), canonical order."""
    from ..ml.lm import refine_batch
    from ..sensitivity import is_clipped_cosine

    kinks = model.kind == "angle" and is_clipped_cosine(model.sensitivity)
    out = refine_batch(model, np.repeat(data[None, :], starts.shape[0], axis=0), starts,
                       kinks=kinks)
    return model.canonical(out.x)


def _distinct(model, x: np.ndarray, kept: list[np.ndarray], std: np.ndarray) -> bool:
    """Whether optimum ``x`` differs from every kept one beyond DISTINCT_STD std."""
    from ..exchange import estimation_errors
    from ..ml.rivals import DISTINCT_STD

    if not kept:
        return True
    w = model.n_loc + 1
    loc = np.ones(x.size, dtype=bool)
    loc[w - 1 :: w] = False
    err = estimation_errors(model, x[None, :], np.array(kept))  # (M, P)
    return bool(np.all(np.any(np.abs(err[:, loc]) > DISTINCT_STD * std[loc], axis=-1)))


def find_modes(model, data: np.ndarray, prior, centre: np.ndarray, options: ModeOptions
               ) -> tuple[np.ndarray, np.ndarray]:
    """Distinct optima (M, P) around ``centre`` and their log posteriors (M,), best first.

    ``centre`` (P,) is the ML point in model parameters (no noise sigma); the
    optima have their sources matched to it.  Deterministic (no randomness).
    When no optimum lies inside the prior's support (e.g. a merged pair brighter
    than the intensity bound) the centre alone is returned, one mode.
    """
    from ..bounds import bound_covariance
    from ..exchange import match_sources

    cov = bound_covariance(model.fisher(centre))[0]
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    std = np.where(np.isfinite(std) & (std > 0), std, np.inf)
    kept: list[np.ndarray] = []
    frontier = [np.asarray(centre, dtype=float)]  # refined in the first round (the ML
    for _ in range(options.rounds):               # point stays where it is)
        starts = np.concatenate([mode_candidates(model, x, options) for x in frontier])
        optima = _refine(model, data, starts)
        lp = _log_post(model, data, prior, optima)
        frontier = []
        for i in np.argsort(-lp):
            if np.isfinite(lp[i]) and _distinct(model, optima[i], kept, std):
                kept.append(optima[i])
                frontier.append(optima[i])
        if not frontier:
            break
    if not kept:  # no optimum inside the prior's support: the centre alone, one mode
        x = np.asarray(centre, dtype=float)[None, :]
        return x, _log_post(model, data, prior, x)
    x = match_sources(model, np.array(kept), centre)
    lp = _log_post(model, data, prior, x)
    keep = np.argsort(-lp)
    keep = keep[lp[keep] >= lp[keep[0]] - options.log_range][: options.max_modes]
    return x[keep], lp[keep]


def _log_post(model, data: np.ndarray, prior, x: np.ndarray) -> np.ndarray:
    """log L + log prior of optima x (M, P_model); -inf outside the prior (sigma at ML)."""
    full = x
    if prior.noise is not None:
        resid = data - model.response(x)
        sig = np.maximum(np.sqrt(np.mean(resid**2, axis=-1)), 1e-300)
        full = np.concatenate([x, sig[:, None]], axis=1)
        model_ll = np.array([model.with_sigma(s).log_likelihood(xi, data)
                             for xi, s in zip(x, sig, strict=True)])
    else:
        model_ll = model.log_likelihood(x, data)
    with np.errstate(divide="ignore"):
        return np.where(prior.contains(full), model_ll + prior.log_prob(full), -np.inf)
