"""The Fig. 2 imaging scene: the "OLSS" bitmap, its source grid and sensor grids.

Paper (Fig. 2): a sphere of 15 x 20 = 300 sub-sensors within +-pi longitude and
+-pi/2.05 latitude; 19 x 16 = 304 sources at known directions within +-pi/2
longitude and +-pi/3 latitude forming "OLSS" with intensities 0/1; sigma = 0.01.

Grid conventions (the paper states none, and the answer depends on them):

* sources: 19 longitudes x 16 latitudes (19 columns fit four 4-pixel letters
  with three 1-pixel gaps), either ``"endpoints"`` (linspace including the
  range ends, spacing pi/18 and 2pi/45) or ``"centres"`` (centres of 19 x 16
  equal cells);
* sensors: ``"grid"`` is ``Sphere.grid(15, 20, pi/2.05)`` -- 20 distinct
  meridians 18 deg apart (the endpoint pi = -pi is not repeated); ``"linspace"``
  is what ``linspace(-pi, pi, 20)`` gives in Matlab -- both ends kept, so the
  meridian at +-pi is doubled and only 19 distinct meridians remain.

The bitmap is an easier scene than the paper's figure.  Its letters are 11 rows
tall with 68 bright pixels; those of the paper's figure are about 12 rows tall with
about 73.  ``olss_bitmap(letter_rows=12)`` builds such a mask (73 pixels), and on it
the bounded posterior mode errs about twice as much: error sd 0.076 instead of 0.037
(sensors ``linspace``, sources ``endpoints``; 0.046 and 0.044 with sources
``centres``), against the paper's 0.0640 -- 40 noise draws each,
``python analyses/fig2_imaging.py --full --mode-only --letter-rows 12`` (and
``--letter-rows 11``).  The errors come from a few pixels the array cannot tell
apart, so another seed moves them by about 0.005-0.01.  Compare the paper's number
with the 12-row mask; the 11-row one is kept as the default so earlier results
stay comparable.

Why it matters: with the clipped cosine, ``g(c) - g(-c) = c``, so a sub-sensor
and its antipode together read a *linear* function of the source's unit vector;
with 20 (even) meridians and symmetric latitudes every sub-sensor has an
antipode and the design matrix loses rank massively (rank 135 of 300), while
with 19 distinct meridians no antipodal pairs exist (rank 251).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..geometry import Sphere

__all__ = ["OLSS_ROWS", "olss_bitmap", "olss_directions", "fig2_sphere", "SIGMA"]

SIGMA = 0.01

def _letters(height: int) -> list[str]:
    """The rows of "OLSS" in 4-pixel letters ``height`` rows tall, 1-pixel gaps."""
    o = [".##."] + ["#..#"] * (height - 2) + [".##."]
    el = ["#..."] * (height - 1) + ["####"]
    upper = (height - 3) // 2  # rows of the S's upper stroke; the lower one gets the rest
    s = [".###"] + ["#..."] * upper + [".##."] + ["...#"] * (height - 3 - upper) + ["###."]
    return [".".join(r) for r in zip(o, el, s, s)]


#: 16 rows (north at the top) of 19 columns (west at the left): 11-row letters.
OLSS_ROWS: tuple[str, ...] = tuple(["." * 19] * 2 + _letters(11) + ["." * 19] * 3)


def olss_bitmap(letter_rows: int = 11) -> np.ndarray:
    """The "OLSS" bitmap, shape (16, 19), 1.0 bright / 0.0 dark, row 0 = north.

    Parameters
    ----------
    letter_rows : {11, 12}
        Height of the letters.  11 (the default, :data:`OLSS_ROWS`): 68 bright
        pixels.  12: 73 bright pixels, closer to the paper's figure (see the
        module notes: an easier scene at 11 rows).
    """
    if letter_rows == 11:
        rows = OLSS_ROWS
    elif letter_rows == 12:
        rows = tuple(["." * 19] * 2 + _letters(12) + ["." * 19] * 2)
    else:
        raise InputError(f"letter_rows must be 11 or 12; got {letter_rows!r}")
    return np.array([[ch == "#" for ch in row] for row in rows], dtype=float)


def olss_directions(convention: str = "endpoints") -> np.ndarray:
    """Source directions (lon, lat) in rad, shape (304, 2), in bitmap order (row-major).

    Parameters
    ----------
    convention : {"endpoints", "centres"}
        Grid convention inside +-pi/2 longitude and +-pi/3 latitude.
    """
    if convention == "endpoints":
        lon = np.linspace(-np.pi / 2, np.pi / 2, 19)
        lat = np.linspace(-np.pi / 3, np.pi / 3, 16)
    elif convention == "centres":
        lon = -np.pi / 2 + (np.arange(19) + 0.5) * np.pi / 19
        lat = -np.pi / 3 + (np.arange(16) + 0.5) * (2 * np.pi / 3) / 16
    else:
        raise InputError(f"convention must be 'endpoints' or 'centres'; got {convention!r}")
    lat_g, lon_g = np.meshgrid(lat[::-1], lon, indexing="ij")  # row 0 = north
    return np.column_stack([lon_g.ravel(), lat_g.ravel()])


def fig2_sphere(convention: str = "grid") -> Sphere:
    """The 15 x 20 sub-sensor sphere of Fig. 2 (see module notes for conventions)."""
    if convention == "grid":
        return Sphere.grid(15, 20, np.pi / 2.05)
    if convention == "linspace":
        lat = np.linspace(-np.pi / 2.05, np.pi / 2.05, 15)
        lon = np.linspace(-np.pi, np.pi, 20)
        lat_g, lon_g = np.meshgrid(lat, lon, indexing="ij")
        return Sphere(lon_g.ravel(), lat_g.ravel())
    raise InputError(f"convention must be 'grid' or 'linspace'; got {convention!r}")
