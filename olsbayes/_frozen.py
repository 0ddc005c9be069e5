"""Immutable objects: attributes are set in ``__init__`` and never again.

Models, sensor arrays and sensitivity laws key the caches of derived constants
(atoms, compiled-kernel arguments, designs), so changing one in place would leave
those caches describing another object.  Instances of :class:`Frozen` refuse any
attribute assignment once their constructor has returned; copies and unpickled
instances stay frozen.
"""

from __future__ import annotations

from abc import ABCMeta

__all__ = ["Frozen"]


class _FrozenMeta(ABCMeta):
    """Marks an instance frozen when its class's constructor returns."""

    def __call__(cls, *args, **kwargs):
        obj = super().__call__(*args, **kwargs)
        object.__setattr__(obj, "_frozen", True)
        return obj


class Frozen(metaclass=_FrozenMeta):
    """Base of immutable classes (abstract methods allowed, as with ``abc.ABC``)."""

    #: Appended to the error message (e.g. which method returns a changed copy).
    _mutation_hint = ""

    def __setattr__(self, name: str, value: object) -> None:
        if self.__dict__.get("_frozen", False):
            raise AttributeError(
                f"cannot set {name!r}: {type(self).__name__} objects are immutable"
                f"{self._mutation_hint}")
        object.__setattr__(self, name, value)

    def __delattr__(self, name: str) -> None:
        if self.__dict__.get("_frozen", False):
            raise AttributeError(
                f"cannot delete {name!r}: {type(self).__name__} objects are immutable")
        object.__delattr__(self, name)
