"""Which nuisance structure a scene needs: candidate models compared by their evidence.

Each candidate is a :class:`~olsbayes.Model` of the same array -- e.g. without
and with an inferred background, gains fixed or free, Gaussian or Poisson
noise -- and its evidence is that of :func:`~olsbayes.select.select_k` summed
over the number of sources,

    Z_m = sum_K Z_{m,K} p(K),

with one intensity prior for every candidate (so the comparison is about the
structure, not the priors of the sources).  p(m | data) is proportional to
Z_m p(m) with equal prior odds; the chosen candidate is the *first* (list the
candidates from the simplest) within ``tie`` nats of the most probable: a term
is added only when the data earn it.

:func:`structure_candidates` builds the usual candidates from one model: every
combination of an inferred background and inferred gains (each with its prior),
optionally under a second noise model (e.g. Poisson counts besides a Gaussian of
unknown sigma); :attr:`StructureSelection.supported` names the terms of the
chosen one.

Comparing a Gaussian density with a Poisson probability treats each count as a
bin of unit width, which is accurate when the Gaussian is wide compared with one
count (many counts per sub-sensor).  When a Gaussian candidate is chosen over a
Poisson one on low counts (median non-zero count per frame below
:data:`LOW_COUNTS`) an :class:`~olsbayes.errors.EvidenceWarning` says that the
Gaussian approximation of the counts is poor there.
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from .._validation import as_rng, choice, nonnegative_float, positive_float
from ..errors import EvidenceWarning, InputError
from ..model import Model
from ..noise import NoiseModel
from ..nuisance import Nuisance
from ..priors import Prior
from .options import SelectOptions
from .result import SelectionResult

__all__ = ["StructureOptions", "StructureSelection", "select_structure", "structure_candidates"]

_METHODS = ("laplace", "auto", "nested")
#: Median non-zero count per frame below which a Gaussian model of counts is warned about.
LOW_COUNTS = 20.0


@dataclass(frozen=True)
class StructureOptions:
    """Settings of :func:`select_structure`.

    Attributes
    ----------
    tie : float
        Nats (>= 0) within which the first (simplest) candidate reaching the most
        probable is chosen; default log 3 (odds below 3 : 1 do not add a term).
    method : {"laplace", "auto", "nested"}
        The evidence of every (candidate, K), as in :func:`~olsbayes.select.select_k`.
    select : SelectOptions, optional
        Options of every candidate's :func:`~olsbayes.select.select_k`.
    """

    tie: float = math.log(3.0)
    method: str = "laplace"
    select: SelectOptions | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "tie", nonnegative_float("tie", self.tie))
        choice("method", self.method, _METHODS)
        if self.select is not None and not isinstance(self.select, SelectOptions):
            raise InputError("select must be None or a SelectOptions; got "
                             f"{type(self.select).__name__}")


@dataclass(frozen=True, eq=False)
class StructureSelection:
    """Evidence of every candidate structure and the one chosen.

    Attributes
    ----------
    names : tuple of str
        The candidates, in the order given.
    log_evidence : ndarray (M,)
        log Z_m, summed over K (nats).
    probabilities : ndarray (M,)
        p(m | data) with equal prior odds.
    best : str
        The chosen candidate (see the module notes).
    best_k : ndarray of int (M,)
        The number of sources each candidate's own selection chooses.
    selections : tuple of SelectionResult
        Each candidate's full K table.
    """

    names: tuple[str, ...]
    log_evidence: np.ndarray
    probabilities: np.ndarray
    best: str
    best_k: np.ndarray
    selections: tuple[SelectionResult, ...]

    @property
    def supported(self) -> tuple[str, ...]:
        """The terms of the chosen candidate (its name split at ``+``; ``plain`` has none).

        Names of :func:`structure_candidates` read ``[noise:]term+term`` or ``plain``.
        """
        name = self.best.split(":", 1)[-1]
        return () if name == "plain" else tuple(name.split("+"))

    def table(self) -> str:
        """A text table: candidate, log Z, p(m | data), its K; the chosen one starred."""
        w = max(len(n) for n in self.names) + 1
        lines = [f"{'model':<{w}}  {'log Z':>12}  {'p(m|data)':>9}  K", "-" * (w + 30)]
        for n, lz, p, k in zip(self.names, self.log_evidence, self.probabilities, self.best_k):
            star = "*" if n == self.best else " "
            lines.append(f"{n + star:<{w}}  {lz:12.3f}  {p:9.4f}  {k}")
        return "\n".join(lines)

    def __repr__(self) -> str:
        probs = ", ".join(f"{n}: {p:.3g}" for n, p in zip(self.names, self.probabilities))
        return f"StructureSelection(best={self.best!r}, p=({probs}))"


def _check_models(models: object) -> tuple[str, ...]:
    """Names of at least two Model candidates of one array, else InputError."""
    if not isinstance(models, Mapping) or len(models) < 2:
        raise InputError("models must be a mapping {name: Model} of at least two candidates")
    first = next(iter(models.values()))
    for name, m in models.items():
        if not isinstance(m, Model):
            raise InputError(f"models[{name!r}] must be an olsbayes.Model; got "
                             f"{type(m).__name__}")
        if m.array.n_sensors != first.array.n_sensors or not np.array_equal(
                m.array.normals, first.array.normals):
            raise InputError(f"models[{name!r}] is for another array than the first candidate")
    return tuple(str(n) for n in models)


def select_structure(models: Mapping[str, Model], data: np.ndarray, k_max: int = 2, *,
                     i_max: float | None = None, options: StructureOptions | None = None,
                     rng: np.random.Generator | int | None = None,
                     frames: bool = False) -> StructureSelection:
    """Compare candidate models of one array by their evidence (module notes).

    Every argument is checked before the first fit.

    Parameters
    ----------
    models : mapping {name: Model}
        At least two candidates of the same array, the simplest first (e.g. from
        :func:`structure_candidates`).
    data : ndarray (N,), or (F, N) with ``frames``
        Readings (every candidate's noise model must accept them).
    k_max : int
        Largest number of sources of every candidate.
    i_max : float, optional
        Upper end of the (shared) intensity prior Uniform(0, i_max); default derived
        from the data under the first candidate.
    options : StructureOptions, optional
        Tie margin, evidence method and the options of every ``select_k``.
    rng : Generator or int, optional
        One independent stream per candidate is spawned from it.
    frames : bool
        ``data`` holds F frames of one static scene.

    Returns
    -------
    StructureSelection
    """
    from scipy.special import logsumexp  # on use: scipy is slow to import

    from ..priors import default_priors
    from .select import select_k

    names = _check_models(models)
    opts = StructureOptions() if options is None else options
    if not isinstance(opts, StructureOptions):
        raise InputError(f"options must be a StructureOptions; got {type(opts).__name__}")
    for name, m in models.items():
        m.check_data(data, name=f"data (under candidate {name!r})", frames=bool(frames))
    if i_max is None:
        first = next(iter(models.values()))
        i_max = default_priors(first, 1, data=data, frames=frames).intensity.upper
    i_max = positive_float("i_max", i_max)
    streams = as_rng(rng).spawn(len(names))
    sel = tuple(select_k(m, data, k_max, i_max=i_max, method=opts.method,
                         options=opts.select, rng=g, frames=frames)
                for m, g in zip(models.values(), streams))
    log_z = np.array([float(logsumexp(s.log_evidence + s.log_prior_k)) for s in sel])
    prob = np.exp(log_z - log_z.max())
    prob /= prob.sum()
    top = float(log_z.max())
    best = next(n for n, lz in zip(names, log_z) if lz >= top - opts.tie)
    _warn_low_counts(models, best, data)
    return StructureSelection(names=names, log_evidence=log_z, probabilities=prob,
                              best=best, best_k=np.array([s.best for s in sel]),
                              selections=sel)


def _warn_low_counts(models: Mapping[str, Model], best: str, data: np.ndarray) -> None:
    """EvidenceWarning when a Gaussian model beats a Poisson candidate on low counts."""
    if models[best].noise.kind == "poisson" or not any(
            m.noise.kind == "poisson" for m in models.values()):
        return
    arr = np.asarray(data, float)
    positive = arr[arr > 0]
    median = float(np.median(positive)) if positive.size else 0.0
    if median < LOW_COUNTS:
        warnings.warn(f"the Gaussian candidate {best!r} was chosen over Poisson counts with a "
                      f"median non-zero count of {median:.3g} per frame (< {LOW_COUNTS:g}): "
                      "the Gaussian approximation of counts this low is poor",
                      EvidenceWarning, stacklevel=3)


def _term_models(model: Model, background: Prior | None, gains: Prior | None
                 ) -> dict[str, Model]:
    """``plain`` and every combination of the given terms, fewest terms first."""
    terms = [(n, p) for n, p in (("background", background), ("gains", gains)) if p is not None]
    out = {"plain": model}
    for size in range(1, len(terms) + 1):
        for combo in itertools.combinations(terms, size):
            kw = {("background_prior" if n == "background" else "gain_prior"): p
                  for n, p in combo}
            out["+".join(n for n, _ in combo)] = model.with_noise(
                model.noise, replace(model.nuisance, **kw))
    return out


def structure_candidates(model: Model, *, background: Prior | None = None,
                         gains: Prior | None = None,
                         noise: NoiseModel | None = None) -> dict[str, Model]:
    """Candidate structures of one array for :func:`select_structure`, simplest first.

    Parameters
    ----------
    model : Model
        The simplest candidate (``plain``): its noise and its nuisance as given.
    background : Prior, optional
        Prior of an inferred isotropic background (support within [0, inf)); adds
        the candidates with a ``background`` term.
    gains : Prior, optional
        Prior of every sub-sensor's gain (support within (0, inf), e.g.
        ``LogNormal(0, 0.1)``); adds the candidates with a ``gains`` term.
    noise : NoiseModel, optional
        A second noise model; every candidate is repeated under it, named
        ``"<kind>:<name>"`` (the first ones then ``"<model's kind>:<name>"``).

    Returns
    -------
    dict {name: Model}
        ``plain``, ``background``, ``gains``, ``background+gains`` (those whose
        terms were given), in that order; with ``noise`` twice as many.
    """
    if not isinstance(model, Model):
        raise InputError(f"model must be an olsbayes.Model; got {type(model).__name__}")
    if background is None and gains is None and noise is None:
        raise InputError("structure_candidates needs at least one of background, gains "
                         "or noise (otherwise there is only one candidate)")
    for name, p in (("background", background), ("gains", gains)):
        if p is not None and not isinstance(p, Prior):
            raise InputError(f"{name} must be None or an olsbayes.priors prior; got "
                             f"{type(p).__name__}")
    if noise is not None and not isinstance(noise, NoiseModel):
        raise InputError(f"noise must be None or an olsbayes.noise NoiseModel; got "
                         f"{type(noise).__name__}")
    Nuisance(background_prior=background, gain_prior=gains)  # checks the priors' supports
    first = _term_models(model, background, gains)
    if noise is None:
        return first
    second = _term_models(model.with_noise(noise), background, gains)
    return {**{f"{model.noise.kind}:{n}": m for n, m in first.items()},
            **{f"{noise.kind}:{n}": m for n, m in second.items()}}
