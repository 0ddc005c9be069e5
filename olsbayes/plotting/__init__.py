"""Figures (matplotlib, imported lazily): responses, corner plots, sky maps, model checks.

Each plotting function takes ``ax=`` or ``fig=`` and returns the figure.  The
submodules import matplotlib only when a function is called, so importing this
package is cheap.
"""

from __future__ import annotations

import importlib

__all__ = [
    "plot_response",
    "plot_corner",
    "plot_trace",
    "plot_sky",
    "plot_sphere_response",
    "plot_image_result",
    "plot_ppc",
    "plot_k_posterior",
]

_LAZY = {
    "plot_response": "response",
    "plot_corner": "corner",
    "plot_trace": "corner",
    "plot_sky": "skymap",
    "plot_sphere_response": "skymap",
    "plot_image_result": "skymap",
    "plot_ppc": "checks",
    "plot_k_posterior": "checks",
}


def __getattr__(name: str):
    if name in _LAZY:
        module = importlib.import_module(f".{_LAZY[name]}", __name__)
        return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
