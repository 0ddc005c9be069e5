"""The package's default scene priors and the data-derived intensity bound."""

from __future__ import annotations

import numpy as np

from .._validation import finite_array, positive_float
from ..errors import InputError
from .scene import ScenePrior
from .univariate import LogUniform, Prior, Uniform

__all__ = ["default_priors", "data_intensity_bound"]


def _direction_gain(model, prior_loc: tuple[Prior, ...]) -> float:
    """A low quantile over the location prior of the best sub-sensor gain per unit I."""
    gen = np.random.default_rng(20240531)  # fixed stream: a deterministic grid of directions
    loc = np.column_stack([p.sample(4096, rng=gen) for p in prior_loc])
    x = np.column_stack([loc, np.ones(len(loc))])
    best = model.response(x).max(axis=-1)
    return float(np.quantile(best, 0.01))


def data_intensity_bound(model, data: np.ndarray, location: tuple[Prior, ...] | None = None
                         ) -> float:
    """Weakly informative intensity bound from the readings.

    Every source adds a non-negative reading, so one source of intensity I at a
    location seen with best sub-sensor gain ``a`` gives ``max(data) >= a I`` up
    to noise.  Returns ``2 (max(data) + 3 sigma) / a`` with ``a`` the 1% quantile
    of the best gain over the location prior (a Monte Carlo grid).  It depends
    on the data: prefer an explicit ``i_max`` for evidence calculations.
    """
    data = model.check_data(data)
    if location is None:
        location = ScenePrior(model, 0, Uniform(0.0, 1.0)).location
    gain = _direction_gain(model, tuple(location))
    if not gain > 0:
        raise InputError("the array leaves part of the location prior unseen; give i_max")
    return 2.0 * (float(np.max(data)) + 3.0 * model.sigma) / gain


def _plate_box(model) -> tuple[Prior, Prior, Prior]:
    pos = model.array.positions
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    size = float(max(np.max(hi - lo), 1e-12))
    return (Uniform(lo[0] - size / 2, hi[0] + size / 2),
            Uniform(lo[1] - size / 2, hi[1] + size / 2), Uniform(0.0, size))


def default_priors(
    model,
    n_sources: int,
    *,
    i_max: float | None = None,
    data: np.ndarray | None = None,
    intensity: str | Prior = "uniform",
    infer_sigma: bool = False,
    sigma_range: tuple[float, float] | None = None,
    box: tuple[Prior, Prior, Prior] | None = None,
    frames: bool = False,
) -> ScenePrior:
    """The package's default scene prior.

    A model with extra parameters (:mod:`olsbayes.measurement`: an unknown sigma,
    inferred background, gains or offsets) gets their priors appended: sigma
    ``LogUniform(*sigma_range)`` (default ``(sigma / 100, 100 sigma)``), the nuisance
    terms the priors of the model's :class:`~olsbayes.Nuisance`.

    Parameters
    ----------
    model : Model
    n_sources : int
    i_max : float, optional
        Upper end of the intensity prior.  If None, derived from ``data`` with
        :func:`data_intensity_bound`; one of the two is required.
    data : ndarray (N,), optional
        Readings, used only when ``i_max`` is None.
    intensity : {"uniform", "loguniform"} or Prior
        ``Uniform(0, i_max)`` or ``LogUniform(1e-3 i_max, i_max)``, or any prior.
    infer_sigma : bool
        Add the noise sd as a parameter with prior ``LogUniform(*sigma_range)``,
        default range ``(model.sigma / 100, model.sigma * 100)``.
    box : three Priors, optional
        Plate only: priors of x, y, z; default the plate's extent widened by half
        its size on each side, and z in [0, size].
    frames : bool
        ``data`` holds frames (F, N) of one scene.
    """
    if model.kind == "position":
        location = box if box is not None else _plate_box(model)
    else:
        location = None
    inten = _intensity_prior(model, intensity, i_max, data, location, frames)
    noise = None
    if _has_extras(model):
        return ScenePrior(model, n_sources, inten, location=location,
                          extra=_model_extras(model, sigma_range))
    if infer_sigma:
        rng_ = sigma_range if sigma_range is not None else (model.sigma / 100, model.sigma * 100)
        bounds = finite_array("sigma_range", rng_, ndim=1)
        if bounds.shape != (2,):
            raise InputError(f"sigma_range must be (lo, hi); got {sigma_range!r}")
        noise = LogUniform(float(bounds[0]), float(bounds[1]))
    return ScenePrior(model, n_sources, inten, location=location, noise=noise)


def _intensity_prior(model, intensity, i_max, data, location, frames) -> Prior:
    """The intensity prior of :func:`default_priors` (``intensity`` a name or a Prior)."""
    if isinstance(intensity, Prior):
        return intensity
    if i_max is None:
        if data is None:
            raise InputError("default_priors needs i_max (the largest intensity) or data")
        loc = location if location is not None else ScenePrior(
            model, 0, Uniform(0.0, 1.0)).location
        i_max = _data_bound(model, data, loc, frames)
    i_max = positive_float("i_max", i_max)
    if intensity == "uniform":
        return Uniform(0.0, i_max)
    if intensity == "loguniform":
        return LogUniform(1e-3 * i_max, i_max)
    raise InputError(
        f"intensity must be 'uniform', 'loguniform' or a Prior; got {intensity!r}"
    )


def _has_extras(model) -> bool:
    from ..measurement import n_extra
    return n_extra(model) > 0


def _model_extras(model, sigma_range) -> tuple[tuple[str, Prior], ...]:
    """(name, prior) of the model's extra parameters; sigma's range as ``default_priors``."""
    from ..measurement import extra_names, extra_priors

    sigma_prior = None
    if sigma_range is not None:
        bounds = finite_array("sigma_range", sigma_range, ndim=1)
        if bounds.shape != (2,):
            raise InputError(f"sigma_range must be (lo, hi); got {sigma_range!r}")
        sigma_prior = LogUniform(float(bounds[0]), float(bounds[1]))
    return tuple(zip(extra_names(model), extra_priors(model, sigma_prior)))


def _data_bound(model, data, location, frames: bool) -> float:
    """:func:`data_intensity_bound` in the units of the response (counts and frames mapped)."""
    from ..measurement import is_plain, surrogate

    if is_plain(model) and not frames:
        return data_intensity_bound(model, data, location)
    arr = model.check_data(data, frames=frames)
    gauss, y, _, _ = surrogate(model, arr[None], frames)
    return data_intensity_bound(gauss, y[0], location)
