"""Ready-made trial functions (module level, so any executor can run them).

Each takes ``settings`` with the keys listed in its docstring and, keyword-only,
a numpy Generator ``rng`` (or, for the vectorised ones, ``rngs``: a list of
Generators, one per trial).
"""

from __future__ import annotations

import functools

import numpy as np

from ..geometry import Ring
from ..model import Model
from ._work import trial_outputs, trial_settings, vectorized
from .grid import Setting

__all__ = ["ring_scene", "noise_check", "noise_check_batch", "ring_model", "RING_SETTINGS"]

#: Settings of a ring scene and their accepted ranges (checked before a study runs).
RING_SETTINGS = {
    "n_sensors": Setting("int", 3, 10_000),
    "sigma": Setting("float", high=1e6, positive=True),
    "n_sources": Setting("int", 1, 5_000),
    "separation": Setting("float", -1e3, 1e3),
    "intensity": Setting("float", 0, 1e12),
}


def ring_scene(settings: dict, *, rng: np.random.Generator) -> np.ndarray:
    """Random ring scene: K sources, all of intensity ``intensity``.

    The first is uniform on the circle, the others at multiples of ``separation``
    (rad) from it.

    Settings: ``n_sources`` (default 1), ``separation`` (default 2 pi / K),
    ``intensity`` (default 1.0).  Returns the flat parameter vector (2K,).
    """
    k = int(settings.get("n_sources", 1))
    sep = float(settings.get("separation", 2 * np.pi / k))
    theta0 = rng.uniform(-np.pi, np.pi)
    theta = theta0 + sep * np.arange(k)
    inten = np.full(k, float(settings.get("intensity", 1.0)))
    return np.column_stack([theta, inten]).ravel()


def ring_model(settings: dict) -> Model:
    """The ring model of ``settings`` (``n_sensors``, ``sigma``), one per process and setting.

    A trial runs once per chunk; reusing the model keeps what its first fit
    derived (search grids, atoms, kernel arguments) for the later chunks, which
    would otherwise rebuild it each time (about 1 ms per chunk on a ring of 16).
    """
    return _cached_ring(int(settings["n_sensors"]), float(settings["sigma"]))


@functools.lru_cache(maxsize=16)
def _cached_ring(n_sensors: int, sigma: float) -> Model:
    return Model(Ring(n_sensors), sigma)


#: (long_name, units) of the outputs of :func:`noise_check` and :func:`noise_check_batch`.
NOISE_OUTPUTS = {
    "chi2": ("residual sum of squares / sigma^2 at the true scene", "1"),
    "theta0": ("direction of the first source", "rad"),
    "moments": ("mean and variance of the standardised residual", "1"),
}


@trial_outputs(**NOISE_OUTPUTS)
@trial_settings(**RING_SETTINGS)
def noise_check(settings: dict, *, rng: np.random.Generator) -> dict:
    """Simulate one ring scene and measure its noise: chi2 of the truth (~ chi2_N).

    Settings: ``n_sensors``, ``sigma`` and those of :func:`ring_scene`.
    Returns ``chi2`` (residual sum of squares / sigma^2 at the truth), ``theta0``
    (the first source direction, rad) and ``moments`` (2,): mean and variance of the
    standardised residual over the sub-sensors.
    """
    model = ring_model(settings)
    x = ring_scene(settings, rng=rng)
    data = model.simulate(x, rng=rng)
    resid = data - model.response(x)
    z = resid / model.sigma
    return {"chi2": float(z @ z), "theta0": x[0], "moments": np.array([z.mean(), z.var()])}


@vectorized
@trial_outputs(**NOISE_OUTPUTS)
@trial_settings(**RING_SETTINGS)
def noise_check_batch(settings: dict, *, rngs: list[np.random.Generator]) -> dict:
    """Vectorised :func:`noise_check`: the same numbers, one batched model call."""
    model = ring_model(settings)
    xs = np.stack([ring_scene(settings, rng=r) for r in rngs])
    noise = np.stack([r.standard_normal(model.n_sensors) for r in rngs])
    data = model.response(xs) + model.sigma * noise
    z = (data - model.response(xs)) / model.sigma
    return {"chi2": np.einsum("tn,tn->t", z, z), "theta0": xs[:, 0],
            "moments": np.column_stack([z.mean(axis=1), z.var(axis=1)])}
