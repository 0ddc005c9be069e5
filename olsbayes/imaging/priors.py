"""Intensity priors of the imaging mode: small frozen records, validated when built.

Each prior carries exactly the settings it uses:

* :class:`Gaussian` -- independent ``N(mean, sd^2)``; closed-form posterior and evidence.
* :class:`NonNegative` -- flat on ``I >= 0``.
* :class:`Bounded` -- uniform on ``[0, i_max]``.
* :class:`Sparse` -- spike-and-slab ``(1 - w) delta_0 + w U(0, i_max)`` with
  ``w ~ Beta(a, b)``, so the data decide how sparse the scene is.  Experimental:
  not offered by name (:data:`PRIORS`) or on the command line, because its Gibbs
  sampler does not mix on ill-posed scenes (see :data:`WITHDRAWN`); the object
  is still accepted, and non-mixing chains are warned about.
* :class:`TwoLevel` -- each intensity 0 or ``i_max``, bright with probability
  ``p_bright``; its MAP scene is found by a local search.

**No silent clipping.**  An upper bound that is too low truncates the posterior
and returns the bound with a tiny sd.  ``Bounded`` and ``Sparse`` therefore take
``i_max=None`` by default, which :func:`~olsbayes.imaging.image` replaces by the
bound :func:`data_bound` derives from the readings -- the same rule as the
posterior's :func:`olsbayes.priors.data_intensity_bound`, with the known
directions' gains -- and ``image`` warns
(:class:`~olsbayes.errors.PriorBoundWarning`) whenever a posterior still piles
up at ``i_max``.  The two-level prior's ``i_max`` is the intensity of a bright
source, a model parameter rather than a bound, so it must be given.

Every prior has a ``scale`` (intensity units): a direction of intensity space
counts as measured when the readings pin it to better than ``scale``
(:attr:`olsbayes.imaging.Design.effective_rank`), and the samplers size their
starting jitter and the exact-HMC surrogate ridge by it.  For the priors with
an upper bound it is ``i_max``; the flat and Gaussian priors have none, so it
is a field of theirs.
"""

from __future__ import annotations

import dataclasses
import numbers
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .._validation import positive_float, positive_pair
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
    "data_bound",
    "with_data_bound",
]


def _real(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not np.isfinite(value):
        raise InputError(f"{name} must be a finite real number; got {value!r}")
    return float(value)


def _set(obj: object, name: str, value: object) -> None:
    object.__setattr__(obj, name, value)


@dataclass(frozen=True)
class ImagingPrior(ABC):
    """Base of the imaging priors; ``name`` is the value of ``ImageResult.prior``.

    Every concrete prior gives its ``scale`` (a field or a property).
    """

    name: ClassVar[str] = ""

    @property
    @abstractmethod
    def scale(self) -> float:
        """Intensity scale of the prior (see the module notes)."""


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
    """A prior supported on ``[0, i_max]``; ``i_max=None``: derived from the readings."""

    i_max: float | None = None

    def __post_init__(self) -> None:
        if self.i_max is not None:
            _set(self, "i_max", positive_float(f"{type(self).__name__}.i_max", self.i_max))

    def _bound(self) -> float:
        if self.i_max is None:
            raise InputError(f"{type(self).__name__}.i_max is not set yet: image() derives it "
                             "from the readings (olsbayes.imaging.with_data_bound)")
        return self.i_max

    @property
    def scale(self) -> float:
        """``i_max``."""
        return self._bound()

    @property
    def upper(self) -> float:
        """Upper bound of the support: ``i_max``."""
        return self._bound()


@dataclass(frozen=True)
class Bounded(_BoxPrior):
    """Uniform prior on ``[0, i_max]``.

    Attributes
    ----------
    i_max : float or None
        Upper bound of every intensity (> 0); None (default): derived from the
        readings by :func:`data_bound`.
    """

    name: ClassVar[str] = "bounded"


@dataclass(frozen=True)
class Sparse(_BoxPrior):
    """Spike-and-slab prior ``(1 - w) delta_0 + w U(0, i_max)``, ``w ~ Beta(a, b)``.

    A source is dark with probability ``1 - w``, otherwise of any intensity up
    to ``i_max``; the slab weight ``w`` has a Beta hyperprior and is sampled too.

    Attributes
    ----------
    i_max : float or None
        Upper bound of the slab (> 0); None (default): derived from the readings
        by :func:`data_bound`.
    weight_prior : (float, float)
        Parameters ``(a, b)`` of the Beta hyperprior of ``w`` (both > 0;
        default uniform).
    """

    name: ClassVar[str] = "sparse"
    weight_prior: tuple[float, float] = (1.0, 1.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        _set(self, "weight_prior", positive_pair("Sparse.weight_prior", self.weight_prior))


@dataclass(frozen=True)
class TwoLevel(_BoxPrior):
    """Two-level prior: each intensity is 0 or ``i_max``, bright with probability ``p_bright``.

    The posterior is reported by its MAP scene, found by a local search
    (:mod:`olsbayes.imaging.binary`).  No sampler of it is offered: the block
    Gibbs sampler of :mod:`olsbayes.imaging.binary_gibbs` does not mix at the
    noise levels of interest (its ``WITHDRAWN``).

    Attributes
    ----------
    i_max : float
        Intensity of a bright source (> 0); required.
    p_bright : float
        Prior probability that a source is bright, in (0, 1).
    """

    name: ClassVar[str] = "two-level"
    p_bright: float = 0.5

    def __post_init__(self) -> None:
        if self.i_max is None:
            raise InputError("TwoLevel needs i_max, the intensity of a bright source (> 0): "
                             "e.g. TwoLevel(i_max=1.0)")
        super().__post_init__()
        p = self.p_bright
        if isinstance(p, bool) or not isinstance(p, numbers.Real) or not 0 < p < 1:
            raise InputError(f"TwoLevel.p_bright must be a number in (0, 1); got {p!r}")
        _set(self, "p_bright", float(p))


_BY_NAME: dict[str, type[ImagingPrior]] = {
    cls.name: cls for cls in (Gaussian, NonNegative, Bounded, TwoLevel)
}
#: Names accepted for ``prior`` (each means its prior with default settings).
PRIORS: tuple[str, ...] = tuple(_BY_NAME)
#: Prior names no longer offered, and why (the measured split R-hat).
WITHDRAWN = {
    "sparse": "its spike-and-slab Gibbs sampler does not mix on ill-posed scenes (largest "
              "split R-hat 5.5 at 200 and 3.9 at 1000 draws per chain on the Fig. 2 "
              "scene); olsbayes.imaging.Sparse remains for experiments",
}


def data_bound(matrix: np.ndarray, data: np.ndarray, sigma: float) -> float:
    """Weakly informative intensity bound (> 0) from the readings and the design.

    Every source adds a non-negative reading, so a source k of intensity I seen
    with best sub-sensor gain ``g_k = max_n A[n, k]`` gives ``max(data) >= g_k I``
    up to noise.  Returns ``2 (max(data) + 3 sigma) / min_k g_k``: twice the
    largest intensity any direction's readings allow, the rule of
    :func:`olsbayes.priors.data_intensity_bound` with the known gains.

    Parameters
    ----------
    matrix : ndarray, shape (N, K)
        Design matrix (every column non-zero: every direction seen).
    data : ndarray, shape (N,)
    sigma : float
        Noise sd of one reading.
    """
    gain = float(np.min(np.max(matrix, axis=0)))
    top = max(float(np.max(data)), 0.0) + 3.0 * sigma
    return 2.0 * top / gain


def with_data_bound(prior: ImagingPrior, matrix: np.ndarray, data: np.ndarray,
                    sigma: float) -> ImagingPrior:
    """``prior`` with ``i_max`` set by :func:`data_bound` when it is None; else unchanged."""
    if isinstance(prior, _BoxPrior) and prior.i_max is None:
        return dataclasses.replace(prior, i_max=data_bound(matrix, data, sigma))
    return prior


def as_prior(prior: ImagingPrior | str) -> ImagingPrior:
    """The prior object for a prior object or a name of :data:`PRIORS` (default settings).

    ``"two-level"`` has no default bright level: pass ``TwoLevel(i_max=...)``.
    """
    if isinstance(prior, (*_BY_NAME.values(), Sparse)):
        return prior
    if isinstance(prior, str) and prior.lower() in WITHDRAWN:
        raise InputError(f"prior {prior!r} is not offered: {WITHDRAWN[prior.lower()]}")
    if isinstance(prior, str) and prior.lower() == "two-level":
        raise InputError("prior 'two-level' needs the intensity of a bright source: pass "
                         "TwoLevel(i_max=...) (its i_max is a model parameter, not a bound)")
    if isinstance(prior, str) and prior.lower() in _BY_NAME:
        return _BY_NAME[prior.lower()]()
    raise InputError(
        f"prior must be one of {', '.join(map(repr, PRIORS))} or a prior object "
        f"(Gaussian, NonNegative, Bounded, TwoLevel; Sparse, experimental); got {prior!r}"
    )
