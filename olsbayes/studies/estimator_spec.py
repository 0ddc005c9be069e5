"""Which estimator a ring study runs: a name plus its options, validated up front.

An :class:`Estimator` is a small frozen record, e.g. ``Estimator("multistart",
n_starts=5)``.  Its options are checked against :data:`ESTIMATORS` when it is
made, so an unknown name, an unknown option or a value out of range is refused
before any trial runs.  Equal estimators have equal canonical labels --
``"fast"``, ``"fast(batched=True)"``, ``"multistart(n_starts=5)"`` -- which a
study uses as the coordinate of its ``estimator`` axis.

In a grid (Python or TOML) an estimator may be written as

* an :class:`Estimator`;
* a name alone, for estimators without required options: ``"fast"``;
* a pair ``(name, {option: value})``: ``("multistart", {"n_starts": 5})``;
* a table with a ``name`` key: ``{"name": "multistart", "n_starts": 5}``
  (TOML: ``{name = "multistart", n_starts = 5}``).

:func:`as_estimator` turns any of these into an :class:`Estimator`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from .._validation import _short, integer
from ..errors import InputError

__all__ = ["Estimator", "EstimatorOption", "ESTIMATORS", "as_estimator"]


class _Required:
    """Marks an option without a default."""

    def __repr__(self) -> str:
        return "required"


_REQUIRED = _Required()


@dataclass(frozen=True)
class EstimatorOption:
    """One option of an estimator: a flag, or an integer in ``[low, high]``.

    Attributes
    ----------
    doc : str
        What the option sets.
    default : object
        Value when the option is not given (None also accepts None); absent:
        the option must be given.
    low, high : int or None
        Accepted range of an integer option; None for a flag (True or False).
    """

    doc: str
    default: Any = _REQUIRED
    low: int | None = None
    high: int | None = None

    @property
    def required(self) -> bool:
        """True when the option has no default."""
        return self.default is _REQUIRED

    def check(self, name: str, value: object) -> Any:
        """The validated value, or InputError naming ``name`` and the accepted values."""
        if value is None and self.default is None:
            return None
        if self.low is None:
            if not isinstance(value, bool):
                raise InputError(f"{name} must be true or false; got {_short(value)}")
            return value
        return integer(name, value, low=self.low, high=self.high)

    @property
    def accepted(self) -> str:
        """The accepted values, e.g. ``"an integer in [1, 100000]"``."""
        return "true or false" if self.low is None else f"an integer in [{self.low}, {self.high}]"

    def describe(self) -> str:
        """The accepted values and the default, e.g. ``"an integer in [1, 100000], required"``."""
        text = self.accepted
        if self.required:
            return f"{text}, required"
        default = str(self.default).lower() if self.default in (None, True, False) \
            else repr(self.default)
        return f"{text}, default {default}"


#: The estimators of :func:`olsbayes.studies.estimators.ring_estimate` and their options.
ESTIMATORS: Mapping[str, Mapping[str, EstimatorOption]] = MappingProxyType({
    "fast": MappingProxyType({
        "batched": EstimatorOption("fit all trials of a chunk in one batched fit_ml call",
                                   default=False),
    }),
    "multistart": MappingProxyType({
        "n_starts": EstimatorOption("pseudo-random starts of the multistart baseline",
                                    low=1, high=100_000),
    }),
    "exact": MappingProxyType({}),
    "posterior": MappingProxyType({
        "n_steps": EstimatorOption("emcee steps of every chain (a fixed length)",
                                   low=1, high=10_000_000),
        "n_walkers": EstimatorOption("emcee walkers, at least 2 per parameter (none: the "
                                     "sampler's choice)", default=None, low=2, high=100_000),
    }),
    "nested": MappingProxyType({
        "max_calls": EstimatorOption("cap on the likelihood calls of nested sampling",
                                     default=20_000, low=1000, high=10**9),
    }),
})


def _canonical(name: object, options: Mapping[str, object]) -> tuple[str, tuple]:
    """Validated ``(name, ((option, value), ...))`` in the table's order, defaults filled."""
    if not isinstance(name, str) or name not in ESTIMATORS:
        raise InputError(f"unknown estimator name {_short(name)}; accepted: "
                         f"{', '.join(repr(n) for n in ESTIMATORS)}")
    table = ESTIMATORS[name]
    unknown = [k for k in options if k not in table]
    if unknown:
        accepted = f"accepted options: {', '.join(table)}" if table else "it takes none"
        raise InputError(f"{name} has no option {unknown[0]!r}; {accepted}")
    values = []
    for key, spec in table.items():
        if key in options:
            values.append((key, spec.check(f"{name} option {key}", options[key])))
        elif spec.required:
            raise InputError(f"{name} needs option {key}, {spec.accepted}")
        else:
            values.append((key, spec.default))
    return name, tuple(values)


@dataclass(frozen=True, init=False, repr=False)
class Estimator:
    """An estimator of a ring study: a name from :data:`ESTIMATORS` and its options.

    * ``Estimator("fast")``: :func:`olsbayes.ml.fit_ml`, method "fast", one fit per
      trial; with ``batched=True`` one batched call for all trials of a chunk.
    * ``Estimator("multistart", n_starts=M)``: the paper's multistart baseline with M
      pseudo-random starts.
    * ``Estimator("exact")``: the global ML optimum by enumeration (clipped cosine,
      K <= 4).
    * ``Estimator("posterior", n_steps=L)``: the posterior mean of an emcee run of
      exactly L steps (optional ``n_walkers``).
    * ``Estimator("nested")``: the posterior mean from dynesty nested sampling, capped
      at ``max_calls`` likelihood calls (default 20000).

    Parameters
    ----------
    name : str
        One of the names above.
    **options
        The estimator's options; unknown ones and values out of range raise
        :class:`~olsbayes.errors.InputError`.

    Attributes
    ----------
    name : str
    options : tuple of (str, object)
        Every option of the estimator in the table's order, defaults filled in, so
        equal estimators compare (and hash) equal.
    """

    name: str
    options: tuple[tuple[str, Any], ...]

    def __init__(self, name: str, /, **options: object) -> None:
        name, values = _canonical(name, options)
        object.__setattr__(self, "name", name)
        object.__setattr__(self, "options", values)

    def option(self, key: str) -> Any:
        """The value of option ``key``."""
        for k, v in self.options:
            if k == key:
                return v
        raise KeyError(f"estimator {self.name!r} has no option {key!r}")

    def replace(self, **changes: object) -> Estimator:
        """A copy with some options changed (validated like the constructor)."""
        return Estimator(self.name, **{**dict(self.options), **changes})

    def _shown(self) -> list[str]:
        """``"key=value"`` of the required options and of those off their default."""
        table = ESTIMATORS[self.name]
        return [f"{k}={v!r}" for k, v in self.options
                if table[k].required or v != table[k].default]

    @property
    def label(self) -> str:
        """Canonical text: the name, then required options and those off their default.

        E.g. ``"fast"``, ``"fast(batched=True)"``, ``"multistart(n_starts=5)"``,
        ``"posterior(n_steps=300)"``.
        """
        shown = self._shown()
        return self.name + (f"({', '.join(shown)})" if shown else "")

    def to_json(self) -> dict[str, Any]:
        """``{"name": ..., **options}`` with every option (read back by :func:`as_estimator`)."""
        return {"name": self.name, **dict(self.options)}

    def __repr__(self) -> str:
        return f"Estimator({', '.join([repr(self.name), *self._shown()])})"


def as_estimator(value: object, where: str = "estimator") -> Estimator:
    """An :class:`Estimator` from any accepted spelling (see the module docstring).

    Parameters
    ----------
    value : Estimator, str, (str, dict) or dict with a "name" key
    where : str
        Names the setting in error messages, e.g. ``"grid['estimator'][1]"``.

    Raises
    ------
    InputError
        Naming ``where``, the unknown name or option and the accepted ones, or the
        option's accepted range.
    """
    if isinstance(value, Estimator):
        return value
    try:
        if isinstance(value, str):
            return Estimator(value)
        if isinstance(value, tuple) and len(value) == 2 and isinstance(value[1], Mapping):
            return Estimator(value[0], **value[1])
        if isinstance(value, Mapping) and "name" in value:
            return Estimator(value["name"], **{k: v for k, v in value.items() if k != "name"})
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
    except TypeError:  # option names that are not strings
        pass
    raise InputError(
        f"{where} must be an Estimator, a name ({', '.join(repr(n) for n in ESTIMATORS)}), "
        f"a pair (name, {{option: value}}) or a table {{name = ..., option = ...}}; "
        f"got {_short(value)}"
    )
