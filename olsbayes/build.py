"""Objects from a validated :class:`~olsbayes.config.Config`: array, model, scene, data.

Errors raised by the library while building (e.g. a scene of the wrong kind for
the array) are re-raised as :class:`~olsbayes.errors.ConfigError` naming the
configuration file, so a user knows which file to fix.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from .build_measurement import measurement_from_config
from .config import Config, read_readings
from .errors import ConfigError, InputError
from .geometry import Plate, Ring, SensorArray, Sphere
from .model import Model
from .noise import GaussianKnown
from .scene import Scene
from .sensitivity import CosinePower, get_sensitivity

__all__ = ["array_from_config", "model_from_config", "scene_from_config", "data_from_config"]


@contextlib.contextmanager
def _as_config_error(cfg: Config, section: str) -> Iterator[None]:
    try:
        yield
    except InputError as exc:
        raise ConfigError(f"{cfg.source}: [{section}] {exc}") from None


def _need(sec: Mapping[str, Any], key: str, what: str) -> Any:
    if key not in sec:
        raise ConfigError(f"[sensor] {key} is required for {what}")
    return sec[key]


def _either(sec: Mapping[str, Any], inline: str, file: str, required: bool) -> np.ndarray | None:
    if inline in sec and file in sec:
        raise ConfigError(f"[sensor] give {inline} or {file}, not both")
    if inline in sec:
        return sec[inline]
    if file in sec:
        return read_readings(sec[file], name=f"[sensor] {file}")
    if required:
        raise ConfigError(f"[sensor] geometry = 'custom' needs {inline} or {file}")
    return None


#: Largest number of sub-sensors a configuration may ask for.
MAX_SENSORS = 1_000_000
#: Largest number of simulated readings (repeats x sub-sensors).
MAX_READINGS = 50_000_000


def _check_size(cfg: Config, count: int, what: str, limit: int) -> None:
    if count > limit:
        raise ConfigError(f"{cfg.source}: {what} = {count}; at most {limit} accepted")


def array_from_config(cfg: Config) -> SensorArray:
    """The :class:`SensorArray` of the ``[sensor]`` section."""
    sec = cfg.section("sensor")
    geo = sec["geometry"]
    if geo == "sphere" and "n_lat" in sec and "n_lon" in sec:
        _check_size(cfg, sec["n_lat"] * sec["n_lon"], "[sensor] n_lat * n_lon", MAX_SENSORS)
    if geo == "plate" and "nx" in sec and "ny" in sec:
        _check_size(cfg, sec["nx"] * sec["ny"], "[sensor] nx * ny", MAX_SENSORS)
    with _as_config_error(cfg, "sensor"):
        if geo == "ring":
            return Ring(_need(sec, "n", "a ring"), sec.get("offset", 0.0))
        if geo == "sphere":
            if sec.get("layout", "grid") == "fibonacci":
                if "n_lat" in sec or "n_lon" in sec:
                    raise ConfigError("[sensor] layout = 'fibonacci' takes n, not n_lat/n_lon")
                return Sphere.fibonacci(_need(sec, "n", "a Fibonacci sphere"))
            if "n" in sec:
                raise ConfigError("[sensor] layout = 'grid' takes n_lat and n_lon, not n")
            return Sphere.grid(
                _need(sec, "n_lat", "a sphere grid"),
                _need(sec, "n_lon", "a sphere grid"),
                sec["lat_max"],
                (sec["lon_min"], sec["lon_max"]),
            )
        if geo == "plate":
            return Plate.grid(_need(sec, "nx", "a plate"), _need(sec, "ny", "a plate"),
                              sec["pitch"])
        normals = _either(sec, "normals", "normals_file", required=True)
        positions = _either(sec, "positions", "positions_file", required=False)
        return SensorArray(normals, positions)


def model_from_config(cfg: Config) -> Model:
    """The :class:`Model` of the ``[sensor]`` section (array, sigma, sensitivity law).

    Its noise and nuisance terms come from ``[noise]``, ``[calibration]`` and
    ``[background]`` when the configuration has them
    (:func:`olsbayes.build_measurement.measurement_from_config`).
    """
    sec = cfg.section("sensor")
    law = sec.get("sensitivity", "cosine")
    if "p" in sec and law != "cosine_power":
        raise ConfigError(
            f"{cfg.source}: [sensor] p is only used with sensitivity = 'cosine_power'; "
            f"got sensitivity = {law!r}"
        )
    array = array_from_config(cfg)
    noise, nuisance = measurement_from_config(cfg, array)
    with _as_config_error(cfg, "sensor"):
        sens = CosinePower(sec.get("p", 2.0)) if law == "cosine_power" else get_sensitivity(law)
        if isinstance(noise, GaussianKnown) and nuisance is None:
            return Model(array, noise.sigma, sens)
        return Model(array, None, sens, noise=noise, nuisance=nuisance)


def scene_from_config(cfg: Config, model: Model | None = None) -> Scene:
    """The :class:`Scene` of the ``[scene]`` section, checked against ``model``."""
    sec = cfg.section("scene")
    if ("directions" in sec) == ("positions" in sec):
        raise ConfigError(f"{cfg.source}: [scene] needs exactly one of directions and positions")
    with _as_config_error(cfg, "scene"):
        if "positions" in sec:
            pos = sec["positions"]
            pos = pos.reshape(-1, 3) if pos.size == 0 else pos
            scene = Scene(positions=pos, intensities=sec["intensities"])
        else:
            scene = Scene(directions=sec["directions"], intensities=sec["intensities"],
                          unit=sec.get("angle_unit", "rad"))
        if model is not None:
            model.pack(scene)
    return scene


def data_from_config(
    cfg: Config,
    model: Model,
    scene: Scene | None = None,
    *, rng: np.random.Generator | int | None = None,
) -> np.ndarray | None:
    """Readings of the ``[data]`` section: read from ``file`` or simulated.

    Returns None when there is no ``[data]`` section.  ``rng`` overrides
    ``[data] seed`` when given.  Shape (N,) for one measurement, (T, N) for T.
    """
    sec = cfg.get("data")
    if sec is None:
        return None
    if "file" in sec and sec.get("simulate", False):
        raise ConfigError(f"{cfg.source}: [data] give file or simulate = true, not both")
    if "file" in sec:
        if "seed" in sec or sec.get("repeats", 1) != 1:
            raise ConfigError(
                f"{cfg.source}: [data] seed and repeats apply only to simulate = true"
            )
        return read_readings(sec["file"], model.n_sensors, name="[data] file")
    if not sec.get("simulate", False):
        raise ConfigError(f"{cfg.source}: [data] needs file = '...' or simulate = true")
    if scene is None:
        scene = scene_from_config(cfg, model)
    seed = rng if rng is not None else sec.get("seed")
    if seed is None:
        raise ConfigError(f"{cfg.source}: [data] simulate = true needs a seed (or --seed)")
    reps = sec.get("repeats", 1)
    _check_size(cfg, reps * model.n_sensors, "[data] repeats * sub-sensors", MAX_READINGS)
    with _as_config_error(cfg, "data"):
        return model.simulate(scene, rng=seed, size=None if reps == 1 else reps)
