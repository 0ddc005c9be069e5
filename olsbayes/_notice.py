"""Status lines on stderr for long steps that show no progress bar of their own.

Steps that take seconds without a bar print one line as they start (``olsbayes:
...``): compiling the kernels on their first use, building the ML search of a
large array, a large batch of ML fits, a long exact enumeration.  The command
line's ``--quiet`` runs its command inside :func:`silenced`; warnings and errors
still print.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["notice", "silenced"]

_QUIET = [False]  # inside silenced(): the command line's --quiet


def notice(text: str) -> None:
    """Print ``olsbayes: <text>`` as one line on stderr, unless silenced."""
    if not _QUIET[0]:
        print(f"olsbayes: {text}", file=sys.stderr, flush=True)


@contextmanager
def silenced(on: bool = True) -> Iterator[None]:
    """No status lines while the block runs (when ``on``); restored afterwards."""
    before = _QUIET[0]
    _QUIET[0] = before or bool(on)
    try:
        yield
    finally:
        _QUIET[0] = before
