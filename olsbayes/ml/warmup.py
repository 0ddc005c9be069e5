"""Compile every kernel of the package once, on tiny problems.

numba compiles a kernel on its first call (then caches the machine code), so the
first fit of a kind pays the compilation.  :func:`compile_kernels` runs one small
fit of every kind that has its own compiled specialisation -- each method, each
source kind, each sensitivity-law family, K = 1..4 -- and one small image (the
imaging sampler's window sweep), so that later calls, the first ``olsbayes demo``
and the timings of tests and benchmarks do not carry it (``olsbayes compile``).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np

from ..geometry import Plate, Ring, Sphere
from ..model import Model
from ..sensitivity import CosinePower
from .fit import fit_ml
from .multistart import MultistartOptions

__all__ = ["compile_kernels", "fast_fits"]


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


def fast_fits() -> int:
    """One fast fit of one data vector per case: the kernels a study's trials use most.

    Returns the number of fits run.
    """
    n = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for model, x, k, methods in _cases():
            if "fast" in methods:
                fit_ml(model, model.response(x), k, "fast", rng=0)
                n += 1
    return n


def compile_kernels(progress: Callable[[int, int], None] | None = None) -> int:
    """Run one small fit per compiled specialisation and one small image.

    Each fit runs on one data vector and on a batch of two, since both shapes reach
    kernels of their own (e.g. the one-lane and the blocked K-tuple scans), and as a
    default call does: with the checks behind its warnings (silenced here), which run
    kernels of their own too.

    Parameters
    ----------
    progress : callable, optional
        Called as ``progress(done, total)`` after each case.

    Returns
    -------
    int
        The number of calls run.
    """
    cases = _cases()
    n = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for i, (model, x, k, methods) in enumerate(cases):
            data = model.response(x)
            for method in methods:
                opts = MultistartOptions(n_starts=2) if method == "multistart" else None
                for d in (data, np.stack([data, data])):
                    fit_ml(model, d, k, method, options=opts, rng=0)
                    n += 1
            if progress is not None:
                progress(i + 1, len(cases) + 1)
        _image_once()
    if progress is not None:
        progress(len(cases) + 1, len(cases) + 1)
    return n + 1


def _image_once() -> None:
    """One small sampled image: compiles the Gibbs sampler's window sweep and block moves."""
    from ..imaging import Bounded, ImageOptions, image

    model = Model(Ring(12), 1e-2)
    directions = np.linspace(-np.pi, np.pi, 6, endpoint=False)
    data = model.response(np.column_stack([directions, np.full(6, 0.5)]).ravel())
    image(model, data, directions, Bounded(i_max=1.0),
          options=ImageOptions(n_samples=4, n_burn=2, n_chains=2, window=3), rng=0,
          progress=False)
    from ..imaging.block import compile_block_kernel

    compile_block_kernel()
