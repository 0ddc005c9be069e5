"""Levenberg–Marquardt on any noise model: Fisher scoring with damping (iteratively reweighted).

For a noise model with score ``u = d log L / d mu`` and Fisher weights ``w``
(:mod:`olsbayes.noise`), the step of the parameters ``phi = [scene, nuisance]``
solves

    (A^T W A + C + lambda D) step = A^T u + grad log prior

with A = d mu / d phi (:func:`olsbayes.measurement.full_jacobian`), C the
curvature of -log prior of the nuisance terms (their priors make gains and
offsets identifiable) and D the damping diagonal of :mod:`olsbayes.ml.damping`.
For Poisson counts this is iteratively reweighted least squares on the deviance
(weights exposure / mean, recomputed at every iterate); for Gaussian noise of
known sds one step is the Gauss–Newton step of the weighted chi^2.  An unknown
Gaussian sigma is profiled out: at every iterate sigma^2 = RSS / (F N), the
objective is (F N / 2) log RSS (plus constants).

Trials advance in lock-step over a leading axis, as :mod:`olsbayes.ml.lm`'s
numpy version does; bounds (intensity >= 0, latitude, the priors' supports) by
projection, an intensity at 0 whose gradient points outwards frozen for the step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import measurement
from ..model import Model
from ..noise import GaussianUnknown
from ..priors import HalfNormal, LogNormal, LogUniform, Normal
from . import damping
from .lm import project

__all__ = ["GeneralOutcome", "refine_general", "objective", "profile_sigma"]


@dataclass(frozen=True)
class GeneralOutcome:
    """Refined fits of T data vectors (internal record).

    Attributes
    ----------
    x : ndarray (T, P)
        Scene parameters.
    extra : ndarray (T, Q)
        Extra parameters (:func:`olsbayes.measurement.extra_names`); an unknown sigma
        at its profile value.
    objective : ndarray (T,)
        -log L - log prior(nuisance) at the fit.
    converged : ndarray of bool (T,)
    n_evaluations : ndarray of int (T,)
    """

    x: np.ndarray
    extra: np.ndarray
    objective: np.ndarray
    converged: np.ndarray
    n_evaluations: np.ndarray


def _prior_terms(priors: tuple, eta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(log prior (T,), gradient (T, Q), curvature >= 0 (T, Q)) of the nuisance priors."""
    t, q = eta.shape
    lp, grad, curv = np.zeros(t), np.zeros((t, q)), np.zeros((t, q))
    for j, p in enumerate(priors):
        x = eta[:, j]
        lp += np.asarray(p.log_prob(x))
        if isinstance(p, Normal):
            grad[:, j], curv[:, j] = -(x - p.mean) / p.sd**2, 1.0 / p.sd**2
        elif isinstance(p, LogNormal):
            xs = np.maximum(x, 1e-300)
            z = (np.log(xs) - p.mu) / p.s**2
            grad[:, j] = -(1.0 + z) / xs
            curv[:, j] = 1.0 / (p.s * xs) ** 2
        elif isinstance(p, HalfNormal):
            grad[:, j], curv[:, j] = -x / p.scale**2, 1.0 / p.scale**2
        elif isinstance(p, LogUniform):
            grad[:, j] = -1.0 / np.maximum(x, 1e-300)
        # flat priors (Uniform) and others: no gradient, the support by projection
    return lp, grad, curv


def profile_sigma(model: Model, mu: np.ndarray, data: np.ndarray, frames: bool) -> np.ndarray:
    """The ML sigma (T, 1) of Gaussian readings around ``mu``: sqrt(RSS / (F N))."""
    r = data - (mu[:, None, :] if frames else mu)
    count = r.shape[-1] * (r.shape[-2] if frames else 1)
    rss = np.einsum("...n,...n->...", r, r)
    rss = rss.sum(axis=-1) if frames else rss
    return np.sqrt(np.maximum(rss / count, 1e-300))[:, None]


class _Problem:
    """The objective and its pieces for a batch: model, data, priors, layout."""

    def __init__(self, model: Model, data: np.ndarray, frames: bool):
        self.model, self.data, self.frames = model, data, frames
        self.profile = isinstance(model.noise, GaussianUnknown)
        self.priors = model.nuisance.priors(model.n_sensors)
        self.qn = len(self.priors)

    def extra(self, eta: np.ndarray, sigma: np.ndarray | None) -> np.ndarray | None:
        parts = ([sigma] if self.profile else []) + ([eta] if self.qn else [])
        return np.concatenate(parts, axis=-1) if parts else None

    def evaluate(self, x: np.ndarray, eta: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """(objective (T,), sigma (T, 1) or None, expected readings (T, N))."""
        m = self.model
        mu = measurement.expected(m, x, self.extra(eta, np.ones((x.shape[0], 1))))
        sigma = profile_sigma(m, mu, self.data, self.frames) if self.profile else None
        theta = sigma if self.profile else None
        ll = m.noise.log_likelihood(mu, self.data, frames=self.frames, theta=theta)
        lp = _prior_terms(self.priors, eta)[0] if self.qn else 0.0
        return -(ll + lp), sigma, mu


def objective(model: Model, data: np.ndarray, x: np.ndarray, eta: np.ndarray,
              frames: bool) -> np.ndarray:
    """-log L - log prior(nuisance) (T,), an unknown sigma profiled out."""
    return _Problem(model, data, frames).evaluate(x, eta)[0]


def _step(pb: _Problem, x: np.ndarray, eta: np.ndarray, sigma: np.ndarray | None,
          mu: np.ndarray, lam: np.ndarray, frozen: np.ndarray | None
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One damped scoring proposal: (x_new, eta_new, predicted increase of log posterior)."""
    m, p = pb.model, x.shape[1]
    a = measurement.full_jacobian(m, x, pb.extra(eta, sigma))  # (T, N, P + Qn)
    u, w = m.noise.score(mu, pb.data, frames=pb.frames, theta=sigma)
    g = np.einsum("tnp,tn->tp", a, u)
    h = np.swapaxes(a, 1, 2) @ (w[:, :, None] * a)
    if pb.qn:
        _, pg, pc = _prior_terms(pb.priors, eta)
        g[:, p:] += pg
        h[:, np.arange(p, p + pb.qn), np.arange(p, p + pb.qn)] += pc
    t, n_phi = g.shape
    d1 = m.n_loc + 1
    fixed = np.zeros((t, n_phi), bool)
    fixed[:, d1 - 1:p:d1] = (x[:, d1 - 1::d1] <= 0.0) & (g[:, d1 - 1:p:d1] <= 0.0)
    if frozen is not None:
        fixed[:, :p] |= frozen
    diag = h.reshape(t, -1)[:, :: n_phi + 1]
    floor = damping.EIG_FLOOR * np.maximum(diag.max(axis=1, keepdims=True), 1e-300)
    hd = h + (lam[:, None] * np.maximum(diag, floor))[:, :, None] * np.eye(n_phi)
    keep = ~fixed
    hd = hd * (keep[:, :, None] & keep[:, None, :]) + fixed[:, :, None] * np.eye(n_phi)
    g = np.where(fixed, 0.0, g)
    step = np.linalg.solve(hd, g[..., None])[..., 0]
    pred = np.einsum("tp,tp->t", g, step) - 0.5 * np.einsum("tp,tpq,tq->t", step, h, step)
    x_new = project(m, x + step[:, :p])
    eta_new = _project_eta(pb.priors, eta + step[:, p:])
    return x_new, eta_new, pred


def _project_eta(priors: tuple, eta: np.ndarray) -> np.ndarray:
    """Nuisance values clipped into their priors' supports (positive ones kept > 0)."""
    if not priors:
        return eta
    lo = np.array([p.lower for p in priors])
    hi = np.array([p.upper for p in priors])
    lo = np.where(lo == 0.0, np.where([isinstance(p, (LogNormal, LogUniform)) for p in priors],
                                      1e-12, 0.0), lo)
    return np.clip(eta, lo, hi)


def refine_general(model: Model, data: np.ndarray, x0: np.ndarray, eta0: np.ndarray, *,
                   frames: bool = False, max_iter: int = 500, ftol: float = 1e-10,
                   frozen: np.ndarray | None = None) -> GeneralOutcome:
    """Damped Fisher scoring of the scene and nuisance terms from ``(x0, eta0)``.

    Parameters
    ----------
    model : Model
    data : ndarray (T, N) or, with frames, (T, F, N)
    x0 : ndarray (T, P)
    eta0 : ndarray (T, Q_nuisance)
        Starting values of the inferred nuisance terms (may be (T, 0)).
    frames : bool
    max_iter : int
    ftol : float
        Stop when an accepted step improves the objective by less than
        ``ftol * |objective| + 1e-12`` nats, or the predicted improvement is below it.
    frozen : ndarray of bool (P,), optional
        Scene parameters held at their starting values (e.g. the locations, to
        polish the intensities of a source that sits on a kink of the law).
    """
    pb = _Problem(model, data, frames)
    x = project(model, np.array(x0, dtype=float))
    eta = _project_eta(pb.priors, np.array(eta0, dtype=float).reshape(x.shape[0], pb.qn))
    t = x.shape[0]
    obj, sigma, mu = pb.evaluate(x, eta)
    lam = np.full(t, damping.START)
    active = np.ones(t, bool)
    conv = np.zeros(t, bool)
    nev = np.zeros(t, dtype=np.int64)
    for _ in range(max_iter):
        rows = np.flatnonzero(active)
        if rows.size == 0:
            break
        sub = _Problem(model, data[rows], frames)
        xn, en, pred = _step(sub, x[rows], eta[rows], None if sigma is None else sigma[rows],
                             mu[rows], lam[rows], frozen)
        on, sn, mn = sub.evaluate(xn, en)
        nev[rows] += 2
        old = obj[rows]
        tiny = ftol * np.abs(old) + 1e-12
        acc = on < old
        small = (acc & (old - on <= tiny)) | (pred <= tiny)
        sel = rows[acc]
        x[sel], eta[sel], obj[sel], mu[sel] = xn[acc], en[acc], on[acc], mn[acc]
        if sigma is not None:
            sigma[sel] = sn[acc]
        lam[rows] = np.where(acc, np.maximum(lam[rows] / damping.DOWN, damping.FLOOR),
                             lam[rows] * damping.UP)
        stall = lam[rows] > damping.MAX
        conv[rows] = small | stall
        active[rows[small | stall]] = False
    extra = pb.extra(eta, sigma)
    return GeneralOutcome(x=x, extra=np.zeros((t, 0)) if extra is None else extra,
                          objective=obj, converged=conv, n_evaluations=nev)
