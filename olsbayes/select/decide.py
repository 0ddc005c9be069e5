"""The decisions of select_k: which K ``auto`` escalates, and which K wins.

``auto`` escalates (to quadrature or nested sampling) only the K in doubt (at most
``max_escalations``): a Laplace value that is untrusted, or trusted but near the
decision boundary of a comparison that is not decisive, or a neighbour of the most
probable K without a Laplace value -- never a K above the most probable one whose ML fit
gains less than ``min_gain`` nats (an extra source fitting noise), nor one whose
likelihood maximum, an upper bound on its evidence, already loses decisively, nor the
most probable K when it leads every other K by twice ``decisive`` nats on an
importance-sampling value (an unbiased estimate of Z: by Markov's inequality its lead is
still decisive with probability >= 1 - e^-decisive).

p(K | data) is proportional to Z_K p(K), and the chosen K is the *smallest* within
``tie`` nats of the most probable: on this sensor an over-complete model is never
decisively worse (a source split in two within one sensor spacing predicts exactly
the same readings), so "more sources" must be earned.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import EvidenceWarning
from .engine import KWork, mixture_doubt
from .options import DecisionOptions
from .result import KEvidence, SelectionResult

__all__ = ["next_escalation", "choose", "finish", "TRUSTED_MARGIN", "FINAL"]

#: Evidence methods whose value is final (never escalated again): exact to its stated error.
FINAL = ("nested", "quadrature")
#: Nats within which a trusted Laplace comparison counts as at the decision boundary.
TRUSTED_MARGIN = 1.0


def _noise_only(works: list[KWork], k: int, top: int, min_gain: float) -> bool:
    """K > top and its ML fit gains < min_gain nats of log L over K = top."""
    return k > top and works[k].log_likelihood - works[top].log_likelihood < min_gain


def _could_compete(work: KWork, log_pk: float, floor: float) -> bool:
    """Whether K's evidence can reach ``floor``.

    log Z_K <= max log L_K (the prior integrates to 1), so a K whose likelihood
    maximum plus log p(K) lies below the decisive floor of the most probable K loses
    whatever its evidence is.
    """
    return bool(work.log_likelihood + log_pk >= floor)


def _settled(works: list[KWork], score: np.ndarray, rivals: list[int], top: int,
             decision: DecisionOptions) -> bool:
    """Whether the most probable K's lead stands on its importance-sampling value.

    The most probable K got its evidence from importance sampling (an unbiased,
    non-negative estimate of Z) and leads every other K that is not only fitting
    noise by at least twice ``decisive`` nats.  By Markov's inequality such an
    estimate exceeds Z by a factor e^x with probability at most e^-x, so the true
    lead is still decisive with probability at least 1 - e^-decisive (0.99 at the
    default); the sampler's usual failure, missing posterior mass, errs low and
    only widens the lead.  Nested sampling could then change that K's log Z but
    not the choice of K; ``recheck_decisive`` sends it anyway.
    """
    if decision.recheck_decisive or works[top].method != "importance" or rivals != [top]:
        return False
    others = [score[k] for k in range(len(works))
              if k != top and not _noise_only(works, k, top, decision.min_gain)]
    lead = score[top] - max(others, default=-np.inf)
    return bool(lead >= 2.0 * decision.decisive)


def _doubtful(works: list[KWork], score: np.ndarray, rivals: list[int], top: int,
              decision: DecisionOptions) -> list[tuple[int, str]]:
    """Rivals whose value is untrusted or near the decision boundary, and why.

    Near: trusted but within ``TRUSTED_MARGIN`` of the decision boundary
    (log odds = +-tie) of a non-decisive comparison.  None when the lead is
    settled (:func:`_settled`).
    """
    out: list[tuple[int, str]] = []
    tie = decision.tie
    if _settled(works, score, rivals, top, decision):
        return out
    for k in rivals:
        w = works[k]
        if k == 0 or w.method in FINAL:
            continue
        why = list(w.reasons)
        if len(rivals) > 1:
            other = rivals[1] if k == top else top
            gap = score[k] - score[other]
            # a trusted Laplace value (error ~0.3 nats) matters only near the decision
            if why or abs(abs(gap) - tie) < TRUSTED_MARGIN:
                how = "importance sampling" if "importance" in (
                    w.method, works[other].method) else "Laplace"
                why.insert(0, f"not decisive against K={other} ({gap:+.2f} nats by {how})")
        if why:
            out.append((k, "; ".join(why)))
    return out


def next_escalation(works: list[KWork], log_pk: np.ndarray, decision: DecisionOptions,
                    done: set[int]) -> tuple[int, str] | None:
    """The most probable K still needing nested sampling, and why (None: none).

    Candidates: the K within ``decisive`` nats of the most probable one whose
    Laplace value is untrusted, or trusted but near the decision boundary, then a
    neighbour of the most probable K whose Laplace value does not exist, unless its
    likelihood maximum (an upper bound on Z_K) already loses decisively.  A K above
    the most probable one whose ML fit gains less than ``min_gain`` nats of
    log-likelihood over it is not sent: its extra source only fits noise; nor is the
    comparison with such a K a reason to send the most probable one (nested
    sampling of the latter would not sharpen the former, whose value comes from
    Laplace or from importance sampling over its free locations).
    """
    score = np.array([w.value for w in works]) + log_pk
    finite = np.isfinite(score)
    top = int(np.nanargmax(np.where(finite, score, -np.inf)))
    order = np.argsort(-np.where(finite, score, -np.inf), kind="stable")
    floor = score[top] - decision.decisive
    competing = [int(k) for k in order if finite[k] and score[k] >= floor]
    rivals = [k for k in competing if not _noise_only(works, k, top, decision.min_gain)]
    candidates = _doubtful(works, score, rivals, top, decision)
    for k in (top - 1, top + 1):  # a neighbour whose Laplace value does not exist
        if (0 < k < len(works) and not finite[k] and works[k].method not in FINAL
                and not _noise_only(works, k, top, decision.min_gain)
                and _could_compete(works[k], log_pk[k], floor)):
            candidates.append((k, "Laplace undefined: " + "; ".join(works[k].reasons)))
    for k, why in candidates:
        if k not in done:
            return k, why
    return None


def choose(score: np.ndarray, tie: float) -> tuple[int, list[str]]:
    """The smallest K within ``tie`` nats of the most probable (log posterior ``score`` per K).

    Also a note when that is not the most probable K.
    """
    top = int(np.argmax(score))
    near = np.flatnonzero(score >= score[top] - tie)
    best = int(near.min())
    notes = []
    if best != top:
        notes.append(
            f"K={best} chosen over the most probable K={top}: posterior log odds "
            f"{score[top] - score[best]:.2f} < tie={tie:.2f} nats, so the data do not "
            "support the extra source(s); the smaller scene is preferred"
        )
    return best, notes


def _notes(works: list[KWork], score: np.ndarray, best: int, method: str,
           decision: DecisionOptions) -> list[str]:
    """Per-K remarks: a noise-fitting K not escalated, no estimate, an untrusted value."""
    notes = []
    for w in works:
        gain = w.log_likelihood - works[best].log_likelihood
        noise_only = (method == "auto" and w.method in ("laplace", "importance")
                      and bool(w.reasons) and w.k > best and gain < decision.min_gain)
        if noise_only:
            low = ("; its p(K) rests on the untrusted Laplace value, which can be several "
                   "nats low for an over-complete K (a source split within one sensor spacing "
                   "predicts the same readings)") if np.isfinite(w.value) else ""
            if w.method == "importance" and np.isfinite(w.value):
                low = (f"; its p(K) rests on the importance-sampling evidence (+-{w.error:.2f} "
                       "nats), which integrates the free location of the extra source")
            notes.append(f"K={w.k}: not escalated, its ML fit gains only {gain:.2f} nats of "
                         f"log L over K={best} (< min_gain={decision.min_gain:g}): the extra "
                         f"source fits noise{low}")
        competing = score[w.k] >= score.max() - decision.decisive
        if not np.isfinite(w.value):
            notes.append(f"K={w.k}: no evidence estimate ({'; '.join(w.reasons)}); p(K) set to 0")
        elif w.method == "laplace" and w.reasons and competing:
            notes.append(f"K={w.k}: Laplace evidence not to be trusted ({'; '.join(w.reasons)})")
        elif w.method == "importance" and not noise_only and competing:
            notes.append(f"K={w.k}: Laplace evidence not to be trusted, importance sampling "
                         f"over the locations used instead ({w.value:.2f} +- {w.error:.2f} "
                         "nats)")
    return notes


def finish(works: list[KWork], log_pk: np.ndarray, method: str, escalated: dict[int, str],
           decision: DecisionOptions, seconds: float) -> SelectionResult:
    """p(K | data), the chosen K and its notes, as a :class:`SelectionResult`."""
    value = np.array([w.value for w in works])
    score = np.where(np.isfinite(value), value + log_pk, -np.inf)
    prob = np.exp(score - score.max())
    prob /= prob.sum()
    best, notes = choose(score, decision.tie)
    notes += _notes(works, score, best, method, decision)
    k_max = len(works) - 1
    if best == k_max >= 1:
        edge = (f"the chosen K = {best} is k_max: p(K) is cut at k_max and more sources "
                f"were not considered (posterior log odds of K={best} over K={best - 1}: "
                f"{score[best] - score[best - 1]:.1f} nats); rerun with a larger k_max")
        notes.insert(0, edge)
        warnings.warn(edge, EvidenceWarning, stacklevel=3)
    untrusted_best = (works[best].method == "laplace" and works[best].reasons) or (
        mixture_doubt(works[best]))
    if untrusted_best and method == "laplace":
        what = "an importance-sampling" if works[best].method == "importance" else "a Laplace"
        warnings.warn(f"the chosen K={best} rests on {what} evidence that is not to be "
                      f"trusted ({'; '.join(works[best].reasons)}); try method='auto'",
                      EvidenceWarning, stacklevel=3)
    evidences = tuple(
        KEvidence(
            k=w.k, log_evidence=float(w.value), error=float(w.error), method=w.method,
            log_likelihood=float(w.log_likelihood), n_params=int(w.params.size),
            params=w.params, laplace=float(w.laplace), trusted=not w.reasons,
            reasons=tuple(w.reasons), n_calls=int(w.n_calls), seconds=float(w.seconds),
            fit=w.fit, origin=w.origin, nested=w.nested,
        )
        for w in works
    )
    return SelectionResult(
        ks=np.arange(len(works)), log_evidence=value,
        error=np.array([w.error for w in works]), log_prior_k=log_pk, probabilities=prob,
        best=best, method=method, evidences=evidences, escalated=escalated,
        notes=tuple(notes), seconds=seconds,
    )
