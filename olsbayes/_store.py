"""Results to files and back: a JSON tree of the fields plus the arrays, in NetCDF.

A result (a frozen dataclass) is written as one NetCDF-4 file that xarray and
any netCDF tool open: every array field becomes a variable, and the attribute
``olsbayes_tree`` holds a JSON description of the result in which each array is
a reference ``{"__array__": name}`` to its variable.  Reading it back rebuilds
the same objects -- the arrays bit for bit -- so a loaded result equals the
saved one.

Only the package's own classes are rebuilt (an allow-list, no code is run from
a file): the results and their parts, the models, sensor arrays, sensitivity
laws and priors.  Sensor arrays, laws and scene priors are stored by their
state, exactly as pickle would, without pickle's ability to run arbitrary code;
a model by its array, noise sd and law (its caches are rebuilt).  A
user-defined sensitivity law (a Python function) cannot be stored; its model is
written as ``{"__unstorable__": ...}`` and a loader then needs the model passed in.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ._io import atomic_path
from ._validation import file_path
from .errors import InputError

__all__ = ["encode", "decode", "save_result", "load_result", "storable", "UnstorableModel"]

#: Attribute holding the JSON tree.
TREE_ATTR = "olsbayes_tree"
#: Attribute naming the stored class.
TYPE_ATTR = "olsbayes_type"
#: State entries that are caches, rebuilt on use.
_CACHES = frozenset({"_memo", "_fast_cache"})


class UnstorableModel:
    """Placeholder of a model that could not be stored (a custom sensitivity law)."""

    def __init__(self, description: str):
        self.description = description

    def __repr__(self) -> str:
        return f"UnstorableModel({self.description!r})"


#: The result classes a file may name, registered by :func:`storable` where they are defined.
_RESULTS: dict[str, type] = {}


def storable(cls: type) -> type:
    """Class decorator: let a stored file name ``cls`` (it joins the allow-list).

    The result classes register themselves where they are defined, so this module
    does not import the wings above it.
    """
    _RESULTS[cls.__name__] = cls
    return cls


def _registry() -> dict[str, type]:
    """The classes a file may name: the registered results, models, arrays, laws, priors."""
    from . import geometry, noise, sensitivity
    from .model import Model
    from .nuisance import Nuisance
    from .priors import scene as scene_priors
    from .priors import univariate

    classes = [Model, geometry.SensorArray, geometry.Ring, geometry.Sphere, geometry.Plate,
               sensitivity.Cosine, sensitivity.CosinePower, scene_priors.ScenePrior, Nuisance,
               noise.GaussianKnown, noise.GaussianUnknown, noise.GaussianPerSensor,
               noise.Poisson]
    classes += [getattr(univariate, name) for name in univariate.__all__ if name != "Prior"]
    return {**_RESULTS, **{cls.__name__: cls for cls in classes}}


def _stateful(obj: object) -> bool:
    """Objects stored by their state (``__getstate__``), not by constructor fields."""
    from .geometry import SensorArray
    from .model import Model
    from .priors import ScenePrior
    from .sensitivity import Cosine, CosinePower

    return isinstance(obj, (Model, SensorArray, Cosine, CosinePower, ScenePrior))


def _scalar(obj: Any) -> tuple[bool, Any]:
    """(True, JSON value) for None, bool, int, float, str and numpy scalars."""
    if obj is None or isinstance(obj, (bool, str)):
        return True, obj
    if isinstance(obj, np.bool_):
        return True, bool(obj)
    if isinstance(obj, (int, np.integer)):
        return True, int(obj)
    if isinstance(obj, (float, np.floating)):
        x = float(obj)
        return True, x if math.isfinite(x) else {"__float__": repr(x)}
    return False, None


def _join(path: str, key: object) -> str:
    return f"{path}.{key}" if path else str(key)


def encode(obj: Any, arrays: dict[str, np.ndarray], path: str = "") -> Any:
    """The JSON tree of ``obj``; its arrays are added to ``arrays`` under unique names.

    Parameters
    ----------
    obj : object
        A result, a part of one, or a plain value (None, bool, int, float, str,
        ndarray, tuple, list, mapping).
    arrays : dict
        Receives ``{name: ndarray}`` for every array met.
    path : str
        Name prefix of the arrays (dotted field path).
    """
    from .sensitivity import CustomSensitivity

    done, value = _scalar(obj)
    if done:
        return value
    if isinstance(obj, np.ndarray):
        name = path or "value"
        while name in arrays:
            name += "_"
        arrays[name] = obj
        return {"__array__": name}
    if isinstance(obj, tuple):
        return {"__tuple__": [encode(v, arrays, _join(path, i)) for i, v in enumerate(obj)]}
    if isinstance(obj, list):
        return [encode(v, arrays, _join(path, i)) for i, v in enumerate(obj)]
    if isinstance(obj, Mapping):
        return {"__map__": [[encode(k, arrays, _join(path, f"k{i}")),
                             encode(v, arrays, _join(path, i))]
                            for i, (k, v) in enumerate(obj.items())]}
    name = type(obj).__name__
    registry = _registry()
    if dataclasses.is_dataclass(obj) and name in registry:
        fields = {f.name: encode(getattr(obj, f.name), arrays, _join(path, f.name))
                  for f in dataclasses.fields(obj) if f.init}
        return {"__class__": name, "fields": fields}
    if isinstance(getattr(obj, "sensitivity", None), CustomSensitivity):
        return {"__unstorable__": repr(obj)}
    if name == "Model" and name in registry:  # rebuilt by its constructor: caches recomputed
        spec = {"array": encode(obj.array, arrays, _join(path, "array")),
                "sigma": obj.sigma,
                "sensitivity": encode(obj.sensitivity, arrays, _join(path, "sensitivity"))}
        if not obj.noise.is_default:  # other noise models and nuisance terms, when present
            spec["noise"] = encode(obj.noise, arrays, _join(path, "noise"))
        if not obj.nuisance.is_trivial:
            spec["nuisance"] = encode(obj.nuisance, arrays, _join(path, "nuisance"))
        return {"__model__": spec}
    if _stateful(obj) and name in registry:
        state = {k: v for k, v in obj.__getstate__().items() if k not in _CACHES}
        return {"__state__": name,
                "fields": {k: encode(v, arrays, _join(path, k)) for k, v in state.items()}}
    raise InputError(f"cannot store an object of type {name} ({path or 'the result'})")


def decode(tree: Any, arrays: Mapping[str, np.ndarray], model: Any = None) -> Any:
    """The objects of a tree written by :func:`encode`.

    ``model``, when given, replaces every stored model (required where a model
    could not be stored).
    """
    if isinstance(tree, list):
        return [decode(v, arrays, model) for v in tree]
    if not isinstance(tree, dict):
        return tree
    if "__float__" in tree:
        return float(tree["__float__"])
    if "__array__" in tree:
        return np.array(arrays[tree["__array__"]])
    if "__tuple__" in tree:
        return tuple(decode(v, arrays, model) for v in tree["__tuple__"])
    if "__map__" in tree:
        return {decode(k, arrays, model): decode(v, arrays, model) for k, v in tree["__map__"]}
    if "__unstorable__" in tree:
        return UnstorableModel(tree["__unstorable__"]) if model is None else model
    if "__model__" in tree:
        if model is not None:
            return model
        from .model import Model

        spec = tree["__model__"]
        noise = decode(spec["noise"], arrays) if "noise" in spec else None
        return Model(decode(spec["array"], arrays), None if noise else spec["sigma"],
                     decode(spec["sensitivity"], arrays), noise=noise,
                     nuisance=decode(spec.get("nuisance"), arrays))
    registry = _registry()
    name = tree.get("__class__") or tree.get("__state__")
    if name not in registry:
        raise InputError(f"the file names an unknown class {name!r}")
    cls = registry[name]
    fields = {k: decode(v, arrays, model) for k, v in tree["fields"].items()}
    if "__class__" in tree:
        return cls(**fields)
    obj = cls.__new__(cls)
    for value in fields.values():
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
    if hasattr(obj, "__setstate__"):
        obj.__setstate__(fields)
    else:
        obj.__dict__.update(fields)
    return obj


def _dataset(obj: Any, attrs: Mapping[str, Any]):
    import xarray as xr

    arrays: dict[str, np.ndarray] = {}
    tree = encode(obj, arrays)
    variables = {}
    for name, arr in arrays.items():
        arr = np.asarray(arr)
        variables[name] = xr.Variable([f"{name}_{i}" for i in range(arr.ndim)], arr)
    meta = {TYPE_ATTR: type(obj).__name__, TREE_ATTR: json.dumps(tree)}
    meta.update({k: v for k, v in attrs.items() if v is not None})
    return xr.Dataset(variables, attrs=meta)


def save_result(obj: Any, path: str | os.PathLike, attrs: Mapping[str, Any] | None = None
                ) -> Path:
    """Write a result to a NetCDF file atomically (see the module notes).

    ``attrs`` (strings and numbers; None values are left out) are added to the
    file's global attributes, e.g. the provenance record.
    """
    path = file_path("path", path)
    ds = _dataset(obj, attrs or {})
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf")
    return Path(path)


def load_result(path: str | os.PathLike, expected: type, model: Any = None) -> Any:
    """Read a result written by :func:`save_result`; InputError if it is not an ``expected``."""
    import xarray as xr

    p = file_path("path", path)
    if not p.is_file():
        raise InputError(f"path {str(path)!r} is not a file")
    try:
        with xr.open_dataset(p, engine="h5netcdf") as ds:
            ds.load()
            attrs = dict(ds.attrs)
            arrays = {name: np.asarray(var.values) for name, var in ds.variables.items()}
    except (OSError, ValueError) as exc:
        raise InputError(f"path {str(path)!r} is not an olsbayes result file: {exc}") from None
    kind = attrs.get(TYPE_ATTR)
    if kind != expected.__name__ or TREE_ATTR not in attrs:
        raise InputError(f"path {str(path)!r} holds {kind or 'no olsbayes result'}, "
                         f"not a {expected.__name__}")
    return decode(json.loads(attrs[TREE_ATTR]), arrays, model)
