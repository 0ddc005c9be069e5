"""Choosing the number of sources K: evidences, the posterior over K, escalation.

:func:`select_k` returns a :class:`SelectionResult` (log Z_K +- error per K,
p(K | data), the chosen K, per-K ML fits and diagnostics, which K were sent to
quadrature or nested sampling and why, ``table()``).

Estimators
    * K = 0 (noise only): closed form, :func:`noise_log_evidence`.
    * Laplace at the ML point (:func:`model_laplace`): Fisher matrix, prior
      density, log K! for the K! labelled copies of each mode of exchangeable
      sources (ScenePrior is the unordered prior on the full space; nested
      sampling integrates the same space, so the two estimate the same Z_K),
      the Gaussian mass left inside the prior box (intensities >= 0), and an
      angle volume capped at the whole circle.  Exact on linear-Gaussian
      problems (:func:`linear_gaussian_log_evidence`).
    * dynesty nested sampling (:func:`nested_log_evidence`): ``rslice``,
      periodic angles, seeded Generator, always capped by ``maxcall``;
      :func:`repeated_log_evidence` combines independent runs with an error
      that includes their scatter (what ``select_k`` uses), under a call cap
      scaled with the problem (:func:`scaled_maxcall`).
    * mixture importance sampling over the source locations, intensities
      integrated analytically (:func:`mixture_log_evidence`): replaces every
      untrusted or undefined Laplace value (intensity at its bound 0 with a free
      location, singular Fisher matrix, weak or close sources), checked against
      the exact grid evidence of 1-2 ring sources.
    * quadrature for K <= 2 ring sources with uniform directions and
      Uniform(lo, hi) intensities, sigma known (:func:`ring_log_evidence`):
      intensities integrated exactly (normal / bivariate-normal box
      probabilities), directions on a screened grid with stratified draws and a
      stated error; what ``auto`` uses for such a K in doubt.
    * one-mode importance sampling (:func:`importance_log_evidence`): a precise
      reference for the Laplace value where the modes are apart.
    * BIC / AIC pseudo-evidences, and PSIS-LOO over sub-sensors
      (:func:`loo_compare`) as a predictive cross-check.

Decision (:mod:`olsbayes.select.decide`)
    ``auto`` computes Laplace for every K, then the quadrature (K <= 2 on a
    ring, where it applies) or nested sampling only for the K in doubt (at most
    ``max_escalations``): Laplace untrusted (singular or ill-conditioned Fisher
    matrix, sources < 2 sensor spacings apart, weak sources, ML not converged)
    within ``decisive`` nats of the best, trusted values near the decision
    boundary, or a neighbour of the best K without a Laplace value -- but not a
    K above the best whose ML fit gains < ``min_gain`` nats (an extra source
    that fits noise; nor the best K for its comparison with such a K), nor one
    whose likelihood maximum, an upper bound on its evidence, already loses
    decisively. The chosen K is the smallest within ``tie`` nats of the most
    probable: on this sensor an over-complete model is never decisively worse (a
    source split in two within one sensor spacing predicts exactly the same
    readings), so "more sources" must be earned.

Settings (:mod:`olsbayes.select.options`)
    ``select_k(..., options=SelectOptions(laplace=LaplaceOptions(...),
    nested=NestedOptions(...), decision=DecisionOptions(...), ml_method="fast"))``;
    every record is checked when it is built.
"""

from ..resolution import sensor_spacing
from .criteria import LOOResult, aic, bic, loo_compare
from .diagnostics import (
    THRESHOLDS,
    check_thresholds,
    closest_pair,
    laplace_trust,
)
from .importance import importance_log_evidence
from .laplace import (
    laplace_log_evidence,
    linear_gaussian_log_evidence,
    model_laplace,
    noise_log_evidence,
)
from .mixture import MixtureEvidence, mixture_log_evidence
from .nested import NestedEvidence, nested_log_evidence
from .nested_error import RepeatedEvidence, repeated_log_evidence, scaled_maxcall
from .options import DecisionOptions, LaplaceOptions, NestedOptions, SelectOptions
from .quadrature import QuadratureEvidence, ring_log_evidence
from .result import KEvidence, SelectionResult
from .select import METHODS, select_k
from .structure import (
    StructureOptions,
    StructureSelection,
    select_structure,
    structure_candidates,
)

__all__ = [
    "select_k",
    "select_structure",
    "StructureSelection",
    "StructureOptions",
    "structure_candidates",
    "SelectOptions",
    "LaplaceOptions",
    "NestedOptions",
    "DecisionOptions",
    "SelectionResult",
    "KEvidence",
    "METHODS",
    "noise_log_evidence",
    "laplace_log_evidence",
    "linear_gaussian_log_evidence",
    "model_laplace",
    "nested_log_evidence",
    "importance_log_evidence",
    "mixture_log_evidence",
    "MixtureEvidence",
    "ring_log_evidence",
    "QuadratureEvidence",
    "NestedEvidence",
    "repeated_log_evidence",
    "RepeatedEvidence",
    "scaled_maxcall",
    "laplace_trust",
    "sensor_spacing",
    "closest_pair",
    "THRESHOLDS",
    "check_thresholds",
    "bic",
    "aic",
    "loo_compare",
    "LOOResult",
]
