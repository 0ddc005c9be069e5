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

Comparing a Gaussian density with a Poisson probability treats each count as a
bin of unit width, which is accurate when the Gaussian is wide compared with one
count (many counts per sub-sensor).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from .._validation import as_rng, nonnegative_float, positive_float
from ..errors import InputError
from ..model import Model
from .options import SelectOptions
from .result import SelectionResult

__all__ = ["StructureSelection", "select_structure"]


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


def select_structure(models: Mapping[str, Model], data: np.ndarray, k_max: int = 2, *,
                     i_max: float | None = None, method: str = "laplace",
                     options: SelectOptions | None = None, tie: float = math.log(3.0),
                     rng: np.random.Generator | int | None = None,
                     frames: bool = False) -> StructureSelection:
    """Compare candidate models of one array by their evidence (module notes).

    Parameters
    ----------
    models : mapping {name: Model}
        At least two candidates of the same array, the simplest first.
    data : ndarray (N,), or (F, N) with ``frames``
    k_max : int
        Largest number of sources of every candidate.
    i_max : float, optional
        Upper end of the (shared) intensity prior; default derived from the data
        under the first candidate.
    method, options, rng, frames
        As for :func:`~olsbayes.select.select_k` (one rng stream per candidate).
    tie : float
        Nats within which the first (simplest) candidate is preferred (>= 0).
    """
    from ..priors import default_priors
    from .select import select_k

    if not isinstance(models, Mapping) or len(models) < 2:
        raise InputError("models must be a mapping {name: Model} of at least two candidates")
    names = tuple(str(n) for n in models)
    first = next(iter(models.values()))
    for name, m in models.items():
        if not isinstance(m, Model):
            raise InputError(f"models[{name!r}] must be an olsbayes.Model; got "
                             f"{type(m).__name__}")
        if m.array.n_sensors != first.array.n_sensors or not np.array_equal(
                m.array.normals, first.array.normals):
            raise InputError(f"models[{name!r}] is for another array than the first candidate")
    tie = nonnegative_float("tie", tie)
    if i_max is None:
        i_max = default_priors(first, 1, data=data, frames=frames).intensity.upper
    i_max = positive_float("i_max", i_max)
    streams = as_rng(rng).spawn(len(names))
    sel = tuple(select_k(m, data, k_max, i_max=i_max, method=method, options=options,
                         rng=g, frames=frames) for m, g in zip(models.values(), streams))
    log_z = np.array([float(logsumexp(s.log_evidence + s.log_prior_k)) for s in sel])
    prob = np.exp(log_z - log_z.max())
    prob /= prob.sum()
    top = float(log_z.max())
    best = next(n for n, lz in zip(names, log_z) if lz >= top - tie)
    return StructureSelection(names=names, log_evidence=log_z, probabilities=prob,
                              best=best, best_k=np.array([s.best for s in sel]),
                              selections=sel)
