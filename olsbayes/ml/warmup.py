"""Compile every kernel of the ML wing once, on tiny problems.

numba compiles a kernel on its first call (then caches the machine code), so the
first fit of a kind pays the compilation.  :func:`compile_kernels` runs one small
fit of every kind that has its own compiled specialisation -- each method, each
source kind, each sensitivity-law family, K = 1..4 -- so that later calls, and
the timings of tests and benchmarks, do not carry it.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..geometry import Plate, Ring, Sphere
from ..model import Model
from ..sensitivity import CosinePower
from .fit import fit_ml
from .multistart import MultistartOptions

__all__ = ["compile_kernels"]


def _ring_scene(k: int) -> np.ndarray:
    return np.column_stack([0.3 + 2 * np.pi * np.arange(k) / k + 0.2 * np.arange(k),
                            np.linspace(1.0, 0.6, k)]).ravel()


def _cases() -> list[tuple[Model, np.ndarray, int, tuple[str, ...]]]:
    """(model, parameters of K sources, K, methods) per compiled specialisation."""
    ring = Model(Ring(12), 1e-2)
    out = [(ring, _ring_scene(k), k, ("fast", "exact")) for k in (1, 2, 3, 4)]
    out.append((Model(Ring(12), 1e-2, CosinePower(2.0)), _ring_scene(2), 2, ("fast",)))
    out.append((Model(Sphere.fibonacci(20), 1e-2), np.array([0.3, 0.2, 1.0]), 1,
                ("fast", "multistart")))
    out.append((Model(Plate.grid(3, 3, 1.0), 1e-2), np.array([0.2, 0.1, 1.5, 1.0]), 1,
                ("fast",)))
    return out


def compile_kernels() -> int:
    """Run one small fit per compiled specialisation; returns the number of fits run.

    Each fit runs on one data vector and on a batch of two, since both shapes reach
    kernels of their own (e.g. the one-lane and the blocked K-tuple scans).
    """
    n = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for model, x, k, methods in _cases():
            data = model.response(x)
            for method in methods:
                opts = MultistartOptions(n_starts=2) if method == "multistart" else None
                for d in (data, np.stack([data, data])):
                    fit_ml(model, d, k, method, options=opts, rng=0, warn=False)
                    n += 1
    return n
