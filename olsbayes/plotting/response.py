"""Figures of readings and fitted responses (matplotlib, imported lazily)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..circular import wrap_angle
from ..errors import InputError
from ..model import Model
from ..scene import Scene

__all__ = ["plot_response"]


def _axes(ax: Any) -> tuple[Any, Any]:
    if ax is not None:
        return ax.figure, ax
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.0, 4.0), layout="constrained")
    return fig, ax


def plot_response(
    model: Model,
    data: np.ndarray,
    truth: Scene | None = None,
    estimate: Scene | np.ndarray | None = None,
    *,
    ax: Any = None,
) -> Any:
    """Readings against the sub-sensors, with the true and fitted Eq. 1 responses.

    Parameters
    ----------
    model : Model
    data : ndarray, shape (N,)
        One measurement.
    truth, estimate : Scene (or flat parameters for ``estimate``), optional
        Drawn as lines (noiseless responses) and vertical source markers (ring).
    ax : matplotlib Axes, optional

    Returns
    -------
    matplotlib.figure.Figure
        On a ring the x axis is the sub-sensor normal angle (rad); on other arrays
        it is the sub-sensor index.
    """
    y = model.check_data(data)
    if y.ndim != 1:
        raise InputError(f"data must be one measurement of shape (N,); got {y.shape}")
    fig, ax = _axes(ax)
    ring = model.kind == "angle"
    if ring:
        x = np.arctan2(model.array.normals[:, 1], model.array.normals[:, 0])
        order = np.argsort(x)
        ax.set_xlabel("sub-sensor normal angle (rad)")
    else:
        x = np.arange(model.n_sensors, dtype=float)
        order = np.arange(model.n_sensors)
        ax.set_xlabel("sub-sensor index")
    ax.errorbar(x[order], y[order], yerr=model.sigma, fmt="o", ms=3, color="0.25",
                elinewidth=0.8, label=f"readings (±σ = {model.sigma:g})")
    for scene, style, label in ((truth, "-", "truth"), (estimate, "--", "estimate")):
        if scene is None:
            continue
        mu = model.response(scene)
        (line,) = ax.plot(x[order], mu[order], style, lw=1.5, label=f"Eq. 1, {label}")
        if ring:
            params = model.pack(scene) if isinstance(scene, Scene) else np.asarray(scene)
            for th in params.reshape(-1, 2)[:, 0]:
                ax.axvline(wrap_angle(th), color=line.get_color(), ls=style,
                           lw=0.8, alpha=0.6)
    ax.set_ylabel("reading")
    ax.set_title(f"{model.array!r}, {model.sensitivity!r}")
    ax.legend(loc="best", fontsize="small")
    return fig
