"""Fisher information and the Cramér–Rao lower bound (CRLB), exact and closed form."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ._validation import finite_array, integer, positive_float
from .errors import InputError, KinkWarning, ResolutionWarning
from .model import Model
from .scene import Scene
from .sensitivity import Sensitivity

__all__ = ["CRLBResult", "crlb", "crlb_eq3", "crlb_eq4", "kink_sources", "horizon_fisher",
           "marginal_information", "bayesian_information"]

#: Relative eigenvalue below which a Fisher matrix counts as singular (after
#: :func:`equilibrate`, so the rule does not depend on the units of the readings).
SINGULAR_RTOL = 1e-10


def equilibrate(fisher: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(D F D, d)`` with D = diag(d), d = diag(F)^-1/2 (1 where a diagonal is 0).

    The parameters mix units -- angles in rad, intensities in the readings' unit
    -- so the raw eigenvalues of F span the square of the readings' scale: with
    readings of order 1e-6, a relative eigenvalue threshold would call every
    well-determined angle singular.  D F D has a unit diagonal, the same null
    space (a congruence) and eigenvalues free of the units.  Batched over
    leading axes: ``fisher`` (..., P, P), ``d`` (..., P).
    """
    diag = np.diagonal(fisher, axis1=-2, axis2=-1)
    pos = diag > 0
    d = np.where(pos, 1.0 / np.sqrt(np.where(pos, diag, 1.0)), 1.0)
    return fisher * d[..., :, None] * d[..., None, :], d


def covariance_root(cov: np.ndarray) -> np.ndarray:
    """A square root R (P, P) with R R^T = cov (negative eigenvalues clipped to 0).

    From the eigendecomposition of the correlation matrix, scaled back: the
    eigenvectors of a covariance in mixed units (rad, readings) would be
    accurate only to eps times its largest variance, not to each parameter's own.
    """
    cov = 0.5 * (cov + cov.T)
    s = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    s = np.where(s > 0, s, 1.0)
    w, v = np.linalg.eigh(cov / np.outer(s, s))
    return s[:, None] * v * np.sqrt(np.clip(w, 0.0, None))


@dataclass(frozen=True)
class CRLBResult:
    """Exact CRLB of one scene.

    Attributes
    ----------
    fisher, cov : ndarray, shape (P, P)
        Fisher information and its (pseudo-)inverse, in the model's flat layout.
    direction_std : ndarray, shape (K,) or (K, 2) or None
        Bound on the std of the angle (ring) or (longitude, latitude) (sphere), rad.
    intensity_std : ndarray, shape (K,)
        Bound on the std of each intensity.
    position_std : ndarray, shape (K, 3) or None
        Bound on the std of each near-source coordinate (plate).
    condition : float
        Condition number of the Fisher matrix with each parameter in units of its
        own information (:func:`equilibrate`; inf when singular).
    resolvable : bool
        False when some parameter is not identifiable (its std is inf).
    """

    fisher: np.ndarray
    cov: np.ndarray
    direction_std: np.ndarray | None
    intensity_std: np.ndarray
    position_std: np.ndarray | None
    condition: float
    resolvable: bool
    extra_names: tuple[str, ...] = ()
    extra_std: np.ndarray | None = None
    cov_known: np.ndarray | None = None

    @property
    def std(self) -> np.ndarray:
        """Bound on every parameter's std in the flat layout, shape (P,)."""
        return np.sqrt(np.diag(self.cov))

    @property
    def nuisance_cost(self) -> np.ndarray | None:
        """std / std with every extra parameter known, shape (P,) (>= 1); None without extras.

        How much inferring the noise and nuisance terms (gains, offsets,
        background, sigma) costs each scene parameter.
        """
        if self.cov_known is None:
            return None
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.std / np.sqrt(np.diag(self.cov_known))


def bound_covariance(fisher: np.ndarray) -> tuple[np.ndarray, float | np.ndarray, np.ndarray]:
    """Covariance bound of a Fisher matrix, with unidentifiable parameters at inf.

    A parameter's bound is finite iff its unit vector is orthogonal to the null
    space of the Fisher matrix; finite bounds then come from the pseudo-inverse.
    Null space and inverse are those of the :func:`equilibrate`-d matrix.
    Batched over leading axes.  A Fisher matrix with non-finite entries (the
    information overflowed: intensity / sigma beyond ~1e150) gets a NaN covariance
    and condition; callers warn or refuse.

    Returns
    -------
    cov : ndarray (..., P, P)
    condition : float, or ndarray (...) for a batch
        Of the equilibrated matrix (units-free); inf when singular.
    singular : ndarray of bool (..., P)
        Parameters whose bound is infinite.
    """
    f, d = equilibrate(np.asarray(fisher, dtype=float))
    if f.shape[-1] == 0:
        cond = np.ones(f.shape[:-2])
        return f.copy(), float(cond) if cond.ndim == 0 else cond, np.zeros(f.shape[:-1], bool)
    bad = ~np.all(np.isfinite(f), axis=(-2, -1))  # overflowed information: no bound
    if np.any(bad):
        f = np.where(bad[..., None, None], np.eye(f.shape[-1]), f)
    w, v = np.linalg.eigh(f)  # (..., P), (..., P, P)
    top = np.maximum(w[..., -1:], np.finfo(float).tiny)
    null = w <= SINGULAR_RTOL * top
    inv_w = np.where(null, 0.0, 1.0 / np.where(null, 1.0, w))
    cov = (v * inv_w[..., None, :]) @ np.swapaxes(v, -1, -2) * d[..., :, None] * d[..., None, :]
    singular = np.any((np.abs(v) > 1e-6) & null[..., None, :], axis=-1)
    cov = np.where(singular[..., :, None] | singular[..., None, :], np.inf, cov)
    sing = null.any(axis=-1)
    cond = np.where(sing, np.inf, top[..., 0] / np.where(sing, 1.0, w[..., 0]))
    if np.any(bad):
        cov = np.where(bad[..., None, None], np.nan, cov)
        cond = np.where(bad, np.nan, cond)
    return cov, float(cond) if cond.ndim == 0 else cond, singular


def kink_sources(model: Model, params: np.ndarray, atol: float = 1e-9) -> np.ndarray:
    """Which sources sit on the kink of a kinked law (a sub-sensor at 90 deg).

    Returns a bool array of shape (..., K).
    """
    if not model.sensitivity.kink:
        return np.zeros(np.shape(params)[:-1] + (model.n_sources_of(params),), bool)
    return np.any(np.abs(model.cosines(params)) < atol, axis=-1)


#: |cos| below which a sub-sensor counts as exactly on a source's horizon
#: (:func:`kink_sources` and :func:`horizon_fisher`).
HORIZON_ATOL = 1e-9


class _OneSided(Sensitivity):
    """A kinked law with every cosine within ``atol`` of the kink taken on it, from one side.

    ``lit``: g'(0+) (the side where the sub-sensor sees the source); else g'(0) (the
    dark side, as the law itself evaluates at c = 0).  Elsewhere the law unchanged.
    """

    kink = True

    def __init__(self, law: Sensitivity, atol: float, lit: bool):
        self.law, self.atol = law, atol
        self.side = float(law.derivative(np.array([np.finfo(float).tiny if lit else 0.0]))[0])

    def value(self, c: np.ndarray) -> np.ndarray:
        """g(c), with c = 0 on the horizon."""
        c = np.asarray(c, dtype=float)
        return self.law.value(np.where(np.abs(c) < self.atol, 0.0, c))

    def derivative(self, c: np.ndarray) -> np.ndarray:
        """dg/dc, the one-sided value on the horizon."""
        c = np.asarray(c, dtype=float)
        return np.where(np.abs(c) < self.atol, self.side, self.law.derivative(c))


def horizon_fisher(model: Model, params: np.ndarray, atol: float = HORIZON_ATOL) -> np.ndarray:
    """Fisher information (P, P) of one parameter vector, with the horizon rule.

    Where a sub-sensor lies on a source's horizon (``|cos| < atol``) a kinked law
    (the clipped cosine) has no derivative, and the rounding of ``cos`` would
    decide between the two one-sided ones.  The rule here: the Fisher information
    is the mean of the two one-sided matrices, every such sub-sensor lit
    (g'(0+) = 1) and every one dark (g'(0) = 0).  For one horizon sub-sensor this
    is the midpoint of the limits of the Fisher information as the source moves
    off the horizon to either side.  On a ring of even N a sub-sensor on a
    source's horizon has its antipode on it too, and just off the horizon one of
    the two is lit, so the rule gives the Fisher information of the neighbouring
    placements and Eq. 3 holds exactly (with N = 8 and a source on a sub-sensor's
    normal: all lit would give sd(theta) = sqrt(N / (N + 4)) times Eq. 3, all dark
    sqrt(2) times).  Elsewhere it is ``model.fisher(params)``.
    """
    x = np.asarray(params, dtype=float)
    if not np.any(kink_sources(model, x, atol)):
        return model.fisher(x)
    law = model.sensitivity
    lit = model.with_sensitivity(_OneSided(law, atol, lit=True)).fisher(x)
    dark = model.with_sensitivity(_OneSided(law, atol, lit=False)).fisher(x)
    return 0.5 * (lit + dark)


def marginal_information(full: np.ndarray, p: int) -> np.ndarray:
    """Information on the first ``p`` parameters with the others unknown: a Schur complement.

    ``F_ss - F_se F_ee^-1 F_es`` for a full information matrix (..., P + Q, P + Q)
    partitioned after ``p``; its inverse is the ``(p, p)`` block of the inverse of
    the full matrix, the bound with the others marginalised.  ``F_ee`` is
    equilibrated first (:func:`equilibrate`); where it is singular its pseudo-inverse
    is used (the unidentifiable extra directions then carry no information away).
    """
    f_ss, f_se, f_ee = full[..., :p, :p], full[..., :p, p:], full[..., p:, p:]
    if f_ee.shape[-1] == 0:
        return f_ss.copy()
    e, d = equilibrate(f_ee)
    inv = np.linalg.pinv(e, rcond=SINGULAR_RTOL, hermitian=True) * d[..., :, None] * d[
        ..., None, :]
    return f_ss - f_se @ inv @ np.swapaxes(f_se, -1, -2)


def bayesian_information(model: Model, x: np.ndarray, extra: np.ndarray | None = None, *,
                         n_frames: int | None = None) -> np.ndarray:
    """Full information (P + Q, P + Q) of ``[scene, extra]``: likelihood plus priors.

    The nuisance terms' priors add their precision (1 / variance,
    :func:`olsbayes.nuisance.prior_precision`) to the diagonal (a Bayesian,
    van Trees-type bound: without priors free gains and offsets are not
    identifiable from one static scene); the scene's and sigma's parameters get none.
    """
    from .measurement import full_fisher
    from .nuisance import prior_precision

    full = full_fisher(model, x, extra, n_frames=n_frames)
    q_nuis = model.nuisance.n_free(model.n_sensors)
    if q_nuis:
        prec = prior_precision(model.nuisance.priors(model.n_sensors))
        idx = np.arange(full.shape[-1] - q_nuis, full.shape[-1])
        full[..., idx, idx] += prec
    return full


def _extras(model: Model, x: np.ndarray, n_frames: int | None
            ) -> tuple[np.ndarray, dict[str, object]]:
    """Marginal scene information and the CRLBResult fields of the extra parameters."""
    from .measurement import extra_names

    p = x.size
    full = bayesian_information(model, x, n_frames=n_frames)
    cov_full = bound_covariance(full)[0]
    known = bound_covariance(full[:p, :p])[0]
    fields = {"extra_names": tuple(extra_names(model)),
              "extra_std": np.sqrt(np.diag(cov_full)[p:]), "cov_known": known}
    return marginal_information(full, p), fields


def _warn_bound(model: Model, x: np.ndarray, k: int, singular: np.ndarray) -> None:
    """Warn about unidentifiable parameters and sources on a sub-sensor's kink."""
    if singular.any():
        names = [n for n, s in zip(model.param_names(k), singular) if s]
        warnings.warn(
            f"Fisher matrix is singular: {', '.join(names)} cannot be identified "
            "(sources closer than the array can resolve); their CRLB is inf",
            ResolutionWarning,
            stacklevel=3,
        )
    if np.any(kink_sources(model, x)):
        warnings.warn(
            "a sub-sensor lies exactly 90 deg from a source (the kink of costn): the "
            "likelihood is not differentiable there; the CRLB uses the mean of the Fisher "
            "information with that sub-sensor lit and dark",
            KinkWarning,
            stacklevel=3,
        )


def crlb(model: Model, scene: Scene, *, n_frames: int | None = None) -> CRLBResult:
    """Exact CRLB of ``scene`` from the Fisher information of Eq. 1.

    The information is that of the model's noise (Gaussian: J^T J / sigma^2;
    Poisson: sum (d lambda / d theta)^2 / lambda) for ``n_frames`` frames.  When
    the model infers extra parameters (sigma, a background, gains, offsets) the
    scene's bound is the marginal one, with those unknown: the inverse of the
    Schur complement :func:`marginal_information` of the full information
    (:func:`bayesian_information`, the nuisance priors included);
    ``result.cov_known`` holds the bound with them known and
    ``result.nuisance_cost`` the ratio of the two.

    Warns :class:`~olsbayes.errors.ResolutionWarning` (and reports inf std) when
    the Fisher matrix is singular -- sources closer than the array resolves -- and
    :class:`~olsbayes.errors.KinkWarning` when a sub-sensor lies exactly 90 deg
    from a source (``|cos| < 1e-9``), where the clipped cosine is not
    differentiable: the Fisher information there is the mean of its two one-sided
    values, the sub-sensor lit and dark (:func:`horizon_fisher`), whatever the
    rounding of the cosine.
    """
    if not isinstance(model, Model):
        raise InputError(f"model must be an olsbayes Model; got {type(model).__name__}")
    if isinstance(scene, Scene) and scene.n_sources == 0:
        raise InputError("scene must hold at least one source (n_sources >= 1); got 0")
    x = model.pack(scene)
    k = scene.n_sources
    extras: dict[str, object] = {}
    with np.errstate(over="ignore", invalid="ignore"):
        if model.noise.is_default and model.nuisance.is_trivial and n_frames is None:
            fisher = horizon_fisher(model, x)
        elif model.noise.inferred or model.nuisance.n_free(model.n_sensors):
            fisher, extras = _extras(model, x, n_frames)
        else:
            fisher = model.fisher(x, n_frames=n_frames)
    if not np.all(np.isfinite(fisher)):
        ratio = float(np.max(scene.intensities)) / model.sigma
        raise InputError(
            f"the Fisher information of this scene overflows floating point (largest "
            f"intensity / sigma = {ratio:.3g}; sources this far above the noise, or this "
            "close to a sub-sensor, have no representable bound): use readings, "
            "intensities and sigma in units where intensity / sigma is at most ~1e90")
    cov, cond, singular = bound_covariance(fisher)
    _warn_bound(model, x, k, singular)
    std = np.sqrt(np.diag(cov)).reshape(k, model.n_loc + 1)
    loc_std = std[:, :-1]
    direction_std = None if model.kind == "position" else (
        loc_std[:, 0] if model.kind == "angle" else loc_std
    )
    return CRLBResult(
        fisher=fisher,
        cov=cov,
        direction_std=direction_std,
        intensity_std=std[:, -1],
        position_std=loc_std if model.kind == "position" else None,
        condition=cond,
        resolvable=not singular.any(),
        **extras,
    )


def crlb_eq3(n: int, sigma: float, intensity: float | np.ndarray) -> tuple[np.ndarray, float]:
    """Eq. 3: single-source CRLB on a ring of ``n`` sub-sensors.

    Returns ``(theta_std, intensity_std)`` = (2 sigma / (sqrt(n) I), 2 sigma / sqrt(n)).
    Exact for even ``n`` (with a sub-sensor on the source's horizon, under the
    rule of :func:`horizon_fisher`).
    """
    n = integer("n", n, low=3)
    sigma = positive_float("sigma", sigma)
    inten = finite_array("intensity", intensity, nonnegative=True)
    if np.any(inten == 0):
        raise InputError("intensity must be > 0 for a finite angle bound; got 0")
    return 2.0 * sigma / (np.sqrt(n) * inten), 2.0 * sigma / np.sqrt(n)


def crlb_eq4(
    n: int, sigma: float, intensity: float | np.ndarray, separation: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 4: the paper's two-source approximation on a ring.

    Returns ``(theta_std, intensity_std)`` with theta_std = 2 sigma / (I sqrt(n d/pi))
    and, by the same argument, intensity_std = 2 sigma / sqrt(n d/pi), where d is
    the angular separation (rad, folded to [0, pi]).  Where n d / pi <= 1 (the
    paper's "random guessing" region) both are inf.
    """
    n = integer("n", n, low=3)
    sigma = positive_float("sigma", sigma)
    inten = finite_array("intensity", intensity, nonnegative=True)
    sep = np.abs(np.asarray(finite_array("separation", separation)))
    sep = np.minimum(np.mod(sep, 2 * np.pi), 2 * np.pi - np.mod(sep, 2 * np.pi))
    eff = n * sep / np.pi
    with np.errstate(divide="ignore", invalid="ignore"):
        amp = np.where(eff > 1.0, 2.0 * sigma / np.sqrt(eff), np.inf)
        ang = np.where(eff > 1.0, amp / inten, np.inf)
    return ang, amp
