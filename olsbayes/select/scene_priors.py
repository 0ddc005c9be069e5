"""The scene prior of every K that select_k compares, from the user's ``priors`` argument.

One rule for the plain Gaussian path and the other noise models: ``priors`` None
gives the default priors with one intensity bound shared by every K (``i_max``,
or derived from the readings); a mapping ``{K: ScenePrior}`` or a callable
``K -> ScenePrior`` gives the user's, each checked for its K, its kind and, by
the caller's ``check``, the parameters the noise model needs.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from .._validation import positive_float
from ..errors import InputError
from ..model import Model
from ..priors import ScenePrior, default_priors

__all__ = ["prior_factory"]


def prior_factory(model: Model, data: np.ndarray, priors: object, i_max: float | None, *,
                  check: Callable[[ScenePrior], None], frames: bool = False
                  ) -> Callable[[int], ScenePrior]:
    """``K -> ScenePrior`` from ``priors``.

    Parameters
    ----------
    model : Model
    data : ndarray, shape (N,) or (F, N)
        The readings (``frames``: F frames of them), for the data-derived bound.
    priors : None, mapping {K: ScenePrior} or callable K -> ScenePrior
    i_max : float or None
        Intensity bound of the default priors (only with ``priors`` None).
    check : callable
        ``check(prior)`` raises :class:`~olsbayes.errors.InputError` for a user's
        prior the caller cannot use.
    frames : bool
        Whether ``data`` holds frames.

    A prior of the wrong K or kind, or one ``check`` refuses, is refused when
    the factory is called for that K.
    """
    if priors is None:
        # one data-derived bound shared by every K (plates: over the default box)
        bound = (default_priors(model, 1, data=data, frames=frames).intensity.upper
                 if i_max is None else positive_float("i_max", i_max))
        return lambda k: default_priors(model, k, i_max=bound)
    if i_max is not None:
        raise InputError("give either priors= or i_max=, not both")
    if isinstance(priors, Mapping):
        get = priors.__getitem__
    elif callable(priors):
        get = priors
    else:
        raise InputError("priors must be None, a mapping {K: ScenePrior} or a callable "
                         f"K -> ScenePrior; got {type(priors).__name__}")

    def factory(k: int) -> ScenePrior:
        try:
            p = get(k)
        except KeyError:
            raise InputError(f"priors has no entry for K = {k}") from None
        if not isinstance(p, ScenePrior) or p.n_sources != k or p.kind != model.kind:
            raise InputError(f"priors for K = {k} must be a ScenePrior of {k} {model.kind!r} "
                             f"sources; got {p!r}")
        check(p)
        return p

    return factory
