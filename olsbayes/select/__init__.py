"""Choosing the number of sources K: evidences, the posterior over K, escalation.

:func:`select_k` returns a :class:`SelectionResult`.  Evidence estimators: the
closed form for K = 0 (:func:`noise_log_evidence`), the Laplace approximation
at the ML point (:func:`laplace_log_evidence`, :func:`model_laplace`, with the
K! factor of exchangeable sources), dynesty nested sampling
(:func:`nested_log_evidence`) and the information criteria BIC/AIC.
"""

from .criteria import LOOResult, aic, bic, loo_compare
from .diagnostics import THRESHOLDS, laplace_trust, min_separation, sensor_spacing
from .laplace import (
    laplace_log_evidence,
    linear_gaussian_log_evidence,
    model_laplace,
    noise_log_evidence,
)
from .nested import NestedEvidence, nested_log_evidence
from .result import KEvidence, SelectionResult
from .select import METHODS, select_k

__all__ = [
    "select_k",
    "SelectionResult",
    "KEvidence",
    "METHODS",
    "noise_log_evidence",
    "laplace_log_evidence",
    "linear_gaussian_log_evidence",
    "model_laplace",
    "nested_log_evidence",
    "NestedEvidence",
    "laplace_trust",
    "sensor_spacing",
    "min_separation",
    "THRESHOLDS",
    "bic",
    "aic",
    "loo_compare",
    "LOOResult",
]
