"""Settings of :func:`olsbayes.select.select_k`: small frozen records, checked on construction.

* :class:`LaplaceOptions` -- when a Laplace evidence is trusted, and what replaces
  it where it is not (mixture importance sampling over the source locations);
* :class:`NestedOptions` -- every dynesty nested-sampling run;
* :class:`DecisionOptions` -- which K ``method="auto"`` escalates, and the choice of K;
* :class:`SelectOptions` -- the three above and the ML fits of every K.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from .._io import ensure_dir
from .._validation import choice, flag, integer, nonnegative_float, positive_float
from ..errors import InputError
from ..ml import METHODS as ML_METHODS
from .diagnostics import check_thresholds

__all__ = ["LaplaceOptions", "NestedOptions", "DecisionOptions", "SelectOptions"]


@dataclass(frozen=True)
class LaplaceOptions:
    """When the Laplace evidence is trusted, and its replacement where it is not.

    Attributes
    ----------
    thresholds : mapping
        Overrides of :data:`olsbayes.select.diagnostics.THRESHOLDS` (keys
        ``separation`` in sensor spacings, ``snr`` = intensity / its sd,
        ``correlation`` = largest |correlation| of the bound); unknown keys are
        refused.  Stored as the full, read-only set of thresholds in use.
    importance_draws : int
        Initial draws (0 or >= 100) of the mixture importance sampler
        (:func:`~olsbayes.select.mixture.mixture_log_evidence`) that replaces every
        untrusted or undefined Laplace value for K <= 5 (methods ``laplace`` and
        ``auto``): intensities at their bound 0, (nearly) free locations, singular
        Fisher matrices.  Doubled once if its error exceeds 0.2 nats.  0 restores
        the bare Laplace rule (an undefined Laplace value gets the rough
        prior-ridge fallback if its ML fit gains >= ``RIDGE_GAIN`` = 10 nats over
        every smaller K, else p = 0).
    """

    thresholds: Mapping[str, float] | None = field(default=None, hash=False)
    importance_draws: int = 500

    def __post_init__(self) -> None:
        th = MappingProxyType(check_thresholds(self.thresholds))
        object.__setattr__(self, "thresholds", th)
        n = integer("importance_draws", self.importance_draws, low=0)
        if 0 < n < 100:
            raise InputError(f"importance_draws must be 0 or >= 100; got {n}")
        object.__setattr__(self, "importance_draws", n)


@dataclass(frozen=True)
class NestedOptions:
    """Settings of every dynesty run (``method="nested"``, and the K ``auto`` escalates).

    Attributes
    ----------
    maxcall : int or None
        Cap on likelihood calls per run (>= 1000); a run stopped by it is
        flagged.  None (default): scaled with the parameters P and the live
        points (:func:`~olsbayes.select.nested_error.scaled_maxcall`), within
        the memory budget.
    n_live : int or None
        Live points of each run; None: ``max(100, 25 P)`` for P parameters.
        More than P of the largest K that may be sampled (checked by ``select_k``).
    dlogz : float
        Stopping tolerance on the remaining evidence (nats, > 0).
    n_runs : int
        Independent runs per K (>= 1), combined with an error that includes
        their scatter (:func:`~olsbayes.select.nested_error.combine_runs`);
        runs that disagree beyond their errors flag the value as untrusted.
    checkpoint_dir : path or None
        Folder where every nested run keeps its sampler (``nested-k<K>.pkl``,
        written every minute and at the end) and from which a run started again
        on the same readings, model and prior continues.  The files are pickles:
        resume only from folders you wrote.
    """

    maxcall: int | None = None
    n_live: int | None = None
    dlogz: float = 0.5
    n_runs: int = 3
    checkpoint_dir: str | os.PathLike | None = None

    def __post_init__(self) -> None:
        if self.checkpoint_dir is not None:
            if not isinstance(self.checkpoint_dir, (str, os.PathLike)):
                raise InputError(f"checkpoint_dir must be a folder path or None; "
                                 f"got {type(self.checkpoint_dir).__name__}")
            object.__setattr__(self, "checkpoint_dir",
                               ensure_dir(self.checkpoint_dir, "checkpoint_dir"))
        if self.maxcall is not None:
            object.__setattr__(self, "maxcall", integer("maxcall", self.maxcall, low=1000))
        object.__setattr__(self, "n_runs", integer("n_runs", self.n_runs, low=1))
        if self.n_live is not None:
            object.__setattr__(self, "n_live", integer("n_live", self.n_live, low=2))
        object.__setattr__(self, "dlogz", positive_float("dlogz", self.dlogz))


@dataclass(frozen=True)
class DecisionOptions:
    """Which K ``method="auto"`` escalates (quadrature or nested sampling), which K wins.

    Attributes
    ----------
    decisive : float
        Log odds (nats, > 0) beyond which a comparison is decisive; default log 100.
    tie : float
        Candidates within ``tie`` nats (>= 0) of the most probable K count as tied
        and the smallest of them is chosen; default log 3 (Jeffreys' "barely worth
        mentioning").  0 picks the most probable K.
    max_escalations : int
        At most this many K (>= 0) are sent to nested sampling by ``auto``.
    min_gain : float
        ``auto`` does not escalate a K above the most probable one whose ML
        log-likelihood exceeds that K's by less than this (nats, >= 0): on K = 1
        truths (ring N = 30) the gain of a second source is below 3 nats in 95 %
        of noise draws.
    recheck_decisive : bool
        ``auto`` also sends the most probable K to nested sampling when it leads every
        other K by twice ``decisive`` nats on an importance-sampling value (default
        False: by Markov's inequality the lead then stays decisive with probability
        >= 1 - e^-decisive, so nested sampling would change that K's log Z -- which
        importance sampling can put a few nats low near the resolution limit -- but
        not the choice of K).
    quadrature : bool
        ``auto`` computes the evidence of a K it escalates by quadrature instead of
        nested sampling where that is exact (default True): K <= 2 sources on a ring
        with Gaussian noise of known sd, uniform directions and intensities
        Uniform(lo, hi) (:mod:`olsbayes.select.quadrature`).  Where its grid would
        exceed its budget or its stated error exceeds
        :data:`~olsbayes.select.quadrature.MAX_ERROR` nats, nested sampling is used.
    """

    decisive: float = math.log(100.0)
    tie: float = math.log(3.0)
    max_escalations: int = 2
    min_gain: float = 3.0
    recheck_decisive: bool = False
    quadrature: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "decisive", positive_float("decisive", self.decisive))
        object.__setattr__(self, "tie", nonnegative_float("tie", self.tie))
        object.__setattr__(self, "max_escalations",
                           integer("max_escalations", self.max_escalations, low=0))
        object.__setattr__(self, "min_gain", nonnegative_float("min_gain", self.min_gain))
        for name in ("recheck_decisive", "quadrature"):
            object.__setattr__(self, name, flag(name, getattr(self, name)))


@dataclass(frozen=True)
class SelectOptions:
    """All settings of :func:`~olsbayes.select.select_k` beyond the priors and the method.

    Attributes
    ----------
    laplace : LaplaceOptions
    nested : NestedOptions
    decision : DecisionOptions
    ml_method : str
        ``method`` of :func:`olsbayes.ml.fit_ml` for the ML fit of every K.
    ml_options : object or None
        ``options`` of :func:`olsbayes.ml.fit_ml` (checked by it before any fit).
    """

    laplace: LaplaceOptions = field(default_factory=LaplaceOptions)
    nested: NestedOptions = field(default_factory=NestedOptions)
    decision: DecisionOptions = field(default_factory=DecisionOptions)
    ml_method: str = "fast"
    ml_options: object = None

    def __post_init__(self) -> None:
        for name, kind in (("laplace", LaplaceOptions), ("nested", NestedOptions),
                           ("decision", DecisionOptions)):
            if not isinstance(getattr(self, name), kind):
                raise InputError(f"{name} must be an olsbayes.select.{kind.__name__}; "
                                 f"got {type(getattr(self, name)).__name__}")
        choice("ml_method", self.ml_method, tuple(ML_METHODS))
