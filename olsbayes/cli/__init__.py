"""The ``olsbayes`` command line.

Each subcommand lives in its own module ``olsbayes/cli/<name>.py`` exposing
``register(subparsers)`` and ``run(args) -> int``.  To add one, write the module
and add ONE line to :data:`COMMANDS` below.

Errors: any :class:`~olsbayes.errors.OlsBayesError` (bad input, bad config)
prints one line ``olsbayes: error: ...`` on stderr and exits with status 2; no
traceback.  Usage errors from argparse do the same.  Warnings are printed as one
line each (``olsbayes: warning: <Class>: ...``) and, with ``--json``, listed in the
output object as ``"warnings": [{"category": ..., "message": ...}, ...]``.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings
from collections.abc import Sequence

from .._notice import silenced
from ..errors import OlsBayesError, OlsBayesWarning
from ._common import OneLineParser

__all__ = ["build_parser", "main", "COMMANDS"]

#: Subcommand modules, in the order ``--help`` lists them.  One line per command.
COMMANDS: tuple[str, ...] = (
    "demo",
    "simulate",
    "crlb",
    "fit",
    "study",
    "select",
    "image",
    "compile",
)


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser (every subcommand registered)."""
    from .._version import __version__

    parser = OneLineParser(
        prog="olsbayes",
        description="Bayesian analysis of optics-less smart (OLS) radiation sensors.",
        epilog="Run `olsbayes COMMAND --help` for a command's options.",
    )
    parser.add_argument("--version", action="version", version=f"olsbayes {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def _warning_printer(record: list[dict[str, str]]):
    """A ``warnings.showwarning`` that prints one line and keeps the warning in ``record``."""

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        text = " ".join(str(message).split())
        record.append({"category": category.__name__, "message": text})
        print(f"olsbayes: warning: {category.__name__}: {text}", file=sys.stderr)

    return show


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status (0 ok, 2 bad input)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, usage errors (already printed)
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    args.warnings_seen = []  # what --json reports as "warnings" (see _common.emit)
    with warnings.catch_warnings(), silenced(getattr(args, "quiet", False)):
        warnings.showwarning = _warning_printer(args.warnings_seen)
        warnings.simplefilter("default", OlsBayesWarning)  # always shown, never fatal
        try:
            return int(args.run(args) or 0)
        except OlsBayesError as exc:
            print(f"olsbayes: error: {' '.join(str(exc).split())}", file=sys.stderr)
            return 2
        except RecursionError:  # a pathologically nested input (TOML, --set) not caught earlier
            print("olsbayes: error: the input is nested too deeply to process", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print("olsbayes: interrupted", file=sys.stderr)
            return 130
        except BrokenPipeError:  # e.g. `olsbayes simulate | head`: stop quietly
            try:
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            except (OSError, ValueError):  # pragma: no cover - stdout already gone
                pass
            return 0
