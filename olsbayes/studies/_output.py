"""A study's results as an xarray Dataset: dimensions, coordinates and attributes."""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np

from .checkpoint import fingerprint_key
from .grid import Grid

__all__ = ["study_dataset", "first_dataset", "seed_attrs", "dataset_seed"]


def seed_attrs(entropy: int) -> dict[str, Any]:
    """The dataset attributes of a study's root seed: numeric, plus its exact decimal text.

    ``seed`` is an int64 when the seed fits (every seed a user types); a larger
    entropy (128 bits drawn when no seed is given) is stored as an array of uint64
    words, least significant first, that :func:`dataset_seed` reassembles.
    ``seed_decimal`` holds the same number as text.
    """
    if entropy < 2**63:
        return {"seed": np.int64(entropy), "seed_decimal": str(entropy)}
    words = []
    rest = entropy
    while rest:
        words.append(rest & (2**64 - 1))
        rest >>= 64
    return {"seed": np.array(words, dtype=np.uint64), "seed_decimal": str(entropy)}


def dataset_seed(ds: Any) -> int:
    """The root seed of a study dataset (as ``rng`` for :func:`run_study` to repeat it)."""
    seed = ds.attrs["seed"]
    if isinstance(seed, str):  # a seed stored as decimal text
        return int(seed)
    words = np.atleast_1d(np.asarray(seed)).astype(np.uint64)
    return sum(int(w) << (64 * i) for i, w in enumerate(words))


#: Attributes of the trial coordinate.
_TRIAL_ATTRS = {"long_name": "trial index within a grid cell"}


def study_dataset(full: dict, grid: Grid, fingerprint: dict, described: Mapping) -> Any:
    """The Dataset of a finished study.

    ``full`` maps each output's name to its array of shape ``grid.shape +
    (n_trials,) + output shape``; ``described`` maps names to ``(long_name,
    units)``; ``fingerprint`` is the study's record (trial, settings, seed,
    version), kept in the attributes.
    """
    import xarray as xr

    dims = grid.names + ("trial",)
    data_vars = {}
    for name, arr in full.items():
        long_name, units = described.get(name, (name, None))
        attrs = {"long_name": long_name}
        if units:
            attrs["units"] = units
        data_vars[name] = (dims + tuple(f"{name}_dim{i}" for i in range(arr.ndim - len(dims))),
                           arr, attrs)
    coords = dict(grid.coords())
    coords["trial"] = ("trial", np.arange(fingerprint["n_trials"]), _TRIAL_ATTRS)
    attrs = {
        **seed_attrs(int(fingerprint["seed"])),
        "olsbayes_version": fingerprint["olsbayes_version"],
        "trial_function": fingerprint["trial"],
        "vectorized": int(fingerprint["vectorized"]),
        "n_trials": fingerprint["n_trials"],
        "grid": json.dumps(fingerprint["grid"]),
        "fixed_settings": json.dumps(fingerprint["fixed"]),
        "study_key": fingerprint_key(fingerprint),
    }
    return xr.Dataset(data_vars, coords=coords, attrs=attrs)


def first_dataset() -> None:
    """Import xarray and make a one-element Dataset, as a thread while a study's workers run.

    A process's first Dataset also imports ``dask.array`` where dask is installed
    (xarray's check for dask arrays): with the import of xarray, 0.5-1.2 s of CPU
    that :func:`study_dataset` would otherwise pay after the last chunk.
    """
    try:
        import xarray as xr

        xr.Dataset({"x": ("i", np.zeros(1))})
    except Exception:  # noqa: BLE001, S110 - study_dataset itself reports a broken xarray
        pass
