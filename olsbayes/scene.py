"""The user's view of a parameter vector: source locations and intensities."""

from __future__ import annotations

from dataclasses import InitVar, dataclass, field

import numpy as np

from ._validation import choice, finite_array
from .circular import wrap_angle
from .errors import InputError

__all__ = ["Scene", "ANGLE_UNITS"]

#: Units a Scene accepts for ``directions`` (stored in rad whatever the unit given).
ANGLE_UNITS = ("rad", "deg")


@dataclass(frozen=True, eq=False)
class Scene:
    """K point sources: where they are and how bright.

    Parameters
    ----------
    directions : array_like, shape (K,) or (K, 2), optional
        Ring: angles (wrapped to (-pi, pi]).  Sphere: (longitude, latitude) pairs,
        latitude in [-pi/2, pi/2] (or [-90, 90] deg).  In ``unit``; stored in rad.
    intensities : array_like, shape (K,)
        Source intensities I[k] >= 0 (units of the sub-sensor reading).
    positions : array_like, shape (K, 3), optional
        Near sources (plate): 3-D positions, instead of ``directions``.
    unit : {"rad", "deg"}
        Unit of ``directions``.  Degrees must lie within one turn: ring angles and
        longitudes in [-360, 360], latitudes in [-90, 90]; a value beyond (e.g.
        370) is refused with :class:`~olsbayes.errors.InputError` instead of
        wrapped.  The stored ``directions`` are in rad (wrapped to (-pi, pi]).

    Notes
    -----
    Exactly one of ``directions`` and ``positions`` is given.  A scene with
    K = 0 sources (noise only) is allowed.
    """

    directions: np.ndarray | None = None
    intensities: np.ndarray = field(default_factory=lambda: np.zeros(0))
    positions: np.ndarray | None = None
    unit: InitVar[str] = "rad"

    def __post_init__(self, unit: str = "rad") -> None:
        if (self.directions is None) == (self.positions is None):
            raise InputError("Scene needs exactly one of directions= and positions=")
        choice("unit", unit, ANGLE_UNITS)
        if unit == "deg" and self.positions is not None:
            raise InputError("unit='deg' applies to directions; positions are lengths")
        inten = finite_array(
            "intensities", self.intensities, ndim=1, nonnegative=True, allow_empty=True
        )
        k = inten.shape[0]
        if self.positions is not None:
            loc = finite_array("positions", self.positions, ndim=2, last=3, allow_empty=True)
            name = "positions"
        else:
            loc = finite_array("directions", self.directions, ndim=(1, 2), allow_empty=True)
            name = "directions"
            if unit == "deg":
                loc = _degrees_to_rad(loc)
            if loc.ndim == 2:
                if loc.shape[1] != 2:
                    raise InputError(
                        f"directions must have shape (K,) for a ring or (K, 2) "
                        f"(longitude, latitude) for a sphere; got {loc.shape}"
                    )
                if np.any(np.abs(loc[:, 1]) > np.pi / 2 + 1e-12):
                    raise InputError(
                        "directions latitude must be in [-pi/2, pi/2]; got "
                        f"{float(np.abs(loc[:, 1]).max())!r}"
                    )
                loc = np.column_stack([wrap_angle(loc[:, 0]), loc[:, 1]])
            else:
                loc = wrap_angle(loc)
        if loc.shape[0] != k:
            raise InputError(
                f"{name} and intensities must describe the same number of sources; "
                f"got {loc.shape[0]} and {k}"
            )
        for arr in (loc, inten):
            arr.flags.writeable = False
        object.__setattr__(self, name, loc)
        object.__setattr__(self, "intensities", inten)

    @property
    def n_sources(self) -> int:
        """Number K of sources."""
        return int(self.intensities.shape[0])

    @property
    def kind(self) -> str:
        """``"angle"``, ``"lonlat"`` or ``"position"``."""
        if self.positions is not None:
            return "position"
        return "angle" if self.directions.ndim == 1 else "lonlat"

    @property
    def locations(self) -> np.ndarray:
        """Location parameters, shape (K, d) with d = 1, 2 or 3."""
        loc = self.positions if self.positions is not None else self.directions
        return loc.reshape(self.n_sources, -1)

    def sorted(self) -> "Scene":
        """The same scene in canonical order: by angle, by (lon, lat) or by (x, y, z)."""
        loc = self.locations
        order = np.lexsort(loc.T[::-1]) if loc.shape[0] else np.arange(0)
        return self._take(order)

    def _take(self, order: np.ndarray) -> "Scene":
        if self.positions is not None:
            return Scene(positions=self.positions[order], intensities=self.intensities[order])
        return Scene(directions=self.directions[order], intensities=self.intensities[order])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Scene):
            return NotImplemented
        return self.kind == other.kind and np.array_equal(
            self.locations, other.locations
        ) and np.array_equal(self.intensities, other.intensities)

    def __repr__(self) -> str:
        loc = "positions" if self.positions is not None else "directions"
        return (
            f"Scene({loc}={np.array2string(getattr(self, loc), precision=4)}, "
            f"intensities={np.array2string(self.intensities, precision=4)})"
        )


def _degrees_to_rad(loc: np.ndarray) -> np.ndarray:
    """Directions in deg -> rad, refusing values beyond one turn (or |latitude| > 90)."""
    ang = loc if loc.ndim == 1 else loc[:, 0]
    if ang.size and np.abs(ang).max() > 360.0:
        what = "angles" if loc.ndim == 1 else "longitudes"
        raise InputError(f"directions {what} in deg must lie in [-360, 360]; got "
                         f"{float(ang[np.argmax(np.abs(ang))])!r}")
    if loc.ndim == 2 and loc.shape[1] == 2 and loc.size and np.abs(loc[:, 1]).max() > 90.0:
        raise InputError(f"directions latitudes in deg must lie in [-90, 90]; got "
                         f"{float(loc[np.argmax(np.abs(loc[:, 1])), 1])!r}")
    out = np.deg2rad(loc)
    if loc.ndim == 2 and loc.shape[1] == 2:  # +-90 deg exactly: keep the pole inside the range
        out[:, 1] = np.clip(out[:, 1], -np.pi / 2, np.pi / 2)
    return out
