"""Whether this call comes from top-level code of the running script that its workers re-run.

A local pool's and a local Dask cluster's workers fork from a server that imports
the running script (as ``__mp_main__``), so that trials defined there can be
found.  A script that starts a study at its top level, outside
``if __name__ == "__main__":``, therefore starts it again inside that server,
which cannot start processes while it is importing: the stdlib then prints
several tracebacks and the pool breaks, seconds into the study or never if the
study happens to finish in its own process first.  :func:`unguarded_call` finds
such a call before anything starts, so that it is refused at once in one line.

It reads the script's syntax tree and the line its top-level frame is at; where
it cannot tell (no script file, source unreadable, the call made from another
thread) it says nothing and the study runs as it would have.
"""

from __future__ import annotations

import ast
import functools
import os
import sys
from pathlib import Path

__all__ = ["unguarded_call", "guarded_line"]


def _tests_name(test: ast.expr) -> bool:
    return any(isinstance(node, ast.Name) and node.id == "__name__" for node in ast.walk(test))


def _guards(tree: ast.Module) -> tuple[tuple[int, int], ...]:
    """First and last lines of every ``if`` of ``tree`` that tests ``__name__``."""
    return tuple((node.lineno, node.end_lineno or node.lineno) for node in ast.walk(tree)
                 if isinstance(node, ast.If) and _tests_name(node.test))


def guarded_line(tree: ast.Module, line: int) -> bool:
    """Whether top-level line ``line`` of ``tree`` is under an ``if`` that tests ``__name__``.

    Its body or its ``else``: any such test counts, so that no guarded call is
    ever refused.
    """
    return _within(_guards(tree), line)


def _within(guards: tuple[tuple[int, int], ...], line: int) -> bool:
    """Whether ``line`` lies in one of the ``(first, last)`` line ranges ``guards``."""
    return any(first <= line <= last for first, last in guards)


@functools.lru_cache(maxsize=4)
def _layout(path: str, stamp: tuple[int, int]) -> tuple[tuple, tuple[int, ...]] | None:
    """The script's guards (:func:`_guards`) and its top-level statements' first lines.

    Parsed once per version of the file (``stamp``: mtime in ns, size): parsing
    a 400-line script takes ~10 ms, a sizeable part of a small study.  None if
    the file cannot be read or parsed.
    """
    try:
        tree = ast.parse(Path(path).read_bytes(), filename=path)
    except (OSError, SyntaxError, ValueError):
        return None
    return _guards(tree), tuple(node.lineno for node in tree.body)


def unguarded_call() -> tuple[str, int] | None:
    """``(script path, line)`` of the running script's unguarded statement behind this call.

    The line is where the top-level statement begins.  None when the process
    runs no script file (``python -c``, a notebook, an interactive session),
    when the script's ``<module>`` frame is not on this thread's stack, when its
    source cannot be read or parsed, and when the line is under an ``if`` that
    tests ``__name__``.
    """
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if not isinstance(path, str):
        return None
    frame = sys._getframe(1)
    while frame is not None and not (frame.f_code.co_name == "<module>"
                                     and frame.f_globals is vars(main)):
        frame = frame.f_back
    if frame is None:
        return None
    try:
        info = os.stat(path)
    except (OSError, ValueError):
        return None
    layout = _layout(path, (info.st_mtime_ns, info.st_size))
    line = frame.f_lineno
    if layout is None or _within(layout[0], line):
        return None
    starts = [first for first in layout[1] if first <= line]
    return path, max(starts, default=line)  # where the statement begins
