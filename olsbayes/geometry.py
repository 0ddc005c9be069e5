"""Sub-sensor arrays: where the sub-sensors sit and which way they face.

Three kinds of source space follow from an array:

* ``"angle"`` -- a planar array of 2-D normals (the 1-D model of Fig. 1a, the
  :class:`Ring`); a distant source is one angle in rad, wrapped to (-pi, pi].
* ``"lonlat"`` -- an array of 3-D normals (the sphere of Fig. 1b); a distant source
  is a (longitude, latitude) pair in rad.
* ``"position"`` -- an array with sub-sensor positions (the plate of Fig. 1c); a
  near source is a 3-D position (same length unit as the positions) and its
  response also falls as 1/r^2.

The geometry knows nothing of sources' intensities, sensitivity laws or noise.
"""

from __future__ import annotations

import numpy as np

from ._budget import check_sensors
from ._frozen import Frozen
from ._validation import finite_array, integer, positive_float
from .circular import TWO_PI, wrap_angle
from .errors import InputError

__all__ = ["SensorArray", "Ring", "Sphere", "Plate"]


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=float)
    a.flags.writeable = False
    return a


class SensorArray(Frozen):
    """Any array of sub-sensors, e.g. one a user measured (immutable).

    Parameters
    ----------
    normals : array_like, shape (N, 2) or (N, 3)
        Outward surface normals of the N sub-sensors; normalised to unit length.
        2-D normals describe a planar array for distant sources (angles), 3-D
        normals a spatial array for distant sources (longitude, latitude).
    positions : array_like, shape (N, 3), optional
        Sub-sensor positions for sources close to the array.  When given, the
        normals must be 3-D and sources are 3-D positions.
    """

    def __init__(self, normals: np.ndarray, positions: np.ndarray | None = None):
        nrm = finite_array("normals", normals, ndim=2)
        if nrm.shape[1] not in (2, 3):
            raise InputError(
                f"normals must have shape (N, 2) or (N, 3); got {nrm.shape}"
            )
        if nrm.shape[0] < 3:
            raise InputError(
                f"an array needs n >= 3 sub-sensors; got {nrm.shape[0]}"
            )
        length = np.linalg.norm(nrm, axis=1)
        if np.any(length < 1e-12):
            raise InputError("normals must be non-zero vectors; got a zero row")
        self._normals = _readonly(nrm / length[:, None])
        self._positions = None
        if positions is not None:
            pos = finite_array("positions", positions, ndim=2, last=3)
            if nrm.shape[1] != 3 or pos.shape[0] != nrm.shape[0]:
                raise InputError(
                    "positions must have shape (N, 3) matching 3-D normals of shape "
                    f"(N, 3); got positions {pos.shape} and normals {nrm.shape}"
                )
            self._positions = _readonly(pos)

    @property
    def normals(self) -> np.ndarray:
        """Unit normals, shape (N, D) with D = 2 or 3."""
        return self._normals

    @property
    def positions(self) -> np.ndarray | None:
        """Sub-sensor positions, shape (N, 3), or None for distant sources."""
        return self._positions

    @property
    def n_sensors(self) -> int:
        """Number N of sub-sensors."""
        return self._normals.shape[0]

    @property
    def source_kind(self) -> str:
        """``"angle"``, ``"lonlat"`` or ``"position"`` (see module docstring)."""
        if self._positions is not None:
            return "position"
        return "angle" if self._normals.shape[1] == 2 else "lonlat"

    @property
    def n_source_params(self) -> int:
        """Number of location parameters per source: 1, 2 or 3."""
        return {"angle": 1, "lonlat": 2, "position": 3}[self.source_kind]

    def __len__(self) -> int:
        return self.n_sensors

    def __repr__(self) -> str:
        return f"{type(self).__name__}(n_sensors={self.n_sensors}, kind={self.source_kind!r})"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, SensorArray):
            return NotImplemented
        same_pos = (self.positions is None and other.positions is None) or (
            self.positions is not None
            and other.positions is not None
            and np.array_equal(self.positions, other.positions)
        )
        return same_pos and np.array_equal(self.normals, other.normals)

    __hash__ = None  # type: ignore[assignment]


class Ring(SensorArray):
    """N sub-sensors on a circle, normals at ``offset + 2*pi*k/n`` (Fig. 1a).

    Parameters
    ----------
    n : int
        Number of sub-sensors, n >= 3.
    offset : float
        Angle of the first normal in rad.
    """

    def __init__(self, n: int, offset: float = 0.0):
        self.n = integer("n", n, low=3)
        check_sensors(f"Ring(n={self.n})", self.n)
        off = finite_array("offset", offset, ndim=0)
        self.offset = float(off)
        self.angles = _readonly(wrap_angle(self.offset + TWO_PI * np.arange(self.n) / self.n))
        super().__init__(np.column_stack([np.cos(self.angles), np.sin(self.angles)]))

    @property
    def spacing(self) -> float:
        """Angular spacing 2*pi/n between neighbouring sub-sensors (rad)."""
        return TWO_PI / self.n

    def __repr__(self) -> str:
        return f"Ring(n={self.n}, offset={self.offset!r})"


def lonlat_to_unit(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """Unit vectors, shape (..., 3), of longitudes and latitudes in rad."""
    cl = np.cos(lat)
    return np.stack([cl * np.cos(lon), cl * np.sin(lon), np.sin(lat)], axis=-1)


class Sphere(SensorArray):
    """Sub-sensors on a sphere for distant sources (Fig. 1b).

    Build one with :meth:`grid` or :meth:`fibonacci`; ``lon`` and ``lat`` hold the
    sub-sensors' longitudes and latitudes (rad).
    """

    def __init__(self, lon: np.ndarray, lat: np.ndarray):
        lon = finite_array("lon", lon, ndim=1)
        lat = finite_array("lat", lat, ndim=1)
        if lon.shape != lat.shape:
            raise InputError(f"lon and lat must have equal shapes; got {lon.shape} and {lat.shape}")
        if np.any(np.abs(lat) > np.pi / 2 + 1e-12):
            raise InputError("lat must be in [-pi/2, pi/2]; got a value outside")
        self.lon = _readonly(wrap_angle(lon))
        self.lat = _readonly(lat)
        super().__init__(lonlat_to_unit(self.lon, self.lat))

    @classmethod
    def grid(
        cls,
        n_lat: int,
        n_lon: int,
        lat_max: float = np.pi / 2.05,
        lon_range: tuple[float, float] = (-np.pi, np.pi),
    ) -> "Sphere":
        """A latitude-longitude grid of ``n_lat * n_lon`` sub-sensors.

        Grid convention: latitudes are ``n_lat`` equally spaced values from
        ``-lat_max`` to ``+lat_max`` *including both endpoints*.  Longitudes are
        equally spaced over ``lon_range``; when the range spans the full circle
        (2*pi) the end point is dropped so no meridian is duplicated (spacing
        2*pi/n_lon), otherwise both endpoints are included.  The Fig. 2 sensor is
        ``Sphere.grid(15, 20, np.pi / 2.05)``.  Order: latitude-major.
        """
        n_lat = integer("n_lat", n_lat, low=1)
        n_lon = integer("n_lon", n_lon, low=1)
        if n_lat * n_lon < 3:
            raise InputError(f"n_lat * n_lon must be >= 3; got {n_lat * n_lon}")
        check_sensors(f"Sphere.grid(n_lat={n_lat}, n_lon={n_lon})", n_lat * n_lon)
        lat_max = positive_float("lat_max", lat_max, upper=np.pi / 2)
        bounds = finite_array("lon_range", lon_range, ndim=1)
        span = bounds[1] - bounds[0] if bounds.shape == (2,) else np.nan
        if not 0 < span <= TWO_PI + 1e-12:
            raise InputError(
                f"lon_range must be (lo, hi) with lo < hi and hi - lo <= 2*pi; got {lon_range!r}"
            )
        lo, hi = float(bounds[0]), float(bounds[1])
        full = abs((hi - lo) - TWO_PI) < 1e-9
        lons = np.linspace(lo, hi, n_lon, endpoint=not full) if n_lon > 1 else np.array([lo])
        lats = np.linspace(-lat_max, lat_max, n_lat) if n_lat > 1 else np.array([0.0])
        lat_g, lon_g = np.meshgrid(lats, lons, indexing="ij")
        return cls(lon_g.ravel(), lat_g.ravel())

    @classmethod
    def fibonacci(cls, n: int) -> "Sphere":
        """``n`` near-uniform sub-sensors on the whole sphere (Fibonacci lattice)."""
        n = integer("n", n, low=3)
        check_sensors(f"Sphere.fibonacci(n={n})", n)
        k = np.arange(n) + 0.5
        lat = np.arcsin(1.0 - 2.0 * k / n)
        lon = wrap_angle(np.pi * (1.0 + 5.0**0.5) * k)
        return cls(lon, lat)


class Plate(SensorArray):
    """A flat array facing +z, for sources close to it (Fig. 1c).

    Sources are 3-D positions with z > 0 in the same length unit as ``pitch``.

    Parameters
    ----------
    normals, positions : array_like, shape (N, 3)
        As for :class:`SensorArray`.
    pitch : float, optional
        Spacing of a regular grid of sub-sensors (set by :meth:`grid`).
    """

    def __init__(self, normals: np.ndarray, positions: np.ndarray,
                 pitch: float | None = None):
        super().__init__(normals, positions)
        self.pitch = None if pitch is None else positive_float("pitch", pitch)

    @classmethod
    def grid(cls, nx: int, ny: int, pitch: float = 1.0) -> "Plate":
        """``nx * ny`` sub-sensors on a square grid of spacing ``pitch``, centred at 0."""
        nx = integer("nx", nx, low=1)
        ny = integer("ny", ny, low=1)
        if nx * ny < 3:
            raise InputError(f"nx * ny must be >= 3; got {nx * ny}")
        check_sensors(f"Plate.grid(nx={nx}, ny={ny})", nx * ny)
        pitch = positive_float("pitch", pitch)
        x = (np.arange(nx) - (nx - 1) / 2.0) * pitch
        y = (np.arange(ny) - (ny - 1) / 2.0) * pitch
        gx, gy = np.meshgrid(x, y, indexing="ij")
        pos = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
        normals = np.tile([0.0, 0.0, 1.0], (gx.size, 1))
        return cls(normals, pos, pitch)
