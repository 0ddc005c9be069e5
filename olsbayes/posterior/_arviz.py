"""Every ArviZ call of the package lives here.

Other modules (model selection, CLI, studies) call these helpers rather than
ArviZ itself, so one module tracks the ArviZ API.  ArviZ is imported lazily.

Variables of a posterior ``InferenceData``: one per coordinate role with a
``source`` dimension -- ``theta`` (ring, rad), ``lon``/``lat`` (sphere, rad),
``x``/``y``/``z`` (plate, length unit of the array), ``I`` (intensity, units
of the readings) -- plus a scalar ``sigma`` when the noise is inferred.  ArviZ
labels their entries ``theta[0]``, ``I[1]``, ... exactly as
``Model.param_names`` does.

**Angles are stored unwrapped** around their circular means (each draw within
pi of the mean, so a source at +-pi has one continuous distribution), with the
attributes ``circular = 1``, ``units = "rad"`` and ``period``.  Plain
``arviz.summary(idata)`` and ``corner.corner(idata)`` therefore see the right
spread; ``arviz.summary(idata, circ_var_names=["theta"])`` gives the circular
statistics instead.  Wrap to (-pi, pi] with ``pi - mod(pi - x, 2 pi)``.  Every
variable carries ``units`` and ``long_name``; every group carries
``inference_library`` (emcee), ``inference_library_version``,
``olsbayes_version`` and the run's provenance (seed, data hash, command line).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .._io import atomic_path
from .._validation import file_path
from ..errors import InputError

__all__ = [
    "import_arviz",
    "split_names",
    "unwrap_periodic",
    "wrap_periodic",
    "to_inference_data",
    "posterior_array",
    "summary_frame",
    "ess_rhat",
    "rhat_array",
    "from_dict",
    "to_netcdf",
    "from_netcdf",
    "loo",
    "waic",
]


def import_arviz():
    """Import arviz quietly (0.23 emits a FutureWarning about its 1.0 rewrite)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        import arviz as az
    return az


@contextmanager
def _known_shapes() -> Iterator[None]:
    """Silence ArviZ's shape guess "More chains (W) than draws (D)".

    Arrays handed to ArviZ here are (chain, draw, ...) by construction; a short
    run with more walkers than stored draws is legitimate, not a transposition.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"More chains \(\d+\) than draws",
                                category=UserWarning)
        yield


def split_names(names: list[str]) -> list[tuple[str, int | None]]:
    """``"theta[1]"`` -> ``("theta", 1)``; ``"sigma"`` -> ``("sigma", None)``."""
    out = []
    for nm in names:
        if nm.endswith("]") and "[" in nm:
            base, idx = nm[:-1].split("[", 1)
            out.append((base, int(idx)))
        else:
            out.append((nm, None))
    return out


#: Units and long names of the posterior variables.
_UNITS = {"theta": ("rad", "source direction (ring angle)"),
          "lon": ("rad", "source longitude"), "lat": ("rad", "source latitude"),
          "x": ("length unit of the array", "source position x"),
          "y": ("length unit of the array", "source position y"),
          "z": ("length unit of the array", "source height z above the plate"),
          "I": ("reading units", "source intensity"),
          "sigma": ("reading units", "noise sd of one sub-sensor"),
          "b": ("intensity units", "diffuse background"),
          "g": ("", "sub-sensor gain"), "o": ("reading units", "sub-sensor offset")}
#: Variables indexed by sub-sensor (dim ``sensor``), not by source.
_PER_SENSOR = ("g", "o")


def _dim(base: str) -> str:
    return "sensor" if base in _PER_SENSOR else "source"
_TWO_PI = 2.0 * np.pi


def unwrap_periodic(draws: np.ndarray, centre: np.ndarray, periodic: np.ndarray) -> np.ndarray:
    """Draws (..., P) with periodic columns shifted by whole turns to within pi of ``centre``.

    Exact for draws already within pi of the centre (only whole turns of 2 pi are
    added), so :func:`wrap_periodic` gives the original draws back bit for bit there.
    """
    out = np.array(draws, dtype=float)
    if np.any(periodic):
        x = out[..., periodic]
        turns = np.rint((np.asarray(centre, dtype=float)[periodic] - x) / _TWO_PI)
        out[..., periodic] = np.where(turns == 0, x, x + _TWO_PI * turns)
    return out


def wrap_periodic(draws: np.ndarray, periodic: np.ndarray) -> np.ndarray:
    """Periodic columns of draws (..., P) wrapped to (-pi, pi] by whole turns (exact inside)."""
    out = np.array(draws, dtype=float)
    if np.any(periodic):
        x = out[..., periodic]
        turns = -np.floor((np.pi - x) / _TWO_PI)
        out[..., periodic] = np.where(turns == 0, x, x - _TWO_PI * turns)
    return out


def _variable_attrs(idata, periodic_names: set[str]) -> None:
    """units / long_name on every posterior and prior variable; circular flags on angles."""
    for group in ("posterior", "prior"):
        if group not in idata.groups():
            continue
        ds = getattr(idata, group)
        for name in ds.data_vars:
            units, long_name = _UNITS.get(name, ("", name))
            ds[name].attrs.update(units=units, long_name=long_name)
            if name in periodic_names:
                ds[name].attrs.update(
                    circular=1, period=_TWO_PI,
                    storage=("unwrapped around the circular mean" if group == "posterior"
                             else "wrapped to (-pi, pi]"))


def _by_variable(values: np.ndarray, names: list[str]) -> dict[str, np.ndarray]:
    """(chain, draw, P) -> {base: (chain, draw[, source])} in layout order."""
    groups: dict[str, list[int]] = {}
    scalars: dict[str, int] = {}
    for j, (base, idx) in enumerate(split_names(names)):
        if idx is None:
            scalars[base] = j
        else:
            groups.setdefault(base, []).append(j)
    out = {b: values[..., idx] for b, idx in groups.items()}
    out.update({b: values[..., j] for b, j in scalars.items()})
    return out


def _dims_coords(post: dict, names: list[str], constants: dict, n_sensors: int,
                 n_walkers: int) -> tuple[dict, dict]:
    """Named dims and coordinates of every variable (see :func:`to_inference_data`)."""
    k = max((i + 1 for b, i in split_names(names) if i is not None and _dim(b) == "source"),
            default=0)
    p = len(names)
    dims = {b: [_dim(b)] for b, v in post.items() if v.ndim == 3}
    dims.update({"obs": ["sensor"], "normals": ["sensor", "axis"],
                 "positions": ["sensor", "axis"]})
    for key, value in constants.items():
        shape = np.shape(value)
        if key not in dims and shape == (p,):
            dims[key] = ["parameter"]
        elif key not in dims and shape == (p, p):
            dims[key] = ["parameter", "parameter_bis"]
        elif key not in dims and len(shape) == 1 and shape[0] == n_walkers:
            dims[key] = ["walker"]
    n_axis = np.shape(constants["normals"])[-1] if "normals" in constants else 0
    coords = {"source": np.arange(k), "sensor": np.arange(n_sensors),
              "parameter": list(names), "parameter_bis": list(names),
              "axis": ["x", "y", "z"][:n_axis], "walker": np.arange(n_walkers)}
    return dims, coords


def to_inference_data(
    draws: np.ndarray,
    names: list[str],
    *,
    sample_stats: dict[str, np.ndarray],
    pointwise: np.ndarray,
    data: np.ndarray,
    constants: dict[str, np.ndarray],
    attrs: dict[str, object],
    periodic: np.ndarray,
    centre: np.ndarray,
    predictive: np.ndarray | None = None,
    prior_draws: np.ndarray | None = None,
    reading_stride: int = 1,
):
    """Assemble an ``arviz.InferenceData``.

    Parameters
    ----------
    draws : ndarray (chain, draw, P)
        Relabelled draws (walkers as chains), burn-in removed.
    names : list of str
        Flat parameter names, length P.
    sample_stats : dict
        ArviZ's ``sample_stats`` group, each (chain, draw): ``lp`` (log
        posterior), ``log_prior`` and ``acceptance_rate`` (1.0 where the walker
        moved at that step, else 0.0).
    pointwise : ndarray (chain, draw', N) or Deferred
        Per-sub-sensor log-likelihood; a :class:`~._lazy.Deferred` is made on first access.
        ``draw'``: every ``reading_stride``-th draw.
    data : ndarray (N,)
    constants : dict
        ``constant_data`` arrays: ``normals``/``positions`` (N, D) get dims
        (sensor, axis); (P,) arrays dim ``parameter``, (P, P) arrays dims
        (``parameter``, ``parameter_bis``), (W,) arrays dim ``walker``.
    attrs : dict
        Written into the attributes of every group and of the file (strings and
        numbers only).
    periodic : ndarray of bool (P,)
        Angles, stored unwrapped around ``centre`` (see the module notes).
    centre : ndarray (P,)
        The circular means of the angles.
    predictive : ndarray (chain, draw', N), optional
        Posterior predictive readings: the ``posterior_predictive`` group (``obs``).
    prior_draws : ndarray (1, draw, P), optional
        Independent draws from the prior (raw, exchangeable labels): the
        ``prior`` group.
    reading_stride : int
        The per-reading groups (``posterior_predictive``, ``log_likelihood``) hold
        every this-many-th draw; their ``draw`` coordinate is the posterior's label of
        each (0, s, 2 s, ...).
    """
    az = import_arviz()
    from ._lazy import Deferred

    deferred = pointwise if isinstance(pointwise, Deferred) else None
    if deferred is not None:
        pointwise = deferred.placeholder()
    post = _by_variable(unwrap_periodic(draws, centre, periodic), names)
    dims, coords = _dims_coords(post, names, constants, data.shape[-1], draws.shape[0])
    with _known_shapes():
        idata = az.from_dict(
            posterior=post,
            posterior_predictive=None if predictive is None else {"obs": predictive},
            sample_stats=sample_stats,
            log_likelihood={"obs": pointwise},
            observed_data={"obs": data},
            constant_data=constants,
            prior=None if prior_draws is None else _by_variable(prior_draws, names),
            coords=coords,
            dims=dims,
            attrs=attrs,
        )
    if reading_stride != 1:  # label the per-reading draws as the posterior's
        labels = idata.posterior["draw"].values[::reading_stride]
        for group in ("log_likelihood", "posterior_predictive"):
            if group in idata.groups():
                setattr(idata, group, getattr(idata, group).assign_coords(draw=labels))
    if deferred is not None:
        deferred.install(idata.log_likelihood, "obs")
    for group in idata.groups():  # ArviZ keeps ``attrs`` on the object; groups need them
        getattr(idata, group).attrs.update(attrs)
    angles = {base for (base, _), per in zip(split_names(names), periodic) if per}
    _variable_attrs(idata, angles)
    for group in ("observed_data", "posterior_predictive"):
        if group in idata.groups():
            getattr(idata, group)["obs"].attrs.update(units="reading units",
                                                       long_name="sub-sensor reading")
    return idata


def posterior_array(idata, names: list[str]) -> np.ndarray:
    """The posterior as one (chain, draw, P) array in layout order (angles as stored)."""
    post = idata.posterior
    cols = []
    for base, idx in split_names(names):
        var = post[base]
        cols.append((var if idx is None else var.isel({_dim(base): idx})).values)
    return np.stack(cols, axis=-1)


def summary_frame(draws: np.ndarray, names: list[str], hdi_prob: float = 0.94):
    """``arviz.summary`` (pandas DataFrame, rows in layout order) of (chain, draw, P) draws.

    Columns: mean, sd, hdi_*, mcse_mean, mcse_sd, ess_bulk, ess_tail, r_hat.
    """
    az = import_arviz()
    post = _by_variable(np.asarray(draws, dtype=float), names)
    dims = {b: [_dim(b)] for b, v in post.items() if v.ndim == 3}
    with _known_shapes():
        idata = az.from_dict(posterior=post, dims=dims)
        frame = az.summary(idata, hdi_prob=hdi_prob, round_to="none")
    return frame.loc[list(names)]


def from_dict(**groups):
    """``arviz.from_dict`` (for other modules building InferenceData)."""
    az = import_arviz()
    with _known_shapes():
        return az.from_dict(**groups)


def ess_rhat(idata) -> dict[str, np.ndarray]:
    """Bulk ESS, tail ESS and rank-normalised split R-hat per variable (xarray)."""
    az = import_arviz()
    return {
        "ess_bulk": az.ess(idata, method="bulk"),
        "ess_tail": az.ess(idata, method="tail"),
        "r_hat": az.rhat(idata),
    }


def rhat_array(draws: np.ndarray) -> np.ndarray:
    """Rank-normalised split R-hat of (chain, draw, P) draws, shape (P,)."""
    az = import_arviz()
    with _known_shapes():
        ds = az.convert_to_dataset(np.asarray(draws, dtype=float))
    return np.asarray(az.rhat(ds)["x"].values, dtype=float)


def to_netcdf(idata, path: str | os.PathLike) -> Path:
    """Write ``idata`` to NetCDF atomically (loadable with ``arviz.from_netcdf``)."""
    path = file_path("path", path)
    with atomic_path(path) as tmp:
        idata.to_netcdf(str(tmp))
    return Path(path)


def from_netcdf(path: str | os.PathLike):
    """Read an InferenceData written by :func:`to_netcdf`."""
    if not file_path("path", path).is_file():
        raise InputError(f"path {str(path)!r} is not a file")
    az = import_arviz()
    return az.from_netcdf(str(path))


def loo(idata, pointwise: bool = False):
    """PSIS-LOO over sub-sensors (``arviz.loo``); returns ArviZ's ELPDData.

    Sub-sensors that no source reaches in any draw have a constant pointwise
    log-likelihood; their leave-one-out term is exact, but ArviZ's Pareto fit
    reports k = inf (and a warning) for them.  Such columns are therefore left
    out of the importance sampling and added back exactly: ``elpd_loo``, ``se``
    and ``n_data_points`` cover every sub-sensor, and with ``pointwise=True``
    their ``pareto_k`` is 0 (exact).
    """
    az = import_arviz()
    ll = idata.log_likelihood["obs"]
    vals = ll.values.reshape(-1, ll.shape[-1])
    const = np.ptp(vals, axis=0) <= 1e-12 * np.maximum(1.0, np.abs(vals).max(axis=0))
    if idata.posterior.sizes["draw"] != ll.sizes["draw"]:
        # ArviZ's relative efficiency is the posterior's ESS over the log-likelihood's
        # draws: the posterior at those draws (every s-th, see to_inference_data)
        idata = az.InferenceData(posterior=idata.posterior.sel(draw=ll["draw"].values),
                                 log_likelihood=idata.log_likelihood)
    if not const.any():
        return az.loo(idata, pointwise=pointwise)
    if const.all():
        raise InputError("loo: the log-likelihood does not vary over the draws")
    sub = az.InferenceData(posterior=idata.posterior,
                           log_likelihood=idata.log_likelihood.isel(sensor=np.flatnonzero(~const)))
    res = az.loo(sub, pointwise=True)
    loo_i = np.empty(vals.shape[1])
    loo_i[~const] = res["loo_i"].values
    loo_i[const] = vals[0, const]
    res["elpd_loo"] = float(loo_i.sum())
    res["se"] = float(np.sqrt(loo_i.size * np.var(loo_i)))
    res["n_data_points"] = int(loo_i.size)
    if not pointwise:
        short = res.drop(["loo_i", "pareto_k"])
        return type(res)(data=list(short.values), index=list(short.index))
    k = np.zeros(loo_i.size)
    k[~const] = res["pareto_k"].values
    res["loo_i"] = ll.isel(chain=0, draw=0).copy(data=loo_i).rename("loo_i")
    res["pareto_k"] = ll.isel(chain=0, draw=0).copy(data=k).rename("pareto_shape")
    return res


def waic(idata, pointwise: bool = False):
    """WAIC over sub-sensors (``arviz.waic``)."""
    az = import_arviz()
    return az.waic(idata, pointwise=pointwise)
