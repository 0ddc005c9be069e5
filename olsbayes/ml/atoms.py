"""Candidate source locations ("atoms") for the matched-filter search.

An atom is the noiseless response of one unit-intensity source at a grid
location: ``model.response([loc..., 1.0])``, shape (N,).  The grid only has to
put every true source inside the basin of attraction of the subsequent
Levenberg–Marquardt refinement, i.e. a fraction of the array's resolution.
"""

from __future__ import annotations

import hashlib

import numpy as np

from .._budget import check_memory
from .._notice import notice
from .._validation import finite_array, positive_float
from ..circular import wrap_angle
from ..errors import InputError
from ..model import Model
from ..sensitivity import is_clipped_cosine

__all__ = ["default_grid", "default_grid_size", "cached_default_grid", "check_grid",
           "check_atom_memory", "atoms", "grid_step", "NEIGHBOUR", "RING_ATOMS_MAX",
           "gram_from_arcs", "SPHERE_ATOMS", "GRAM_ATOMS", "ARC_GRAM_SENSORS", "NOTICE_ENTRIES",
           "NOTICE_GRAM"]

#: Normalised-atom correlation above which two atoms count as one basin (the
#: neighbourhood of an atom in the searches of the fast fit).
NEIGHBOUR = 0.95

#: Largest default ring grid (angles), and the range of the default sphere grid
#: (directions).  An atom's correlation with its neighbours depends on their angular
#: distance, not on N, once the sub-sensors sample the cosine law finely, so a grid
#: of fixed angular spacing keeps every source inside a refinement basin at any N;
#: the caps keep the search's cost per fit linear in N.
RING_ATOMS_MAX = 1024
SPHERE_ATOMS = (1024, 2048)

#: Largest M for which the fast search forms the atoms' Gram matrix (M^2 doubles) for
#: its projections: every default ring and sphere grid (:data:`SPHERE_ATOMS`).  The
#: coarse subsets' sampling reuses that matrix (:mod:`olsbayes.ml.fast.coarse`).
GRAM_ATOMS = 2048

#: Above this many sub-sensors the Gram matrix of a ring's clipped-cosine atoms comes
#: from the arcs of sub-sensors they light (:func:`olsbayes.ml._numba.search.arc_gram`,
#: O(M^2 + N)) instead of ``G @ G.T`` (O(M^2 N): 5 s for the default 1024 atoms of a
#: 100,000-ring); at or below it the product costs at most ~0.1 s once per model and
#: keeps the smaller rings' fits to the bit (the two agree to rounding).
ARC_GRAM_SENSORS = 2048


def _ring_grid(model: Model, density: float) -> np.ndarray:
    m = int(min(max(128, np.ceil(density * model.n_sensors)), RING_ATOMS_MAX))
    return (wrap_angle(2 * np.pi * (np.arange(m) + 0.5) / m))[:, None]


def _sphere_grid(model: Model, density: float) -> np.ndarray:
    m = int(np.clip(np.ceil(density * model.n_sensors), *SPHERE_ATOMS))
    k = np.arange(m) + 0.5
    lat = np.arcsin(1.0 - 2.0 * k / m)
    lon = wrap_angle(np.pi * (1.0 + 5.0**0.5) * k)
    return np.column_stack([lon, lat])


def _plate_grid(model: Model, density: float) -> np.ndarray:
    pos = model.array.positions
    lo, hi = pos[:, :2].min(axis=0), pos[:, :2].max(axis=0)
    ext = float(max(np.max(hi - lo), 1e-12))
    diffs = np.abs(pos[:, None, :2] - pos[None, :, :2]).ravel()
    pitch = float(np.min(diffs[diffs > 1e-12 * ext])) if np.any(diffs > 1e-12 * ext) else ext
    step = pitch / max(density / 8.0, 0.25)
    pad = 0.5 * ext
    xs = np.arange(lo[0] - pad, hi[0] + pad + 1e-9, step)
    ys = np.arange(lo[1] - pad, hi[1] + pad + 1e-9, step)
    zs = np.geomspace(0.5 * pitch, 2.0 * ext + pitch, 10)
    gx, gy, gz = np.meshgrid(xs, ys, zs, indexing="ij")
    return np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])


def default_grid(model: Model, density: float | None = None) -> np.ndarray:
    """Default candidate locations, shape (M, d).

    ``density`` defaults to 4 (ring, sphere) or 8 (plate).
    Ring: ``max(128, density * N)`` equally spaced angles, at most
    :data:`RING_ATOMS_MAX` (1024: 0.35 deg apart).  Sphere: a Fibonacci lattice of
    ``density * N`` directions over the whole sphere, clipped to
    :data:`SPHERE_ATOMS` ([1024, 2048]: about 7 to 4.5 deg apart).  Plate: an
    (x, y, z) grid over the plate's extent padded by half of it, xy step
    ``8 * pitch / density``, 10 geometric z levels from pitch/2 to twice the extent
    (override with ``grid=`` for other source volumes).
    """
    if density is None:
        density = 8.0 if model.kind == "position" else 4.0
    density = positive_float("density", density)
    if model.kind == "position":  # the pitch comes from all pairs of sub-sensors
        check_memory(f"the default plate grid of {model.n_sensors} sub-sensors (all pairs)",
                     16.0 * model.n_sensors**2)
    if model.kind == "angle":
        return _ring_grid(model, density)
    if model.kind == "lonlat":
        return _sphere_grid(model, density)
    return _plate_grid(model, density)


def default_grid_size(model: Model) -> int:
    """Number M of locations of :func:`default_grid` at the default density.

    Counted without building the grid for rings and spheres (a plate's grid is
    built, and cached, to count it).
    """
    if model.kind == "angle":
        return int(min(max(128, np.ceil(4.0 * model.n_sensors)), RING_ATOMS_MAX))
    if model.kind == "lonlat":
        return int(np.clip(np.ceil(4.0 * model.n_sensors), *SPHERE_ATOMS))
    return int(cached_default_grid(model).shape[0])


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def cached_default_grid(model: Model) -> np.ndarray:
    """:func:`default_grid` of a model at the default density, cached on the model.

    The cached grid is read-only.
    """
    return model.memo("default_grid", lambda: _readonly(default_grid(model)))


def check_atom_memory(model: Model, n_grid: int, n_rows: int) -> None:
    """Refuse a fast fit whose atoms (M, N) and search arrays exceed the memory budget.

    ``n_grid`` candidate locations M, ``n_rows`` data vectors searched together; the
    search keeps a few (rows, M) arrays besides the (M, N) atoms.
    """
    n = model.n_sensors
    check_memory(f"the fast fit's {n_grid} candidate locations x {n} sub-sensors "
                 f"({n_rows} data vectors at once)", 8.0 * n_grid * (n + 6 * n_rows))


def check_grid(model: Model, grid: object) -> np.ndarray:
    """Validate a user grid of candidate locations, shape (M, d)."""
    g = finite_array("grid", grid, ndim=(1, 2))
    if g.ndim == 1:
        g = g[:, None]
    if g.shape[1] != model.n_loc:
        raise InputError(
            f"grid must have shape (M, {model.n_loc}) for {model.kind!r} sources; got {g.shape}"
        )
    if model.kind == "position" and np.any(g[:, 2] <= 0):
        raise InputError("grid z coordinates must be > 0 (sources in front of the plate)")
    if model.kind == "lonlat" and np.any(np.abs(g[:, 1]) > np.pi / 2):
        raise InputError("grid latitudes must be in [-pi/2, pi/2]")
    return g


#: Grids whose atoms a model keeps at once (the default grid and a few user grids).
_ATOM_GRIDS = 8

#: Atom matrices of more entries (M N) than this say on stderr that they are being
#: built: with the fast search's unit atoms and coarse subsets beside them the first
#: fit then takes more than ~5 s (a 40 x 40 plate, 62,410 x 1,600 entries: 6-8 s).
NOTICE_ENTRIES = 50_000_000
#: So do atoms whose Gram matrix (at most :data:`GRAM_ATOMS` atoms) costs more
#: multiply-adds (M^2 N) than this: it is most of the first fit's set-up on a large
#: sphere (10,000 sub-sensors, 2,048 atoms: 4.2e10, a first fit of 3.2 s CPU on an
#: idle machine and up to 15 s on a busy one; 20,000: 7.6 s idle).
NOTICE_GRAM = 2e10


def _setup_is_long(m: int, n: int, product: bool = True) -> bool:
    """Whether the fast search's set-up on M atoms of N sub-sensors takes seconds.

    ``product``: whether the search forms the atoms' Gram matrix as ``G @ G.T``
    (all but the large rings of :data:`ARC_GRAM_SENSORS`), whose cost then counts.
    """
    gram = product and m <= GRAM_ATOMS and float(m) * m * n > NOTICE_GRAM
    return m * n > NOTICE_ENTRIES or gram


def gram_from_arcs(ring_arcs: bool, n_sensors: int) -> bool:
    """Whether the fast search takes its atoms' Gram matrix from their arcs.

    ``ring_arcs``: the atoms are a clipped-cosine ring's, each lighting one arc of
    sub-sensors; then beyond :data:`ARC_GRAM_SENSORS` sub-sensors.  The one rule for
    the search (:mod:`olsbayes.ml.fast.search`) and for its set-up notice here.
    """
    return ring_arcs and n_sensors > ARC_GRAM_SENSORS


def _gram_by_product(model: Model) -> bool:
    """Whether the fast search forms this model's atoms' Gram matrix as ``G @ G.T``."""
    ring = model.kind == "angle" and is_clipped_cosine(model.sensitivity)
    return not gram_from_arcs(ring, model.n_sensors)


def _responses(model: Model, grid: np.ndarray) -> np.ndarray:
    """The atoms of ``grid`` (read-only), with one stderr line when their set-up is long."""
    if _setup_is_long(grid.shape[0], model.n_sensors, _gram_by_product(model)):
        notice(f"building the search over {grid.shape[0]:,} candidate locations x "
               f"{model.n_sensors:,} sub-sensors (once per model and grid; seconds) ...")
    return _readonly(model.response(np.column_stack([grid, np.ones(grid.shape[0])])))


def atoms(model: Model, grid: np.ndarray) -> np.ndarray:
    """Unit-intensity responses of the grid locations, shape (M, N), read-only.

    Cached on the model (:meth:`~olsbayes.Model.memo`) per grid content, since a
    model's response never changes; the model's own default grid is found by identity.
    Building more than :data:`NOTICE_ENTRIES` entries, or atoms whose Gram matrix
    costs more than :data:`NOTICE_GRAM` multiply-adds, prints one line on stderr.
    """
    if grid is model.memo("default_grid"):
        return model.memo("default_atoms", lambda: _responses(model, grid))
    flat = np.ascontiguousarray(grid, dtype=float)
    key = (flat.shape, hashlib.sha1(flat.view(np.uint8)).hexdigest())
    per_model = model.memo("atoms", dict)
    if key not in per_model:
        if len(per_model) >= _ATOM_GRIDS:
            per_model.clear()
        per_model[key] = _responses(model, grid)
    return per_model[key]


def grid_step(model: Model, grid: np.ndarray) -> np.ndarray:
    """A typical spacing of the grid per location coordinate, shape (d,).

    Used as the scale of the perturbed restarts.  For directions this is the
    angular spacing (rad) of a uniform grid of the same size.
    """
    m = grid.shape[0]
    if model.kind == "angle":
        return np.array([2 * np.pi / m])
    if model.kind == "lonlat":
        return np.full(2, np.sqrt(4 * np.pi / m)) if m else np.ones(2)
    span = np.ptp(grid, axis=0)
    levels = np.array([max(len(np.unique(np.round(grid[:, j], 12))), 2) for j in range(3)])
    return span / (levels - 1)
