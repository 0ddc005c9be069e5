"""Per-K work of select_k: ML fit, Laplace, nested sampling, information criteria."""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import EvidenceWarning
from ..model import Model
from .criteria import aic, bic
from .diagnostics import laplace_trust
from .laplace import model_laplace, noise_log_evidence
from .mixture import mixture_log_evidence
from .nested import NestedCheckpoint
from .nested_error import repeated_log_evidence, scaled_maxcall
from .options import NestedOptions
from .quadrature import MAX_ERROR, ring_log_evidence

__all__ = ["KWork", "noise_work", "laplace_work", "ridge_work", "mixture_work", "nested_work",
           "quadrature_work", "information_criterion", "scalar_log_likelihood",
           "ScalarLogLikelihood",
           "scalar_prior_transform", "ScalarPriorTransform", "nested_key"]


@dataclass(frozen=True, eq=False)
class KWork:
    """Internal per-K record (becomes a :class:`~olsbayes.select.result.KEvidence`)."""

    k: int
    value: float
    error: float
    method: str
    log_likelihood: float
    params: np.ndarray
    laplace: float = math.nan
    reasons: tuple[str, ...] = ()
    n_calls: int = 0
    seconds: float = 0.0
    fit: Any = None
    stats: Mapping[str, float] | None = None
    origin: str = ""
    nested: Any = None


def noise_work(model: Model, data: np.ndarray) -> KWork:
    """K = 0: the closed-form evidence log N(data; 0, sigma^2 I)."""
    t0 = time.perf_counter()
    log_z = float(noise_log_evidence(data, model.sigma))
    return KWork(0, log_z, 0.0, "closed-form", log_z, np.zeros(0), laplace=log_z,
                 seconds=time.perf_counter() - t0)


def ridge_work(model: Model, work: KWork, prior) -> KWork:
    """Replace an undefined (singular-Fisher) Laplace value by the prior-ridge fallback."""
    log_z, _, _ = model_laplace(model, work.params, work.log_likelihood, prior, ridge=True)
    why = ("Laplace with the prior's precision added on a singular Fisher matrix "
           "(rough: unidentifiable directions span the whole prior)")
    return dataclasses.replace(work, value=float(log_z), laplace=float(log_z),
                               method="laplace", reasons=work.reasons + (why,))


#: An importance-sampling evidence is itself in doubt beyond this standard error
#: (nats) or below this effective sample size.
MIXTURE_MAX_ERROR = 0.3
MIXTURE_MIN_ESS = 20.0


def mixture_work(model: Model, data: np.ndarray, work: KWork, prior,
                 lower: list[np.ndarray], n_draws: int, *, rng: np.random.Generator) -> KWork:
    """Replace an untrusted or undefined Laplace value by the mixture evidence.

    The mixture importance-sampling evidence is
    :func:`~olsbayes.select.mixture.mixture_log_evidence`; the Laplace value and its
    reasons are kept, and the sampler's own doubts (large error, few effective draws,
    no draw of positive weight) are added to the reasons.
    """
    out = mixture_log_evidence(model, data, prior, work.params, lower, n_draws=n_draws,
                               rng=rng, max_draws=2 * n_draws, target_error=0.2)
    why = ()
    if not np.isfinite(out.log_evidence):
        why = ("importance sampling found no draw of positive weight",)
    elif out.error > MIXTURE_MAX_ERROR or out.ess < MIXTURE_MIN_ESS:
        why = (f"importance-sampling evidence uncertain (+-{out.error:.2f} nats, "
               f"{out.ess:.0f} effective draws)",)
    value = out.log_evidence if np.isfinite(out.log_evidence) else math.nan
    stats = {**(work.stats or {}), "mixture_error": out.error, "mixture_ess": out.ess}
    return dataclasses.replace(
        work, value=float(value), error=float(out.error), method="importance",
        reasons=work.reasons + why, n_calls=work.n_calls + out.n_draws,
        seconds=work.seconds + out.seconds, stats=stats)


def mixture_doubt(work: KWork) -> bool:
    """Whether a mixture importance-sampling value is itself in doubt."""
    st = work.stats or {}
    return work.method == "importance" and not (
        st.get("mixture_error", math.inf) <= MIXTURE_MAX_ERROR
        and st.get("mixture_ess", 0.0) >= MIXTURE_MIN_ESS)


def laplace_work(model: Model, k: int, fitted: tuple, prior,
                 thresholds: Mapping[str, float] | None, seconds: float = 0.0) -> KWork:
    """Laplace evidence of K sources at the ML point ``fitted``, and the reasons not to trust it.

    ``fitted`` = (fit, params, log L, origin).
    """
    t0 = time.perf_counter()
    fit, params, ll, origin = fitted
    log_z, fisher, _ = model_laplace(model, params, ll, prior)
    reasons, stats = laplace_trust(model, params, fisher, thresholds=thresholds)
    if origin.endswith("(not converged)"):
        reasons = reasons + ("ML optimiser did not meet its stopping rule",)
    log_z = float(log_z)
    if np.isfinite(log_z) and log_z > ll:
        reasons = reasons + ("Laplace exceeds the likelihood maximum (Gaussian wider "
                             "than the prior)",)
    if not np.isfinite(prior.log_prob(params)):
        reasons = reasons + ("ML point outside the prior's support",)
    n_calls = int(np.sum(getattr(fit, "n_evaluations", 0)))
    return KWork(k, log_z, math.nan, "laplace", ll, params, laplace=log_z, reasons=reasons,
                 n_calls=n_calls, seconds=seconds + time.perf_counter() - t0, fit=fit,
                 stats=stats, origin=origin)


def scalar_log_likelihood(model: Model, data: np.ndarray) -> ScalarLogLikelihood:
    """A lean one-point log-likelihood for dynesty, equal to ``model.log_likelihood``.

    dynesty's slice samplers call the likelihood one point at a time, where the
    batched model's per-call overhead dominates.  Distant sources (ring, sphere)
    get a direct kernel; near sources use the model.  The object pickles (a
    checkpointed nested run stores it).
    """
    return ScalarLogLikelihood(model, data)


class ScalarLogLikelihood:
    """``f(x) -> log p(data | x)`` of one parameter vector x (:func:`scalar_log_likelihood`)."""

    def __init__(self, model: Model, data: np.ndarray):
        self.model = model
        self.data = np.array(data, dtype=float)
        if model.kind != "position":
            self.nt = np.ascontiguousarray(model.array.normals.T)
            self.inv2s2 = 0.5 / model.sigma**2
            self.const = -model.n_sensors * (math.log(model.sigma)
                                             + 0.5 * math.log(2.0 * math.pi))
            self.w = model.n_loc + 1
            self.ring = model.kind == "angle"

    def __call__(self, x: np.ndarray) -> float:
        """log-likelihood of x (P,)."""
        model = self.model
        if model.kind == "position":
            return float(model.log_likelihood(x, self.data))
        b = x.reshape(-1, self.w)
        u = np.empty((b.shape[0], self.nt.shape[0]))
        if self.ring:
            u[:, 0] = np.cos(b[:, 0])
            u[:, 1] = np.sin(b[:, 0])
        else:
            cl = np.cos(b[:, 1])
            u[:, 0] = cl * np.cos(b[:, 0])
            u[:, 1] = cl * np.sin(b[:, 0])
            u[:, 2] = np.sin(b[:, 1])
        r = self.data - b[:, -1] @ model.sensitivity.value(u @ self.nt)
        return float(self.const - self.inv2s2 * (r @ r))


def nested_key(model: Model, data: np.ndarray, prior, options: NestedOptions) -> str:
    """SHA-256 naming a nested run's problem: readings, model, prior, live points."""
    import hashlib

    from .._provenance import data_sha256

    text = repr([repr(model), data_sha256(data), repr(prior), options.n_live, options.dlogz])
    return hashlib.sha256(text.encode()).hexdigest()


def scalar_prior_transform(prior) -> ScalarPriorTransform:
    """A lean one-point prior transform for dynesty, equal to ``prior.ppf``.

    For u (P,) in the unit cube: the uniform marginals (:class:`~olsbayes.priors.Uniform`,
    :class:`~olsbayes.priors.CircularUniform`) as one affine map ``lo + scale * u``
    (the same floating-point operations as their quantile functions), the other
    coordinate roles by their own quantile functions.  u outside the cube, and a
    prior with a noise parameter, go through ``prior.ppf``.  dynesty calls the
    transform once per proposed point, where the per-role bookkeeping of
    ``ScenePrior.ppf`` would cost more than the likelihood.  The object pickles
    (a checkpointed nested run stores it).
    """
    return ScalarPriorTransform(prior)


class ScalarPriorTransform:
    """``u (P,) -> x (P,)``, the prior's quantile map (:func:`scalar_prior_transform`)."""

    def __init__(self, prior):
        from ..priors import CircularUniform, Uniform

        self.prior = prior
        w, k = prior.n_loc + 1, prior.n_sources
        self.lo, self.scale = np.zeros(prior.n_params), np.ones(prior.n_params)
        self.other = []  # (marginal, indices) of the coordinate roles with another law
        for j, p in enumerate(prior.location + (prior.intensity,)):
            idx = np.arange(k) * w + j
            if type(p) is Uniform:
                self.lo[idx], self.scale[idx] = p.lo, p.hi - p.lo
            elif type(p) is CircularUniform:
                self.lo[idx], self.scale[idx] = -np.pi, 2.0 * np.pi
            else:
                self.other.append((p, idx))
        self.lean = prior.noise is None

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """x = F^-1(u) for u (P,) in the unit cube."""
        u = np.asarray(u, dtype=float)
        if (not self.lean or u.shape != self.lo.shape
                or not all(0.0 <= v <= 1.0 for v in u.tolist())):
            return self.prior.ppf(u)
        out = self.lo + self.scale * u
        for p, idx in self.other:
            out[idx] = p._ppf(u[idx])
        return out


def nested_work(model: Model, data: np.ndarray, work: KWork, prior, options: NestedOptions,
                *, rng: np.random.Generator, progress: bool = False) -> KWork:
    """Replace a K's evidence by ``options.n_runs`` combined dynesty runs (Laplace kept).

    The error includes the runs' scatter
    (:func:`~olsbayes.select.nested_error.combine_runs`); runs stopped by their cap,
    or disagreeing beyond their errors, make the value untrusted.  With
    ``options.checkpoint_dir`` run r is checkpointed to ``nested-k<K>-run<r>.pkl``
    there (and continued from it).  dynesty's results of the first run are kept.
    """
    p = prior.n_params
    live = options.n_live or max(100, 25 * p)
    cap = options.maxcall or scaled_maxcall(p, live, n_sensors=model.n_sensors,
                                            n_runs=options.n_runs)
    ckpts = None
    if options.checkpoint_dir is not None:
        key = nested_key(model, data, prior, options)
        ckpts = [NestedCheckpoint(Path(options.checkpoint_dir) / f"nested-k{work.k}-run{r}.pkl",
                                  key) for r in range(options.n_runs)]
    out = repeated_log_evidence(
        scalar_log_likelihood(model, data), scalar_prior_transform(prior), p,
        n_runs=options.n_runs, periodic=prior.periodic_indices, rng=rng, maxcall=cap,
        n_live=live, dlogz=options.dlogz, progress=progress, checkpoints=ckpts)
    lap = work.laplace
    if not work.reasons and np.isfinite(lap):
        gap = abs(out.log_evidence - lap)
        if gap > 3 * out.error + 0.5:
            warnings.warn(
                f"K={work.k}: Laplace log Z = {lap:.2f} and nested log Z = "
                f"{out.log_evidence:.2f} +- {out.error:.2f} disagree by {gap:.2f} nats "
                "although the Laplace diagnostics passed", EvidenceWarning, stacklevel=4)
    reasons = work.reasons
    if not out.converged:
        stopped = sum(not r.converged for r in out.runs)
        reasons += (f"nested sampling stopped at maxcall={cap}"
                    + (f" ({stopped} of {len(out.runs)} runs)" if len(out.runs) > 1 else ""),)
    if out.disagree:
        reasons += (f"{len(out.runs)} nested runs disagree by {out.spread:.2f} nats beyond "
                    "their own errors (posterior mass found by some runs only)",)
    stats = {**(work.stats or {}), "nested_within": out.within,
             "nested_between": out.between, "nested_spread": out.spread,
             "nested_log_evidence": out.log_evidence, "nested_error": out.error}
    cost = {"n_calls": work.n_calls + out.n_calls, "seconds": work.seconds + out.seconds,
            "stats": stats, "nested": out.runs[0].run}
    if work.method == "importance" and not mixture_doubt(work) and len(reasons) > len(
            work.reasons):
        # runs that missed mass (or stopped short) err low; the sound importance-sampling
        # value (unbiased for Z, its own error small) stays
        kept = (f"nested sampling ({out.log_evidence:.2f} +- {out.error:.2f} nats) not "
                f"trusted: {'; '.join(reasons[len(work.reasons):])}; the importance-sampling "
                "value is kept")
        return dataclasses.replace(work, reasons=work.reasons + (kept,), **cost)
    return dataclasses.replace(work, value=out.log_evidence, error=out.error, method="nested",
                               reasons=reasons, **cost)


def quadrature_work(model: Model, data: np.ndarray, works: list[KWork], k: int, prior, *,
                    rng: np.random.Generator) -> KWork | str:
    """Replace K's evidence by the ring quadrature (Laplace and its reasons kept), or why not.

    The Fisher information of the ML fits of K and of every smaller K sets the
    grid (:func:`~olsbayes.select.quadrature.ring_log_evidence`).  Returns a
    string instead when the grid exceeds its budget or the stated error exceeds
    :data:`~olsbayes.select.quadrature.MAX_ERROR`.
    """
    out = ring_log_evidence(model, data, prior, [works[j].params for j in range(1, k + 1)],
                            rng=rng)
    if out.why:
        return out.why
    if not (np.isfinite(out.log_evidence) and out.error <= MAX_ERROR):
        return f"quadrature error {out.error:.2g} nats > {MAX_ERROR:g}"
    stats = {**(works[k].stats or {}), "quadrature_cells": float(out.n_cells),
             "quadrature_grid": float(out.n_grid)}
    return dataclasses.replace(works[k], value=out.log_evidence, error=out.error,
                               method="quadrature", seconds=works[k].seconds + out.seconds,
                               stats=stats)


def information_criterion(model: Model, k: int, fitted: tuple, method: str,
                          seconds: float = 0.0) -> KWork:
    """Pseudo-evidence -BIC/2 = log L - (P/2) log N, or -AIC/2 = log L - P."""
    fit, params, ll, origin = fitted
    p = params.size
    crit = bic(ll, p, model.n_sensors) if method == "bic" else aic(ll, p)
    n_calls = int(np.sum(getattr(fit, "n_evaluations", 0)))
    return KWork(k, -0.5 * crit, math.nan, method, ll, params, n_calls=n_calls,
                 seconds=seconds, fit=fit, origin=origin)
