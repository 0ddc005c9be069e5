"""Eq. 1 forward model: response, analytic Jacobian, likelihood, simulation.

Parameter vectors are flat arrays of shape ``(..., n_params)`` whose leading axes
are batch axes (walkers, trials).  For K sources the layout is per source,
``[location..., intensity]`` repeated K times, i.e. ``x.reshape(..., K, d + 1)``
with d = 1 (ring angle), 2 (longitude, latitude) or 3 (position).

The kernel is trig-free per sensor-source pair: each source's direction becomes
one unit vector (a handful of cos/sin per source), then ``c = n . u`` is a
matrix product and the law ``g(c)`` a clip -- multiply-adds only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np

from . import _one, measurement
from ._frozen import Frozen
from ._nearfield import near_gain, near_jacobian_t
from ._validation import finite_array, real_array
from .circular import wrap_angle
from .errors import InputError
from .geometry import SensorArray, lonlat_to_unit
from .noise import NoiseModel
from .nuisance import Nuisance
from .scene import Scene
from .sensitivity import Cosine, Sensitivity, get_sensitivity

__all__ = ["Model"]

#: Sensor-source terms per block of the batched kernel: (block, K, N) float64
#: intermediates of ~256 KiB stay in a core's L2 cache (see benchmarks/).
BLOCK_TERMS = 32768

_FLOAT = np.dtype(float)

_LOC_NAMES = {"angle": ("theta",), "lonlat": ("lon", "lat"), "position": ("x", "y", "z")}


_T = TypeVar("_T")


class Model(Frozen):
    """Eq. 1 for one sensor array, noise model and sensitivity law (immutable).

    Parameters
    ----------
    array : SensorArray
        The sub-sensors (:class:`~olsbayes.Ring`, :class:`~olsbayes.Sphere`, ...).
    sigma : float, optional
        Standard deviation of the additive Gaussian sub-sensor noise, in units of
        the readings, within [1e-100, 1e100] (:data:`olsbayes._validation.SIGMA_RANGE`):
        ``noise=GaussianKnown(sigma)``.  Give sigma or ``noise``.
    sensitivity : Sensitivity or str, optional
        Angular law; default the paper's clipped cosine.
    noise : NoiseModel, optional
        Any :mod:`olsbayes.noise` model (unknown sigma, per-sensor sigma, Poisson
        counts); ``sigma`` is then its nominal scale (:attr:`NoiseModel.scale`).
    nuisance : Nuisance, optional
        Gains, offsets and diffuse background, known or inferred
        (:mod:`olsbayes.nuisance`); default none.  The likelihood, Fisher
        information and simulation go through :mod:`olsbayes.measurement`.

    Notes
    -----
    A model never changes after construction (:meth:`with_sigma` and
    :meth:`with_sensitivity` return changed copies), so the constants derived
    from it -- candidate atoms, compiled-kernel arguments, designs -- are cached
    on the instance itself (:meth:`memo`) and can never describe another model.
    """

    _mutation_hint = "; use with_sigma() or with_sensitivity() for a changed copy"

    def __init__(self, array: SensorArray, sigma: float | None = None,
                 sensitivity: Sensitivity | str | None = None, *,
                 noise: NoiseModel | None = None, nuisance: Nuisance | None = None):
        if not isinstance(array, SensorArray):
            raise InputError(
                f"array must be a SensorArray (Ring, Sphere, Plate); got {type(array).__name__}"
            )
        self.array = array
        self.noise, self.nuisance = measurement.resolve(sigma, noise, nuisance, array.n_sensors)
        self.sigma = self.noise.scale
        self.sensitivity = get_sensitivity(sensitivity)
        self._normals_t = np.ascontiguousarray(array.normals.T)
        self._positions_t = (
            None if array.positions is None else np.ascontiguousarray(array.positions.T)
        )
        # Layout constants, fixed by the (read-only) array: cached because the
        # fitters' inner loops ask for them thousands of times per fit.
        self._kind = array.source_kind
        self._n_loc = array.n_source_params
        self._n_sensors = array.n_sensors
        # log of the Gaussian normalisation, N (log sigma + log(2 pi) / 2)
        self._log_norm = self._n_sensors * (np.log(self.sigma) + 0.5 * np.log(2 * np.pi))
        self._var = self.sigma**2
        # which short paths apply: far-field sources, the clipped cosine, the default noise
        self._far = self._kind != "position"
        self._clipped = type(self.sensitivity) is Cosine
        self._plain = bool(self.noise.is_default and self.nuisance.is_trivial)
        self._one_logl = self._plain and self._far  # the one-vector log-likelihood path
        self._d1 = self._n_loc + 1
        self._memo: dict[Any, Any] = {}

    # -- copies and derived constants ---------------------------------------------
    def with_sigma(self, sigma: float) -> "Model":
        """The same array, law and nuisance with Gaussian noise of known sd ``sigma`` (> 0)."""
        return Model(self.array, sigma, self.sensitivity, nuisance=self.nuisance)

    def with_noise(self, noise: NoiseModel, nuisance: Nuisance | None = None) -> "Model":
        """The same array and law with another noise model (and nuisance, default the same)."""
        return Model(self.array, None, self.sensitivity, noise=noise,
                     nuisance=self.nuisance if nuisance is None else nuisance)

    def with_sensitivity(self, sensitivity: Sensitivity | str | None) -> "Model":
        """The same array and noise with another sensitivity law."""
        return Model(self.array, None, sensitivity, noise=self.noise, nuisance=self.nuisance)

    def memo(self, key: object, make: Callable[[], _T] | None = None) -> _T | None:
        """``make()``, computed once per model and ``key`` (a hashable label).

        Holds constants derived from this model alone (grids, atoms, kernel
        arguments).  The memo belongs to the instance: copies and unpickled models
        start with an empty one.  Without ``make``: the value held, or None.
        """
        try:
            return self._memo[key]
        except KeyError:
            if make is None:
                return None
            value = self._memo[key] = make()
            return value

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_memo"] = {}
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self.__dict__["_memo"] = {}

    # -- layout -----------------------------------------------------------------
    @property
    def n_sensors(self) -> int:
        """Number N of sub-sensors."""
        return self._n_sensors

    @property
    def kind(self) -> str:
        """Source space: ``"angle"``, ``"lonlat"`` or ``"position"``."""
        return self._kind

    @property
    def n_loc(self) -> int:
        """Location parameters per source (1, 2 or 3)."""
        return self._n_loc

    def n_params(self, n_sources: int) -> int:
        """Length of the flat parameter vector for ``n_sources`` sources."""
        return int(n_sources) * (self.n_loc + 1)

    def n_sources_of(self, params: np.ndarray) -> int:
        """Number of sources K encoded by the last axis of ``params``."""
        shape = params.shape if isinstance(params, np.ndarray) else np.shape(params)
        p, d1 = (shape[-1] if shape else -1), self._n_loc + 1
        if p < 0 or p % d1:
            raise InputError(
                f"params must have last axis a multiple of {d1} "
                f"({_LOC_NAMES[self.kind] + ('I',)} per source); got shape {shape}"
            )
        return p // d1

    def param_names(self, n_sources: int) -> list[str]:
        """Names such as ``theta[0], I[0], theta[1], I[1]`` in layout order."""
        names = _LOC_NAMES[self.kind] + ("I",)
        return [f"{nm}[{k}]" for k in range(int(n_sources)) for nm in names]

    def pack(self, scene: Scene) -> np.ndarray:
        """Flat parameter vector, shape (K * (d + 1),), of a scene."""
        if not isinstance(scene, Scene):
            raise InputError(f"scene must be a Scene; got {type(scene).__name__}")
        if scene.n_sources and scene.kind != self.kind:
            raise InputError(
                f"scene has {scene.kind!r} sources but the array expects {self.kind!r} "
                f"sources ({'/'.join(_LOC_NAMES[self.kind])})"
            )
        if self.kind == "position" and scene.n_sources and np.any(scene.positions[:, 2] <= 0):
            raise InputError("positions z must be > 0 (sources in front of the plate)")
        if scene.n_sources == 0:
            return np.zeros(0)
        return np.column_stack([scene.locations, scene.intensities]).ravel()

    def unpack(self, params: np.ndarray) -> Scene:
        """The :class:`Scene` of one flat parameter vector (intensities clipped at 0)."""
        x = finite_array("params", params, ndim=1, allow_empty=True)
        k = self.n_sources_of(x)
        blocks = x.reshape(k, self.n_loc + 1)
        inten = np.maximum(blocks[:, -1], 0.0)
        loc = blocks[:, :-1]
        if self.kind == "position":
            return Scene(positions=loc, intensities=inten)
        if self.kind == "angle":
            return Scene(directions=loc[:, 0], intensities=inten)
        lat = np.clip(loc[:, 1], -np.pi / 2, np.pi / 2)
        return Scene(directions=np.column_stack([loc[:, 0], lat]), intensities=inten)

    def _as_params(self, scene_or_params: Scene | np.ndarray) -> np.ndarray:
        x = scene_or_params
        if (type(x) is np.ndarray and x.dtype is _FLOAT and x.ndim
                and not x.shape[-1] % (self._n_loc + 1)):
            return x  # already a valid float array: the common case, checked cheaply
        if isinstance(scene_or_params, Scene):
            return self.pack(scene_or_params)
        x = real_array("params (a Scene or a real array of shape (..., K * "
                       f"{self.n_loc + 1}))", scene_or_params)
        self.n_sources_of(x)
        return x

    # -- kernel -----------------------------------------------------------------
    def _split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k = self.n_sources_of(x)
        blocks = x.reshape(x.shape[:-1] + (k, self._n_loc + 1))
        return blocks[..., :-1], blocks[..., -1]

    def _directions(self, loc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit vectors (..., K, D) and tangents d u / d loc (..., K, d, D)."""
        if self._kind == "angle":
            u = self._units(loc)
            tang = np.empty(u.shape[:-1] + (1, 2))
            np.negative(u[..., 1], out=tang[..., 0, 0])
            tang[..., 0, 1] = u[..., 0]
            return u, tang
        lon, lat = loc[..., 0], loc[..., 1]
        u = lonlat_to_unit(lon, lat)
        clo, slo, cla, sla = np.cos(lon), np.sin(lon), np.cos(lat), np.sin(lat)
        d_lon = np.stack([-cla * slo, cla * clo, np.zeros_like(lon)], axis=-1)
        d_lat = np.stack([-sla * clo, -sla * slo, cla], axis=-1)
        return u, np.stack([d_lon, d_lat], axis=-2)

    def cosines(self, scene_or_params: Scene | np.ndarray) -> np.ndarray:
        """c = cos(angle between normal n and source), shape (..., K, N)."""
        x = self._as_params(scene_or_params)
        loc, _ = self._split(x)
        if self.kind == "position":
            d = loc[..., :, None, :] - self.array.positions
            nd = np.einsum("...ni,ni->...n", d, self.array.normals)
            return nd / np.linalg.norm(d, axis=-1)
        u, _ = self._directions(loc)
        return u @ self._normals_t

    def _units(self, loc: np.ndarray) -> np.ndarray:
        """Unit vectors (..., K, D) of far-field source locations (trig once per source)."""
        if self._kind == "angle":
            th = loc[..., 0]
            u = np.empty(th.shape + (2,))
            np.cos(th, u[..., 0])
            np.sin(th, u[..., 1])
            return u
        return lonlat_to_unit(loc[..., 0], loc[..., 1])

    def _gain(self, where: np.ndarray) -> np.ndarray:
        """g(n . u) (far field) or g(c) / r^2 (near field), shape (B, K, N).

        ``where`` holds unit vectors (B, K, D) or near-source positions (B, K, 3).
        """
        b, k = where.shape[:2]
        if self.kind == "position":
            return near_gain(where, self._positions_t, self._normals_t, self.sensitivity)
        c = where.reshape(b * k, -1) @ self._normals_t
        return self.sensitivity.value(c).reshape(b, k, self.n_sensors)

    def response(self, scene_or_params: Scene | np.ndarray) -> np.ndarray:
        """Noiseless Eq. 1 readings, shape (..., N).

        The batch is processed in blocks of about :data:`BLOCK_TERMS` sensor-source
        terms so that the (block, K, N) intermediates stay in cache.  One far-field
        vector takes a short path with the same arithmetic (equal to the bit).
        """
        x = scene_or_params
        if (type(x) is np.ndarray and x.ndim == 1 and x.dtype is _FLOAT and self._far
                and not x.shape[0] % self._d1):
            return _one.response(self, x)  # one valid far-field vector: the short path
        x = self._as_params(x)
        if x.ndim == 1 and self._far:
            return _one.response(self, x)
        return self._response_unchecked(x)

    def _response_unchecked(self, x: np.ndarray) -> np.ndarray:
        """:meth:`response` of a float array x (..., P) the caller has validated."""
        loc, inten = self._split(x)
        batch, k, n = inten.shape[:-1], inten.shape[-1], self._n_sensors
        n_batch = math.prod(batch)
        if k == 0 or n_batch == 0:
            return np.zeros(batch + (n,))
        where = loc.reshape(n_batch, k, self.n_loc)
        if self.kind != "position":
            where = self._units(where)
        inten = inten.reshape(n_batch, k)
        out = np.empty((n_batch, n))
        step = max(1, BLOCK_TERMS // (k * n))
        for start in range(0, n_batch, step):
            blk = slice(start, start + step)
            np.einsum("bk,bkn->bn", inten[blk], self._gain(where[blk]), out=out[blk])
        return out.reshape(batch + (n,))

    def jacobian(self, scene_or_params: Scene | np.ndarray) -> np.ndarray:
        """d response / d params, shape (..., N, n_params)."""
        x = self._as_params(scene_or_params)
        if x.ndim == 1 and self._far:
            return _one.jacobian_t(self, x).T
        jac_t = self._jacobian_t(x)
        return jac_t.T if jac_t.ndim == 2 else np.swapaxes(jac_t, -1, -2)

    def _jacobian_t(self, x: np.ndarray) -> np.ndarray:
        """Transposed Jacobian, C-contiguous (..., n_params, N), of a validated x."""
        k = x.shape[-1] // (self._n_loc + 1)
        blocks = x.reshape(x.shape[:-1] + (k, self._n_loc + 1))
        loc, inten = blocks[..., :-1], blocks[..., -1:]
        if self._kind == "position":
            out = near_jacobian_t(loc, inten[..., 0], self.array.positions,
                                  self.array.normals, self.sensitivity)
        else:
            u, tang = self._directions(loc)
            c = u @ self._normals_t  # (..., K, N)
            g, dg = self.sensitivity.value(c), self.sensitivity.derivative(c)
            dc = tang @ self._normals_t  # (..., K, d, N)
            out = np.empty(c.shape[:-1] + (self._n_loc + 1, self._n_sensors))
            np.multiply((inten * dg)[..., None, :], dc, out[..., :-1, :])
            out[..., -1, :] = g  # (..., K, d+1, N)
        return out.reshape(x.shape + (self._n_sensors,))

    # -- statistics (olsbayes.measurement) ---------------------------------------------
    def check_data(self, data: object, name: str = "data", frames: bool = False) -> np.ndarray:
        """Validate readings: real, finite, last axis of length N (frames: (..., F, N)).

        Each data vector's largest |reading| must lie within a factor
        :data:`~olsbayes._validation.READING_RATIO` of sigma (or be 0); Poisson
        readings must be counts.
        """
        return measurement.check_data(self, data, name, frames)

    def log_likelihood(self, scene_or_params: Scene | np.ndarray, data: np.ndarray, *,
                       extra: np.ndarray | None = None, frames: bool = False) -> np.ndarray:
        """Log-likelihood log p(data | params), batched: shape (...,).

        ``params`` (..., n_params) and ``data`` (..., N) broadcast over leading axes;
        with ``frames`` the data are (..., F, N), F frames of one scene each.
        ``extra`` (..., Q): values of the inferred noise and nuisance parameters
        (:func:`olsbayes.measurement.extra_names`), default their nominal values.
        """
        x = scene_or_params
        if (self._one_logl and extra is None and frames is False and type(x) is np.ndarray
                and type(data) is np.ndarray and x.ndim == 1 == data.ndim
                and x.dtype is _FLOAT and data.dtype is _FLOAT
                and data.shape[0] == self._n_sensors and not x.shape[0] % self._d1):
            return _one.log_likelihood(self, x, data)  # one vector, default noise: short path
        return measurement.log_likelihood(self, scene_or_params, data, extra=extra,
                                          frames=frames)

    def fisher(self, scene_or_params: Scene | np.ndarray, *, extra: np.ndarray | None = None,
               n_frames: int | None = None) -> np.ndarray:
        """Fisher information of the scene parameters, shape (..., n_params, n_params).

        J^T W J with the noise model's weights W (Gaussian: 1 / sigma^2; Poisson:
        exposure / mean), for ``n_frames`` frames; extra parameters held fixed.
        """
        return measurement.fisher(self, scene_or_params, extra=extra, n_frames=n_frames)

    def simulate(self, scene: Scene | np.ndarray, *, rng: np.random.Generator | int | None = None,
                 size: int | tuple[int, ...] | None = None,
                 n_frames: int | None = None) -> np.ndarray:
        """Noisy readings: shape ``size + (N,)``, or ``size + (F, N)`` for ``n_frames`` F."""
        return measurement.simulate(self, scene, rng=rng, size=size, n_frames=n_frames)

    def canonical(self, params: np.ndarray) -> np.ndarray:
        """Wrap angles and sort sources by location: shape as ``params``."""
        x = np.array(params, dtype=float)
        blocks = x.reshape(x.shape[:-1] + (self.n_sources_of(x), self.n_loc + 1))
        if self.kind != "position":
            blocks[..., 0] = wrap_angle(blocks[..., 0])
        if blocks.shape[-2] < 2:
            return x  # one source: nothing to sort (blocks is a view of x)
        rows = blocks.reshape(-1, *blocks.shape[-2:])  # (T, K, d + 1): one row per scene
        order = np.argsort(rows[..., 0], axis=-1, kind="stable")
        return rows[np.arange(rows.shape[0])[:, None], order].reshape(x.shape)

    def __repr__(self) -> str:
        # sigma is the model's own only under the default noise; else the noise says it
        head = f"sigma={self.sigma!r}" if self.noise.is_default else f"noise={self.noise!r}"
        extra = "" if self.nuisance.is_trivial else f", nuisance={self.nuisance!r}"
        return f"Model({self.array!r}, {head}, sensitivity={self.sensitivity!r}{extra})"
