"""The user's view of a parameter vector: source locations and intensities."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._validation import finite_array
from .circular import wrap_angle
from .errors import InputError

__all__ = ["Scene"]


@dataclass(frozen=True, eq=False)
class Scene:
    """K point sources: where they are and how bright.

    Parameters
    ----------
    directions : array_like, shape (K,) or (K, 2), optional
        Ring: angles in rad (wrapped to (-pi, pi]).  Sphere: (longitude, latitude)
        pairs in rad, latitude in [-pi/2, pi/2].
    intensities : array_like, shape (K,)
        Source intensities I[k] >= 0 (units of the sub-sensor reading).
    positions : array_like, shape (K, 3), optional
        Near sources (plate): 3-D positions, instead of ``directions``.

    Notes
    -----
    Exactly one of ``directions`` and ``positions`` is given.  A scene with
    K = 0 sources (noise only) is allowed.
    """

    directions: np.ndarray | None = None
    intensities: np.ndarray = field(default_factory=lambda: np.zeros(0))
    positions: np.ndarray | None = None

    def __post_init__(self) -> None:
        if (self.directions is None) == (self.positions is None):
            raise InputError("Scene needs exactly one of directions= and positions=")
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
