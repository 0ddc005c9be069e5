"""Angular sensitivity laws g(cos gamma) of one sub-sensor.

A law maps ``c = cos(gamma)`` -- the cosine of the angle between a sub-sensor's
normal and the direction to a source -- to the fraction of the source's intensity
the sub-sensor reads.  Laws work on ``c`` rather than on the angle so that the
forward model needs dot products only (no trigonometry per sensor-source pair).
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable

import numpy as np

from ._frozen import Frozen
from ._validation import positive_float
from .errors import InputError

__all__ = ["Sensitivity", "Cosine", "CosinePower", "CustomSensitivity", "get_sensitivity",
           "is_clipped_cosine"]


class Sensitivity(Frozen):
    """Interface of a sensitivity law (immutable).

    Subclasses implement :meth:`value` and :meth:`derivative`, both vectorised over
    arrays of ``c`` in [-1, 1].  ``kink`` is True when the law's derivative jumps
    at c = 0 (the clipped cosine), where the likelihood is not differentiable.
    """

    name: str = "sensitivity"
    kink: bool = False

    @abstractmethod
    def value(self, c: np.ndarray) -> np.ndarray:
        """g(c), same shape as ``c``."""

    @abstractmethod
    def derivative(self, c: np.ndarray) -> np.ndarray:
        """dg/dc, same shape as ``c``."""

    def __call__(self, c: np.ndarray) -> np.ndarray:
        """g(c): the same as :meth:`value`."""
        return self.value(c)

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class Cosine(Sensitivity):
    """The paper's clipped cosine ``costn``: g(c) = c for c >= 0, else 0.

    Its derivative is taken as 1 for c > 0 and 0 for c <= 0 (the one-sided value
    from the dark side at the kink c = 0).
    """

    name = "cosine"
    kink = True

    def value(self, c: np.ndarray) -> np.ndarray:
        """g(c) = max(c, 0), same shape as ``c``."""
        return np.maximum(c, 0.0)

    def derivative(self, c: np.ndarray) -> np.ndarray:
        """dg/dc: 1 for c > 0, 0 for c <= 0; same shape as ``c``."""
        return (np.asarray(c) > 0.0).astype(float)


class CosinePower(Sensitivity):
    """A sharper law g(c) = max(c, 0)**p with p >= 1 (p = 1 is :class:`Cosine`).

    Laws of this kind are what the paper says resolve close sources better.
    """

    name = "cosine_power"

    def __init__(self, p: float = 2.0):
        self.p = positive_float("p", p, upper=64.0)
        if self.p < 1.0:
            raise InputError(f"p must be in [1, 64] (g must be differentiable); got {self.p!r}")
        self.kink = self.p == 1.0

    def value(self, c: np.ndarray) -> np.ndarray:
        """g(c) = max(c, 0)**p, same shape as ``c``."""
        return _power(np.maximum(c, 0.0), self.p)

    def derivative(self, c: np.ndarray) -> np.ndarray:
        """dg/dc = p max(c, 0)**(p - 1), same shape as ``c``; for p = 1 as :class:`Cosine`."""
        cp = np.maximum(c, 0.0)
        if self.p == 1.0:
            return (cp > 0.0).astype(float)
        out = _power(cp, self.p - 1.0)
        out *= self.p
        return out

    def __repr__(self) -> str:
        return f"CosinePower(p={self.p!r})"


def _power(x: np.ndarray, p: float) -> np.ndarray:
    """x**p for x >= 0 and p >= 0, by repeated squaring for the integer part of p.

    numpy's float ``**`` goes through exp/log (~20x a multiply); integer and
    half-integer exponents -- the common sharper laws -- need multiplies and at
    most one sqrt, with a relative error of a few ulp.
    """
    n, frac = int(p), p - int(p)
    out, base = None, np.asarray(x, dtype=float)
    while n:
        if n & 1:
            out = base.copy() if out is None else np.multiply(out, base, out=out)
        n >>= 1
        if n:
            base = base * base
    if out is None:
        out = np.ones_like(base)
    if frac == 0.5:
        out *= np.sqrt(x)
    elif frac:
        out *= np.power(x, frac)
    return out


class CustomSensitivity(Sensitivity):
    """A user law from two vectorised callables ``func(c)`` and ``derivative(c)``.

    Parameters
    ----------
    func, derivative : callable
        ``g(c)`` and ``dg/dc`` on arrays of ``c = cos(gamma)`` in [-1, 1].
    name : str
        A label for reports.
    kink : bool
        Whether dg/dc jumps somewhere (enables the kink warnings).
    """

    def __init__(
        self,
        func: Callable[[np.ndarray], np.ndarray],
        derivative: Callable[[np.ndarray], np.ndarray],
        name: str = "custom",
        kink: bool = False,
    ):
        if not callable(func) or not callable(derivative):
            raise InputError("func and derivative must both be callables of c = cos(angle)")
        probe = np.linspace(-1.0, 1.0, 7)
        for label, f in (("func", func), ("derivative", derivative)):
            out = np.asarray(f(probe), dtype=float)
            if out.shape != probe.shape or not np.all(np.isfinite(out)):
                raise InputError(
                    f"{label} must map an array of c in [-1, 1] to a finite array of "
                    f"the same shape; got shape {out.shape}"
                )
        self._func, self._deriv = func, derivative
        self.name, self.kink = str(name), bool(kink)

    def value(self, c: np.ndarray) -> np.ndarray:
        """g(c) by the user's ``func``, as a float array."""
        return np.asarray(self._func(c), dtype=float)

    def derivative(self, c: np.ndarray) -> np.ndarray:
        """dg/dc by the user's ``derivative``, as a float array."""
        return np.asarray(self._deriv(c), dtype=float)

    def __repr__(self) -> str:
        return f"CustomSensitivity(name={self.name!r})"


def is_clipped_cosine(law: Sensitivity) -> bool:
    """Whether ``law`` is the paper's clipped cosine itself.

    That is :class:`Cosine`, or :class:`CosinePower` with p = 1 -- not a subclass or a
    custom law that may behave otherwise.  The compiled kernels, the exact enumeration
    and the kink moves of the fast fit rely on its piecewise-linear form.
    """
    return type(law) is Cosine or (type(law) is CosinePower and law.p == 1.0)


def get_sensitivity(spec: str | Sensitivity | None = None, **params: float) -> Sensitivity:
    """A sensitivity law from a name (``"cosine"``/``"costn"``, ``"cosine_power"``).

    ``spec`` may also be a :class:`Sensitivity` instance (returned as is) or None
    (the clipped cosine).  ``params`` go to the law (``p=`` for cosine_power).
    """
    if spec is None:
        spec = "cosine"
    if isinstance(spec, Sensitivity):
        return spec
    if not isinstance(spec, str):
        raise InputError(
            f"sensitivity must be a name or a Sensitivity; got {type(spec).__name__}"
        )
    key = spec.lower().replace("-", "_")
    if key in ("cosine", "costn", "cos"):
        if params:
            raise InputError(f"sensitivity 'cosine' takes no parameters; got {sorted(params)}")
        return Cosine()
    if key in ("cosine_power", "cos_power", "cosp"):
        unknown = set(params) - {"p"}
        if unknown:
            raise InputError(f"sensitivity 'cosine_power' takes only p; got {sorted(unknown)}")
        return CosinePower(**params)
    raise InputError(
        f"sensitivity must be one of 'cosine' (alias 'costn'), 'cosine_power'; got {spec!r}"
    )
