"""Gain and offset calibration: from frames of known scenes, to and from a file.

A sub-sensor n reads ``g_n r_fn + o_n`` plus noise in frame f, where
``r_fn`` is the known Eq. 1 response of that frame's scene (a source at a known
direction and intensity, a flat field of known level, or nothing: a dark frame).
Each sub-sensor is then a two-parameter linear model over the frames, fitted by
maximum likelihood under the model's noise: weighted least squares for Gaussian
noise, iteratively reweighted least squares (Fisher scoring on the Poisson
likelihood with identity link) for counts.  The uncertainties are the inverse of
each sub-sensor's 2 x 2 Fisher matrix at the estimate (its CRLB).

A :class:`Calibration` remembers the array it was measured on (its normals) and
refuses another; :meth:`Calibration.nuisance` turns it into the model's
:class:`~olsbayes.Nuisance`, known, or inferred with priors centred on the
calibration and as wide as its uncertainties.  Files: TOML (``.toml``, readable
and editable) or NetCDF (``.nc``).
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._io import write_text_atomic
from ._store import load_result, save_result, storable
from ._validation import file_path, finite_array, integer
from .errors import ConfigError, InputError
from .geometry import SensorArray
from .model import Model
from .noise import GaussianUnknown, Poisson
from .nuisance import Nuisance
from .priors import LogNormal, Normal, Prior
from .scene import Scene

__all__ = ["Calibration", "calibrate", "NORMALS_ATOL"]

#: Largest difference of a normal's components for a calibration to fit an array.
NORMALS_ATOL = 1e-9


def _frozen(arr: np.ndarray) -> np.ndarray:
    arr = np.array(arr, dtype=float)
    arr.flags.writeable = False
    return arr


@storable
@dataclass(frozen=True, eq=False)
class Calibration:
    """Per-sensor gains and offsets with their standard errors, for one array.

    Attributes
    ----------
    gains, offsets : ndarray (N,)
        Estimates (gains > 0; offsets in reading units, Poisson: dark rates).
    gain_sd, offset_sd : ndarray (N,)
        Their standard errors (0: exact).
    normals : ndarray (N, D)
        The normals of the array calibrated.
    """

    gains: np.ndarray
    offsets: np.ndarray
    gain_sd: np.ndarray
    offset_sd: np.ndarray
    normals: np.ndarray = field(repr=False)

    def __post_init__(self) -> None:
        g = finite_array("gains", self.gains, ndim=1)
        n = g.size
        if np.any(g <= 0):
            raise InputError(f"gains must be > 0; got minimum {float(g.min())!r}")
        vals = {"gains": g}
        for name in ("offsets", "gain_sd", "offset_sd"):
            vals[name] = finite_array(name, getattr(self, name), ndim=1, last=n,
                                      nonnegative=name.endswith("_sd"))
        vals["normals"] = finite_array("normals", self.normals, ndim=2)
        if vals["normals"].shape[0] != n:
            raise InputError(f"normals must hold one row per sub-sensor ({n}); got shape "
                             f"{vals['normals'].shape}")
        for name, arr in vals.items():
            object.__setattr__(self, name, _frozen(arr))

    @property
    def n_sensors(self) -> int:
        """Number N of sub-sensors calibrated."""
        return int(self.gains.size)

    def check(self, array: SensorArray | Model) -> None:
        """Refuse an array other than the one calibrated (number of sub-sensors or normals)."""
        arr = array.array if isinstance(array, Model) else array
        if arr.n_sensors != self.n_sensors:
            raise InputError(f"calibration is for an array of {self.n_sensors} sub-sensors; "
                             f"this array has {arr.n_sensors}")
        if (arr.normals.shape != self.normals.shape
                or not np.allclose(arr.normals, self.normals, rtol=0, atol=NORMALS_ATOL)):
            raise InputError("calibration is for another array: its normals differ from this "
                             f"array's (by more than {NORMALS_ATOL:g})")

    def nuisance(self, *, infer: bool = False, background: float = 0.0,
                 background_prior: Prior | None = None) -> Nuisance:
        """The model's nuisance terms: these gains and offsets, known or inferred.

        ``infer=True`` gives every gain a prior ``LogNormal(log g_n, sd_n / g_n)``
        and every offset ``Normal(o_n, sd_n)`` (a term with sd 0 stays known).
        """
        if not infer:
            return Nuisance(gains=self.gains, offsets=self.offsets, background=background,
                            background_prior=background_prior)
        g_pr = o_pr = None
        if np.all(self.gain_sd > 0):
            g_pr = tuple(LogNormal(float(np.log(g)), float(s / g))
                         for g, s in zip(self.gains, self.gain_sd))
        if np.all(self.offset_sd > 0):
            o_pr = tuple(Normal(float(o), float(s)) for o, s in zip(self.offsets, self.offset_sd))
        return Nuisance(gains=self.gains, offsets=self.offsets, background=background,
                        gain_prior=g_pr, offset_prior=o_pr, background_prior=background_prior)

    # -- files -------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """Write to ``.toml`` (text) or ``.nc`` (NetCDF), atomically."""
        p = file_path("path", path)
        if p.suffix.lower() == ".nc":
            return save_result(self, p)
        if p.suffix.lower() != ".toml":
            raise InputError(f"calibration file must end in .toml or .nc; got {str(p)!r}")
        rows = ",\n    ".join("[" + ", ".join(repr(float(v)) for v in r) + "]"
                               for r in self.normals)
        lines = ["# olsbayes calibration: per-sensor gains and offsets with standard errors",
                 "[calibration]", f"n_sensors = {self.n_sensors}"]
        for name in ("gains", "offsets", "gain_sd", "offset_sd"):
            vals = ", ".join(repr(float(v)) for v in getattr(self, name))
            lines.append(f"{name} = [{vals}]")
        lines.append(f"normals = [\n    {rows}\n]")
        return write_text_atomic(p, "\n".join(lines) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike) -> Calibration:
        """Read a file written by :meth:`save` (ConfigError for a malformed one)."""
        p = file_path("path", path)
        if p.suffix.lower() == ".nc":
            return load_result(p, cls)
        try:
            doc = tomllib.loads(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"calibration file {str(p)!r} cannot be read: {exc}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"calibration file {str(p)!r}: malformed TOML: {exc}") from None
        sec = doc.get("calibration")
        keys = {"n_sensors", "gains", "offsets", "gain_sd", "offset_sd", "normals"}
        if not isinstance(sec, dict) or set(sec) != keys:
            raise ConfigError(f"calibration file {str(p)!r} must hold a [calibration] table "
                              f"with exactly the keys {sorted(keys)}")
        try:
            out = cls(**{k: np.asarray(sec[k], dtype=float) for k in keys - {"n_sensors"}})
        except (InputError, ValueError, TypeError) as exc:
            raise ConfigError(f"calibration file {str(p)!r}: {exc}") from None
        if out.n_sensors != sec["n_sensors"]:
            raise ConfigError(f"calibration file {str(p)!r}: n_sensors = {sec['n_sensors']} "
                              f"but {out.n_sensors} gains")
        return out


def _responses(model: Model, scenes: Sequence[Scene] | None, flat: np.ndarray | None,
               n_frames: int) -> np.ndarray:
    """Known Eq. 1 responses (F, N) of the frames: scenes plus flat-field levels."""
    r = np.zeros((n_frames, model.n_sensors))
    if scenes is not None:
        if len(scenes) != n_frames:
            raise InputError(f"scenes must hold one Scene per frame ({n_frames}); got "
                             f"{len(scenes)}")
        for f, sc in enumerate(scenes):
            if not isinstance(sc, Scene):
                raise InputError(f"scenes[{f}] must be a Scene; got {type(sc).__name__}")
            if sc.n_sources:
                r[f] = model.response(sc)
    if flat is not None:
        lv = finite_array("flat", flat, ndim=1, last=n_frames, nonnegative=True)
        r += lv[:, None]
    return r


def calibrate(model: Model, readings: np.ndarray, scenes: Sequence[Scene] | None = None, *,
              flat: np.ndarray | None = None, offsets: bool = True,
              max_iter: int = 100) -> Calibration:
    """Gains (and offsets) of every sub-sensor from F frames of known scenes.

    Parameters
    ----------
    model : Model
        The array, law and noise model (its own nuisance terms are ignored).
    readings : ndarray (F, N)
        The frames (Poisson: counts; a vector exposure gives one per frame).
    scenes : sequence of F Scenes, optional
        The known scene of each frame (a Scene without sources: nothing but ``flat``).
    flat : ndarray (F,), optional
        A flat-field level per frame (intensity units), added to every sub-sensor.
    offsets : bool
        Fit offsets too (needs two distinct known levels per sub-sensor, e.g. a dark
        frame); False fixes them at 0.
    max_iter : int
        Fisher-scoring iterations for counts.

    Returns
    -------
    Calibration
    """
    if not isinstance(model, Model):
        raise InputError(f"model must be an olsbayes.Model; got {type(model).__name__}")
    s = model.check_data(readings, name="readings", frames=True)
    if s.ndim != 2:
        raise InputError(f"readings must be frames of shape (F, {model.n_sensors}); got "
                         f"shape {s.shape}")
    n_f = s.shape[0]
    r = _responses(model, scenes, flat, n_f)
    design = np.stack([r.T, np.ones_like(r.T)], axis=-1) if offsets else r.T[..., None]
    rank = np.linalg.matrix_rank(design)
    if np.any(rank < design.shape[-1]):
        bad = int(np.flatnonzero(rank < design.shape[-1])[0])
        raise InputError(f"the frames do not determine sub-sensor {bad}'s gain"
                         f"{' and offset' if offsets else ''}: it needs "
                         f"{design.shape[-1]} distinct known levels (add a dark frame or "
                         "another scene)")
    integer("max_iter", max_iter, low=1)
    beta, info = _fit(model, s, design, max_iter)
    cov = np.linalg.inv(info)
    sd = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0.0, None))
    gains = beta[:, 0]
    if np.any(gains <= 0):
        raise InputError(f"calibration gives gain <= 0 for sub-sensor "
                         f"{int(np.flatnonzero(gains <= 0)[0])}: check the scenes and readings")
    zeros = np.zeros(model.n_sensors)
    return Calibration(gains=gains, offsets=beta[:, 1] if offsets else zeros,
                       gain_sd=sd[:, 0], offset_sd=sd[:, 1] if offsets else zeros,
                       normals=model.array.normals)


def _fit(model: Model, s: np.ndarray, design: np.ndarray, max_iter: int
         ) -> tuple[np.ndarray, np.ndarray]:
    """Per-sensor ML of ``s[:, n] ~ design[n] @ beta_n``: (beta (N, q), information (N, q, q))."""
    noise = model.noise
    if isinstance(noise, Poisson):
        e = np.broadcast_to(np.asarray(noise.exposure, float), (s.shape[0],))  # (F,)
        dark = np.broadcast_to(np.asarray(noise.dark, float), (model.n_sensors,))[:, None]
        rate = s.T / e - dark  # (N, F): the least-squares start
        gram = np.einsum("nfq,nfr->nqr", design, design)
        beta = np.linalg.solve(gram, np.einsum("nfq,nf->nq", design, rate)[..., None])[..., 0]
        for _ in range(max_iter):
            mu = np.maximum(np.einsum("nfq,nq->nf", design, beta) + dark, 1e-12)
            score = np.einsum("nfq,nf->nq", design, s.T / mu - e)
            info = np.einsum("nfq,nf,nfr->nqr", design, e / mu, design)
            step = np.linalg.solve(info, score[..., None])[..., 0]
            beta = beta + step
            if np.all(np.abs(step) <= 1e-12 * (np.abs(beta) + 1e-12)):
                break
        mu = np.maximum(np.einsum("nfq,nq->nf", design, beta) + dark, 1e-12)
        return beta, np.einsum("nfq,nf,nfr->nqr", design, e / mu, design)
    sig = np.broadcast_to(np.asarray(getattr(noise, "sigma", model.sigma), float),
                          (model.n_sensors,))
    gram = np.einsum("nfq,nfr->nqr", design, design)
    beta = np.linalg.solve(gram, np.einsum("nfq,fn->nq", design, s)[..., None])[..., 0]
    if isinstance(noise, GaussianUnknown):  # pooled residual variance
        resid = s - np.einsum("nfq,nq->fn", design, beta)
        dof = max(s.size - beta.size, 1)
        sig = np.full(model.n_sensors, np.sqrt(np.sum(resid**2) / dof))
    return beta, gram / sig[:, None, None] ** 2
