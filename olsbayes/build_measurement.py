"""The measurement model of a configuration: [noise], [calibration], [background] ...

:func:`measurement_from_config` turns the sections documented in
:mod:`olsbayes.config.measurement_sections` into the ``noise=`` and
``nuisance=`` of a :class:`~olsbayes.Model`; :func:`prior_from_config` and
:func:`sampler_options_from_config` give the posterior's prior and emcee settings.
Contradictions between sections (a sigma under Poisson noise, an exposure under
Gaussian noise, a sigma in two places) raise :class:`~olsbayes.errors.ConfigError`
naming the keys.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .config import Config, read_readings
from .errors import ConfigError, InputError
from .geometry import SensorArray
from .noise import GaussianKnown, GaussianPerSensor, GaussianUnknown, NoiseModel, Poisson
from .nuisance import Nuisance

__all__ = ["measurement_from_config", "frames_from_config", "prior_from_config",
           "sampler_options_from_config"]


def _fail(cfg: Config, message: str) -> ConfigError:
    return ConfigError(f"{cfg.source}: {message}")


def _sigma(cfg: Config, noise: dict[str, Any], n: int) -> float | np.ndarray | None:
    """The noise sd: [sensor] sigma, [noise] sigma or [noise] sigma_file (one of them)."""
    given = [k for k, sec in (("[sensor] sigma", cfg.section("sensor")),
                              ("[noise] sigma", noise)) if "sigma" in sec]
    if "sigma_file" in noise:
        given.append("[noise] sigma_file")
    if len(given) > 1:
        raise _fail(cfg, f"give the noise sd once; got {' and '.join(given)}")
    if not given:
        return None
    if given[0] == "[noise] sigma_file":
        return read_readings(noise["sigma_file"], n, name="[noise] sigma_file")
    return cfg.section("sensor")["sigma"] if given[0] == "[sensor] sigma" else noise["sigma"]


def _noise(cfg: Config, n: int) -> NoiseModel:
    noise = dict(cfg.get("noise") or {})
    kind = noise.get("model", "gaussian")
    sigma = _sigma(cfg, noise, n)
    if kind == "poisson":
        if sigma is not None:
            raise _fail(cfg, "[noise] model = 'poisson' takes no sigma (the variance of a "
                             "count is its mean); remove [sensor] sigma / [noise] sigma")
        expo = np.asarray(noise.get("exposure", [1.0]), dtype=float)
        return Poisson(float(expo[0]) if expo.size == 1 else expo, noise.get("dark", 0.0))
    for key in ("exposure", "dark"):
        if key in noise:
            raise _fail(cfg, f"[noise] {key} applies only to model = 'poisson'")
    if sigma is None:
        raise _fail(cfg, "[sensor] sigma is required (the noise sd of one sub-sensor), or "
                         "[noise] sigma / sigma_file, or [noise] model = 'poisson'")
    if np.ndim(sigma):
        if kind == "gaussian_unknown":
            raise _fail(cfg, "[noise] sigma_file (one sd per sub-sensor) needs model = "
                             "'gaussian' (a known sd per sub-sensor)")
        return GaussianPerSensor(np.ravel(sigma))
    return GaussianKnown(float(sigma)) if kind == "gaussian" else GaussianUnknown(float(sigma))


def _nuisance(cfg: Config, array: SensorArray) -> Nuisance | None:
    from .calibration import Calibration
    from .priors import LogNormal, Normal, Uniform

    cal, bg = cfg.get("calibration") or {}, cfg.get("background") or {}
    if not cal and not bg:
        return None
    if bg.get("infer", False) != ("max" in bg):
        raise _fail(cfg, "[background] infer = true needs max (its prior is Uniform(0, max)) "
                         "and max needs infer = true")
    b_prior = Uniform(0.0, bg["max"]) if bg.get("infer", False) else None
    b_value = bg.get("value", 0.0)
    if "file" in cal:
        if "gain_sd" in cal or "offset_sd" in cal:
            raise _fail(cfg, "[calibration] gain_sd / offset_sd apply without a file (with a "
                             "file the file's standard errors are used: infer = true)")
        calib = Calibration.load(cal["file"])
        calib.check(array)
        return calib.nuisance(infer=cal.get("infer", False), background=b_value,
                              background_prior=b_prior)
    if cal.get("infer", False):
        raise _fail(cfg, "[calibration] infer = true needs file; without one give gain_sd "
                         "and/or offset_sd")
    g_prior = LogNormal(0.0, cal["gain_sd"]) if "gain_sd" in cal else None
    o_prior = Normal(0.0, cal["offset_sd"]) if "offset_sd" in cal else None
    return Nuisance(background=b_value, background_prior=b_prior, gain_prior=g_prior,
                    offset_prior=o_prior)


def measurement_from_config(cfg: Config, array: SensorArray) -> tuple[NoiseModel, Nuisance | None]:
    """The noise model and the nuisance terms (None: none) of ``cfg`` for ``array``.

    Without [noise], [calibration] and [background] this is Gaussian noise of the
    known ``[sensor] sigma`` and no nuisance terms.
    """
    try:
        noise = _noise(cfg, array.n_sensors)
        noise.validate(array.n_sensors)
        return noise, _nuisance(cfg, array)
    except InputError as exc:
        raise _fail(cfg, str(exc)) from None


def frames_from_config(cfg: Config) -> bool:
    """``[noise] frames``: whether the rows of the readings are frames of one scene."""
    return bool((cfg.get("noise") or {}).get("frames", False))


def prior_from_config(cfg: Config, model: Any, n_sources: int, data: np.ndarray,
                      frames: bool = False) -> Any:
    """The posterior's :class:`~olsbayes.priors.ScenePrior` from [prior], or None without it."""
    from .priors import default_priors

    sec = cfg.get("prior")
    if not sec:
        return None
    lo, hi = sec.get("sigma_min"), sec.get("sigma_max")
    if (lo is None) != (hi is None) or (lo is not None and lo >= hi):
        raise _fail(cfg, "[prior] sigma_min and sigma_max come together, sigma_min < sigma_max")
    if lo is not None and not isinstance(model.noise, GaussianUnknown):
        raise _fail(cfg, "[prior] sigma_min / sigma_max apply to [noise] model = "
                         "'gaussian-unknown'")
    try:
        prior = default_priors(model, n_sources, i_max=sec.get("i_max"), data=data,
                               intensity=sec.get("intensity", "uniform"),
                               sigma_range=None if lo is None else (lo, hi), frames=frames)
    except InputError as exc:
        raise _fail(cfg, f"[prior] {exc}") from None
    return prior


def sampler_options_from_config(cfg: Config, max_steps: int) -> Any:
    """emcee settings: [posterior] walkers and steps (steps overrides ``max_steps``)."""
    from .posterior import SamplerOptions

    sec = cfg.get("posterior") or {}
    try:
        return SamplerOptions(n_walkers=sec.get("walkers"),
                              max_steps=sec.get("steps", max_steps))
    except InputError as exc:
        raise _fail(cfg, f"[posterior] {exc}") from None
