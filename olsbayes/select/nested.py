"""Nested-sampling evidence with dynesty, always under a cap on likelihood calls.

The prior transform is the priors' ``ppf`` on the unit cube of the full
(unordered, labelled) parameter space, so dynesty integrates over all K! modes
of exchangeable sources -- the same Z_K the Laplace formula reaches with its
log K! term.  Ring angles and sphere longitudes are periodic.  The default
sampler is dynesty's ``rslice`` (random slice sampling), which keeps a bounded
cost on over-complete models (K larger than the truth), where dynesty's default
sampler can run for a very long time; every run is capped by ``maxcall`` anyway.

Every run keeps dynesty's results (:class:`NestedRun`: run and trace plots), can
show a status line (iterations, log Z, the remaining-evidence estimate against
``dlogz``, calls against ``maxcall``) and can be checkpointed: dynesty saves its
sampler to a file every minute and at the end, and a run started again with the
same file continues it (:class:`NestedCheckpoint`).  dynesty's file is a pickle:
loading one runs code, so resume only from files you wrote yourself.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from .._io import ensure_dir, write_target
from .._progress import progress_bar
from .._store import storable
from .._validation import as_rng, choice, integer, positive_float
from ..errors import ConvergenceWarning, InputError

__all__ = ["NestedEvidence", "NestedRun", "NestedCheckpoint", "nested_log_evidence", "SAMPLERS"]

#: dynesty samplers accepted by :func:`nested_log_evidence`.
SAMPLERS = ("rslice", "slice", "rwalk", "unif")


@storable
@dataclass(frozen=True, eq=False)
class NestedRun:
    """dynesty's results of one run, kept as arrays (saved and loaded with the selection).

    Attributes
    ----------
    arrays : Mapping[str, ndarray]
        Every numeric entry of dynesty's ``Results``: ``logl``, ``logvol``,
        ``logwt``, ``logz``, ``logzerr``, ``information``, ``samples`` (S, P) in
        the physical space, ``samples_u`` (the unit cube), ``samples_it``,
        ``ncall``, ``niter``, ``nlive``, ``eff``, ...
    """

    arrays: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        frozen = {}
        for name, value in dict(self.arrays).items():
            arr = np.array(value)
            arr.flags.writeable = False
            frozen[str(name)] = arr
        object.__setattr__(self, "arrays", MappingProxyType(frozen))

    @classmethod
    def from_results(cls, results: Any) -> NestedRun:
        """The numeric entries of a dynesty ``Results`` (bounding objects left out)."""
        keep = {}
        for name in results.keys():
            arr = np.asarray(results[name])
            if arr.dtype.kind in "biuf":
                keep[name] = arr
        return cls(keep)

    def results(self) -> Any:
        """A dynesty ``Results`` of the stored entries (scalars as Python numbers)."""
        from dynesty.results import Results

        return Results({k: (v.item() if v.ndim == 0 else np.array(v))
                        for k, v in self.arrays.items()})

    def plot(self, kind: str = "run", **kwargs: Any) -> Any:
        """dynesty's run plot or trace plot of this run, as a matplotlib figure.

        ``kind="run"``: live points, likelihood, importance weights and evidence
        against prior volume; ``"trace"``: every parameter against prior volume,
        with its marginal.  ``kwargs`` go to dynesty.
        """
        from dynesty import plotting

        if kind not in ("run", "trace"):
            raise InputError(f"kind must be 'run' or 'trace'; got {kind!r}")
        draw = plotting.runplot if kind == "run" else plotting.traceplot
        out = draw(self.results(), **kwargs)
        return out[0]

    def __repr__(self) -> str:
        a = self.arrays
        logz = float(a["logz"][-1]) if "logz" in a and a["logz"].size else float("nan")
        return f"NestedRun(niter={int(a.get('niter', -1))}, log_evidence={logz:.6g})"


@dataclass(frozen=True)
class NestedCheckpoint:
    """Where a nested run keeps its sampler, and what it belongs to.

    Attributes
    ----------
    path : path
        dynesty's checkpoint file (a pickle), written every minute and at the end
        of the run; a run given an existing file continues it.
    key : str
        Names the problem (e.g. a hash of the readings, model and prior); a file
        written under another key is refused.
    """

    path: str | os.PathLike
    key: str = ""


@dataclass(frozen=True, eq=False)
class NestedEvidence:
    """One dynesty run.

    Attributes
    ----------
    log_evidence, error : float
        log Z and dynesty's ``logzerr`` (nats).
    n_calls : int
        Likelihood evaluations used.
    n_iter : int
        Nested-sampling iterations.
    converged : bool
        False if the call cap stopped the run before the remaining-evidence
        tolerance ``dlogz`` was met.
    seconds : float
        Wall time, s.
    samples : ndarray, shape (S, P)
        Dead and live points in the physical space.
    log_weights : ndarray, shape (S,)
        Their log importance weights (normalised).
    run : NestedRun or None
        dynesty's results (run and trace plots).
    """

    log_evidence: float
    error: float
    n_calls: int
    n_iter: int
    converged: bool
    seconds: float
    samples: np.ndarray
    log_weights: np.ndarray
    run: NestedRun | None = None


def nested_log_evidence(
    log_likelihood: Callable[[np.ndarray], float],
    prior_transform: Callable[[np.ndarray], np.ndarray],
    ndim: int,
    *,
    periodic: Sequence[int] | None = None,
    rng: np.random.Generator | int | None = None,
    maxcall: int = 200_000,
    n_live: int | None = None,
    dlogz: float = 0.1,
    sample: str = "rslice",
    progress: bool = False,
    checkpoint: NestedCheckpoint | None = None,
) -> NestedEvidence:
    """Run dynesty's static nested sampler and return log Z +- logzerr.

    Parameters
    ----------
    log_likelihood : callable
        ``f(x) -> float`` for one point x of shape (ndim,).
    prior_transform : callable
        ``g(u) -> x`` from the unit cube to the prior, shape (ndim,) -> (ndim,).
    ndim : int
        Number of parameters (>= 1).
    periodic : sequence of int, optional
        Indices of periodic parameters (ring angles, sphere longitudes).
    rng : Generator or seed, optional
        Randomness; dynesty receives the Generator as ``rstate``.
    maxcall : int
        Cap on likelihood calls (>= 1000); a run stopped by the cap warns
        :class:`~olsbayes.errors.ConvergenceWarning`.
    n_live : int, optional
        Live points (> ndim); default ``max(100, 25 * ndim)``.
    dlogz : float
        Stop when the estimated remaining evidence is below this (nats).
    sample : str
        dynesty sampler, one of :data:`SAMPLERS`.
    progress : bool
        A status line on stderr while the run lasts (after a few seconds).
    checkpoint : NestedCheckpoint, optional
        Save the sampler there as the run goes; continue the run stored there.
        ``log_likelihood`` and ``prior_transform`` must then be picklable (module
        level functions or objects, not closures).
    """
    import dynesty  # heavy import kept out of `import olsbayes`

    ndim = integer("ndim", ndim, low=1)
    maxcall = integer("maxcall", maxcall, low=1000)
    n_live = max(100, 25 * ndim) if n_live is None else integer("n_live", n_live, low=ndim + 1)
    dlogz = positive_float("dlogz", dlogz)
    choice("sample", sample, tuple(SAMPLERS))
    per = None if not periodic else [integer("periodic index", i, low=0, high=ndim - 1)
                                      for i in periodic]
    if checkpoint is not None and not isinstance(checkpoint, NestedCheckpoint):
        raise InputError(f"checkpoint must be a NestedCheckpoint or None; "
                         f"got {type(checkpoint).__name__}")
    path = None
    if checkpoint is not None:
        path = write_target(checkpoint.path, "checkpoint")[0]
        ensure_dir(path.parent, "folder of the checkpoint")
    gen = as_rng(rng)
    t0 = time.perf_counter()
    if path is not None and path.exists():
        sampler = _restore(path, checkpoint.key, ndim, n_live)
    else:
        sampler = dynesty.NestedSampler(log_likelihood, prior_transform, ndim, nlive=n_live,
                                        bound="multi", sample=sample, periodic=per, rstate=gen)
        sampler.olsbayes_key = None if checkpoint is None else checkpoint.key
    # the initial live points cost n_live calls that run_nested's cap does not count
    with warnings.catch_warnings():  # dynesty's own cap warning is replaced by ours below
        warnings.filterwarnings("ignore", message="The sampling was stopped short")
        with progress_bar(enabled=progress, desc="nested sampling", unit=" it") as bar:
            sampler.run_nested(maxcall=max(maxcall - int(sampler.ncall), 1), dlogz=dlogz,
                               print_progress=bool(progress),
                               print_func=_Status(bar, maxcall) if progress else None,
                               checkpoint_file=None if path is None else str(path),
                               resume=bool(path is not None and sampler.it > 1))
    res = sampler.results
    n_calls = int(np.sum(res.ncall)) + n_live
    converged = n_calls < maxcall
    if not converged:
        warnings.warn(
            f"nested sampling stopped at the cap maxcall={maxcall} before the remaining "
            f"evidence fell below dlogz={dlogz}; log Z is then biased low",
            ConvergenceWarning,
            stacklevel=2,
        )
    return NestedEvidence(
        log_evidence=float(res.logz[-1]), error=float(res.logzerr[-1]), n_calls=n_calls,
        n_iter=int(res.niter), converged=converged, seconds=time.perf_counter() - t0,
        samples=np.asarray(res.samples), log_weights=np.asarray(res.logwt) - res.logz[-1],
        run=NestedRun.from_results(res),
    )


def _restore(path: Path, key: str, ndim: int, n_live: int):
    """The sampler stored at ``path`` (a dynesty pickle), checked against the run asked for."""
    import dynesty

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # dynesty's version-mismatch notes
            sampler = dynesty.NestedSampler.restore(str(path))
    except Exception as exc:  # noqa: BLE001 - any unreadable file is the same user error
        raise InputError(f"checkpoint {str(path)!r} is not a dynesty checkpoint: "
                         f"{type(exc).__name__}: {exc}") from None
    if getattr(sampler, "olsbayes_key", None) != key or sampler.ndim != ndim or (
            sampler.nlive != n_live):
        raise InputError(f"checkpoint {str(path)!r} belongs to another nested run (other "
                         "readings, model, prior or live points): delete it or give another "
                         "path")
    if sampler.added_live:
        # a finished run (converged, or stopped by its call cap): take the final live
        # points back out so that the loop continues where it stopped, as dynesty does
        # itself when a run is extended; a converged run stops again at once
        sampler._remove_live_points()
    return sampler


class _Status:
    """dynesty's ``print_func``: the tqdm status line of a nested run."""

    def __init__(self, bar: Any, maxcall: int):
        self.bar, self.maxcall = bar, maxcall

    def __call__(self, results: Any, niter: int, ncall: int, *args: Any, dlogz: float = 0.0,
                 **kwargs: Any) -> None:
        self.bar.update(max(niter - self.bar.n, 0))
        self.bar.set_postfix_str(
            f"log Z {results.logz:.2f}, remaining {results.delta_logz:.3g} -> needs < "
            f"{dlogz:g}, calls {ncall}/{self.maxcall}", refresh=False)
