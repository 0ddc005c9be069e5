"""Sky maps: values over (longitude, latitude) in Mollweide or equirectangular view.

Used for sphere responses (one value per sub-sensor) and imaging source maps
(one value per known direction).  Values on a regular latitude-longitude grid
are drawn as cells (``pcolormesh``), scattered directions as markers, in a
perceptual colour map on a neutral grey background (so the brightest and the
darkest cells both stand out), with a colour bar, longitude ticks every 90 degrees
and latitude ticks every 30 (no overlap in small panels).  Imaging on a ring is
drawn as intensity against direction angle instead.  matplotlib is imported when a
function is called.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._validation import choice
from ..circular import wrap_angle
from ..errors import InputError
from ..model import Model

__all__ = ["plot_sky", "plot_sphere_response", "plot_image_result"]

PROJECTIONS = ("mollweide", "equirectangular")


def _grid_shape(lon: np.ndarray, lat: np.ndarray) -> tuple[int, int] | None:
    """(n_lat, n_lon) if the points form a latitude-major regular grid, else None."""
    ulat = np.unique(np.round(lat, 12))
    n_lat = ulat.size
    if n_lat == 0 or lon.size % n_lat:
        return None
    n_lon = lon.size // n_lat
    lat_g, lon_g = lat.reshape(n_lat, n_lon), lon.reshape(n_lat, n_lon)
    if np.ptp(lat_g, axis=1).max() > 1e-9 or np.ptp(lon_g, axis=0).max() > 1e-9:
        return None
    return n_lat, n_lon


def _edges(c: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Cell edges around sorted centres, clipped to [lo, hi]."""
    if c.size == 1:
        return np.array([lo, hi])
    mid = 0.5 * (c[1:] + c[:-1])
    e = np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]])
    return np.clip(e, lo, hi)


def plot_sky(
    lon: np.ndarray,
    lat: np.ndarray,
    values: np.ndarray,
    *,
    projection: str = "mollweide",
    ax: Any = None,
    title: str | None = None,
    cmap: str = "viridis",
    vmin: float | None = None,
    vmax: float | None = None,
    label: str | None = None,
    marker_size: float = 30.0,
) -> Any:
    """Draw ``values`` at directions (lon, lat) on a sky map.

    Parameters
    ----------
    lon, lat : array_like, shape (M,)
        Directions in rad (lon wrapped to (-pi, pi], lat in [-pi/2, pi/2]).
    values : array_like, shape (M,)
    projection : {"mollweide", "equirectangular"}
    ax : matplotlib Axes, optional
        Must have the matching projection (``"mollweide"`` or a plain Axes).
    label : str, optional
        Colour-bar label.

    Returns
    -------
    matplotlib.figure.Figure
    """
    lon = np.asarray(lon, dtype=float).ravel()
    lat = np.asarray(lat, dtype=float).ravel()
    val = np.asarray(values, dtype=float).ravel()
    if not (lon.size == lat.size == val.size) or lon.size == 0:
        raise InputError(
            f"lon, lat and values must be non-empty and of equal length; got {lon.size}, "
            f"{lat.size}, {val.size}"
        )
    choice("projection", projection, PROJECTIONS)
    import matplotlib.pyplot as plt

    if ax is None:
        fig = plt.figure(figsize=(7.0, 4.0), layout="constrained")
        ax = fig.add_subplot(projection="mollweide" if projection == "mollweide" else None)
    fig = ax.figure
    lon = wrap_angle(lon)
    shape = _grid_shape(lon, lat)
    kw = dict(cmap=cmap, vmin=vmin, vmax=vmax)
    if shape is not None and min(shape) > 1:
        lat_c, lon_c = lat.reshape(shape)[:, 0], lon.reshape(shape)[0]
        ilat, ilon = np.argsort(lat_c), np.argsort(lon_c)
        z = val.reshape(shape)[ilat][:, ilon]
        elon = _edges(lon_c[ilon], -np.pi, np.pi)
        elat = _edges(lat_c[ilat], -np.pi / 2, np.pi / 2)
        art = ax.pcolormesh(elon, elat, z, shading="flat", **kw)
    else:
        art = ax.scatter(lon, lat, c=val, s=marker_size, marker="s", **kw)
    ax.set_facecolor("0.82")
    if projection == "equirectangular":
        ax.set_xlim(-np.pi, np.pi)
        ax.set_ylim(-np.pi / 2, np.pi / 2)
        ax.set_aspect("equal")
        ax.set_xlabel("longitude (rad)")
        ax.set_ylabel("latitude (rad)")
    else:
        ax.set_xticks(np.deg2rad([-90, 0, 90]))
        ax.set_yticks(np.deg2rad([-60, -30, 0, 30, 60]))
        ax.tick_params(labelsize=7)
    ax.grid(True, alpha=0.3)
    fig.colorbar(art, ax=ax, shrink=0.7, label=label)
    if title:
        ax.set_title(title)
    return fig


def plot_sphere_response(model: Model, data: np.ndarray, **kwargs: Any) -> Any:
    """Readings of a sphere array (one value per sub-sensor) as a sky map.

    ``kwargs`` go to :func:`plot_sky`.  The array must hold 3-D normals.
    """
    if not isinstance(model, Model) or model.kind != "lonlat":
        raise InputError("plot_sphere_response needs a Model of a sphere (3-D normals) array")
    y = model.check_data(data)
    if y.ndim != 1:
        raise InputError(f"data must be one measurement of shape (N,); got {y.shape}")
    nrm = model.array.normals
    lon, lat = np.arctan2(nrm[:, 1], nrm[:, 0]), np.arcsin(np.clip(nrm[:, 2], -1, 1))
    kwargs.setdefault("label", "reading")
    return plot_sky(lon, lat, y, **kwargs)


def plot_image_result(
    result: Any,
    *,
    truth: np.ndarray | None = None,
    model: Model | None = None,
    data: np.ndarray | None = None,
    projection: str = "equirectangular",
    fig: Any = None,
) -> Any:
    """Panels like Fig. 2: true sources, raw readings on the sphere, estimate, posterior sd.

    Parameters
    ----------
    result : ImageResult
        From :func:`olsbayes.image` on a sphere array.
    truth : ndarray, shape (K,), optional
        True intensities (panel skipped when None).
    model, data : optional
        The sphere model and readings for the raw-image panel.
    projection : {"equirectangular", "mollweide"}
    fig : matplotlib Figure, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    d = np.asarray(result.directions)
    if d.ndim == 1 or (d.ndim == 2 and d.shape[1] == 1):
        return _ring_image(result, truth, fig)
    if d.ndim != 2 or d.shape[1] != 2:
        raise InputError("plot_image_result needs ring angles or (longitude, latitude) "
                         "directions; got near-source positions")
    import matplotlib.pyplot as plt

    panels = []
    if truth is not None:
        panels.append(("true sources", np.asarray(truth, float), "intensity", "src"))
    if model is not None and data is not None:
        panels.append(("raw sub-sensor image", np.asarray(data, float), "reading", "raw"))
    panels.append((f"posterior mean ({result.prior})", result.mean, "intensity", "src"))
    panels.append(("posterior sd", result.sd, "sd", "sd"))
    fig = fig or plt.figure(figsize=(4.2 * len(panels), 3.6), layout="constrained")
    proj = "mollweide" if projection == "mollweide" else None
    vmax = float(np.max(result.mean)) if truth is None else float(np.max(truth))
    for i, (title, val, label, kind) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), i + 1, projection=proj)
        if kind == "raw":
            plot_sphere_response(model, val, ax=ax, projection=projection, title=title,
                                 cmap="magma", label=label)
        else:
            plot_sky(d[:, 0], d[:, 1], val, ax=ax, projection=projection, title=title,
                     cmap="viridis" if kind == "src" else "cividis", label=label,
                     vmin=0.0, vmax=vmax if kind == "src" else None)
    return fig


def _ring_image(result: Any, truth: np.ndarray | None, fig: Any) -> Any:
    """Ring imaging: posterior mean with its credible interval (and the truth) per angle."""
    import matplotlib.pyplot as plt

    theta = wrap_angle(np.asarray(result.directions, dtype=float).ravel())
    order = np.argsort(theta)
    fig = fig or plt.figure(figsize=(7.0, 3.6), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    mean = np.asarray(result.mean, dtype=float)
    lo, hi = np.asarray(result.lower, float), np.asarray(result.upper, float)
    if np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)):
        err = np.vstack([mean - lo, hi - mean])[:, order]
        ax.errorbar(theta[order], mean[order], yerr=np.maximum(err, 0.0), fmt="o", ms=4,
                    capsize=2, color="tab:blue",
                    label=f"posterior mean, {result.level:.0%} interval ({result.prior})")
    else:
        ax.plot(theta[order], mean[order], "o", ms=4, color="tab:blue",
                label=f"estimate ({result.prior}, {result.sampler})")
    if truth is not None:
        ax.plot(theta[order], np.asarray(truth, float)[order], "x", ms=7, color="tab:red",
                label="truth")
    if getattr(result, "i_max", None) is not None:
        ax.axhline(result.i_max, color="0.5", ls="--", lw=0.8, label="prior bound i_max")
    ax.set_xlabel("source direction (rad)")
    ax.set_ylabel("intensity")
    ax.set_xlim(-np.pi, np.pi)
    ax.set_ylim(bottom=0.0)
    ax.legend(loc="best", fontsize="small")
    ax.set_title(f"imaging {theta.size} directions: rank {result.rank}")
    return fig
