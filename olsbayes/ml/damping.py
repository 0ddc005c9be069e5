"""The damping schedule of Levenberg–Marquardt, shared by the numpy and compiled paths.

A run starts with damping :data:`START`; an accepted step divides it by
:data:`DOWN` (not below :data:`FLOOR`), a rejected one multiplies it by :data:`UP`.
Above :data:`MAX` no descent step is representable: the point is a local minimum
to working precision (e.g. on the kink of the clipped cosine) and the run stops
*stalled*.  The damped matrix adds ``lambda * max(A_ii, EIG_FLOOR * max_j A_jj)``
to each diagonal entry, so a parameter the data do not constrain still gets a
finite step.
"""

from __future__ import annotations

__all__ = ["START", "DOWN", "UP", "FLOOR", "MAX", "EIG_FLOOR"]

START = 1e-3
DOWN = 5.0
UP = 8.0
FLOOR = 1e-12
MAX = 1e14
EIG_FLOOR = 1e-9
