"""Intensity priors of the imaging mode: small frozen records, validated when built.

Each prior carries exactly the settings it uses:

* :class:`Gaussian` -- independent ``N(mean, sd^2)``; closed-form posterior and evidence.
* :class:`NonNegative` -- flat on ``I >= 0``.
* :class:`Bounded` -- uniform on ``[0, i_max]``.
* :class:`Sparse` -- spike-and-slab ``(1 - w) delta_0 + w U(0, i_max)`` with
  ``w ~ Beta(a, b)``, so the data decide how sparse the scene is.
* :class:`TwoLevel` -- each intensity 0 or ``i_max``, bright with probability
  ``p_bright``; its MAP scene is found by a local search.

Every prior has a ``scale`` (intensity units): a direction of intensity space
counts as measured when the readings pin it to better than ``scale``
(:attr:`olsbayes.imaging.Design.effective_rank`), and the samplers size their
starting jitter and the exact-HMC surrogate ridge by it.  For the priors with
an upper bound it is ``i_max``; the flat and Gaussian priors have none, so it
is a field of theirs.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .._validation import positive_float
from ..errors import InputError

__all__ = [
    "ImagingPrior",
    "Gaussian",
    "NonNegative",
    "Bounded",
    "Sparse",
    "TwoLevel",
    "PRIORS",
    "as_prior",
]


def _real(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not np.isfinite(value):
        raise InputError(f"{name} must be a finite real number; got {value!r}")
    return float(value)


def _set(obj: object, name: str, value: object) -> None:
    object.__setattr__(obj, name, value)


@dataclass(frozen=True)
class ImagingPrior:
    """Base of the imaging priors; ``name`` is the value of ``ImageResult.prior``."""

    name: ClassVar[str] = ""

    @property
    def scale(self) -> float:
        """Intensity scale of the prior (see the module notes)."""
        raise NotImplementedError


@dataclass(frozen=True)
class Gaussian(ImagingPrior):
    """Independent ``N(mean, sd^2)`` prior of every intensity (closed form).

    Attributes
    ----------
    mean : float
        Prior mean (intensity units; any finite value).
    sd : float
        Prior standard deviation (> 0).
    scale : float
        Intensity scale of the design diagnostics (> 0).
    """

    name: ClassVar[str] = "gaussian"
    mean: float = 0.5
    sd: float = 0.5
    scale: float = 1.0

    def __post_init__(self) -> None:
        _set(self, "mean", _real("Gaussian.mean", self.mean))
        _set(self, "sd", positive_float("Gaussian.sd", self.sd))
        _set(self, "scale", positive_float("Gaussian.scale", self.scale))


@dataclass(frozen=True)
class NonNegative(ImagingPrior):
    """Flat prior on ``I >= 0`` (improper; the posterior is proper when A has full rank).

    Attributes
    ----------
    scale : float
        Typical intensity (> 0): the design diagnostics' scale, the size of the
        chains' starting jitter and of the exact-HMC surrogate ridge.
    """

    name: ClassVar[str] = "nonnegative"
    scale: float = 1.0

    def __post_init__(self) -> None:
        _set(self, "scale", positive_float("NonNegative.scale", self.scale))

    @property
    def upper(self) -> float:
        """Upper bound of the support: inf."""
        return float("inf")


@dataclass(frozen=True)
class _BoxPrior(ImagingPrior):
    """A prior supported on ``[0, i_max]``."""

    i_max: float = 1.0

    def __post_init__(self) -> None:
        _set(self, "i_max", positive_float(f"{type(self).__name__}.i_max", self.i_max))

    @property
    def scale(self) -> float:
        """``i_max``."""
        return self.i_max

    @property
    def upper(self) -> float:
        """Upper bound of the support: ``i_max``."""
        return self.i_max


@dataclass(frozen=True)
class Bounded(_BoxPrior):
    """Uniform prior on ``[0, i_max]``.

    Attributes
    ----------
    i_max : float
        Upper bound of every intensity (> 0).
    """

    name: ClassVar[str] = "bounded"


@dataclass(frozen=True)
class Sparse(_BoxPrior):
    """Spike-and-slab prior ``(1 - w) delta_0 + w U(0, i_max)``, ``w ~ Beta(a, b)``.

    A source is dark with probability ``1 - w``, otherwise of any intensity up
    to ``i_max``; the slab weight ``w`` has a Beta hyperprior and is sampled too.

    Attributes
    ----------
    i_max : float
        Upper bound of the slab (> 0).
    weight_prior : (float, float)
        Parameters ``(a, b)`` of the Beta hyperprior of ``w`` (both > 0;
        default uniform).
    """

    name: ClassVar[str] = "sparse"
    weight_prior: tuple[float, float] = (1.0, 1.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        wp = self.weight_prior
        if isinstance(wp, (str, bytes)) or not hasattr(wp, "__len__") or len(wp) != 2:
            raise InputError(f"Sparse.weight_prior must be a pair (a, b) of numbers > 0; "
                             f"got {wp!r}")
        _set(self, "weight_prior", tuple(positive_float("Sparse.weight_prior", v) for v in wp))


@dataclass(frozen=True)
class TwoLevel(_BoxPrior):
    """Two-level prior: each intensity is 0 or ``i_max``, bright with probability ``p_bright``.

    The posterior is reported by its MAP scene, found by a local search
    (:mod:`olsbayes.imaging.binary`); ``olsbayes.imaging.two_level_gibbs``
    samples it.

    Attributes
    ----------
    i_max : float
        Intensity of a bright source (> 0).
    p_bright : float
        Prior probability that a source is bright, in (0, 1).
    """

    name: ClassVar[str] = "two-level"
    p_bright: float = 0.5

    def __post_init__(self) -> None:
        super().__post_init__()
        p = self.p_bright
        if isinstance(p, bool) or not isinstance(p, numbers.Real) or not 0 < p < 1:
            raise InputError(f"TwoLevel.p_bright must be a number in (0, 1); got {p!r}")
        _set(self, "p_bright", float(p))


_BY_NAME: dict[str, type[ImagingPrior]] = {
    cls.name: cls for cls in (Gaussian, NonNegative, Bounded, Sparse, TwoLevel)
}
#: Names accepted for ``prior`` (each means its prior with default settings).
PRIORS: tuple[str, ...] = tuple(_BY_NAME)


def as_prior(prior: ImagingPrior | str) -> ImagingPrior:
    """The prior object for a prior object or a name of :data:`PRIORS` (default settings)."""
    if isinstance(prior, tuple(_BY_NAME.values())):
        return prior
    if isinstance(prior, str) and prior.lower() in _BY_NAME:
        return _BY_NAME[prior.lower()]()
    raise InputError(
        f"prior must be one of {', '.join(map(repr, PRIORS))} or a prior object "
        f"(Gaussian, NonNegative, Bounded, Sparse, TwoLevel); got {prior!r}"
    )
