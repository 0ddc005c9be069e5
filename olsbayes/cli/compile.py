"""Compile the numerical kernels now: once per machine, instead of at their first use.

The package's small numerical kernels are compiled with numba the first time
they run and cached on disk; later processes only load them.  Run this once
after installing (or when building a container image) so that no later command
pays the compilation.  Prints where the cache lives.

Example:
  olsbayes compile
  olsbayes compile --json
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from ._common import add_command, add_json_arg, emit

__all__ = ["register", "run"]


def register(subparsers: Any) -> None:
    """Add the ``compile`` subcommand and its options to ``subparsers``."""
    p = add_command(subparsers, "compile", help="compile the numerical kernels once, now",
                    description=__doc__)
    add_json_arg(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Compile (or load) every kernel specialisation; print the time and the cache folder.

    Returns the exit status 0.
    """
    from .._jit import announced, cache_location
    from ..ml.warmup import compile_kernels

    how, folder = cache_location()
    print("olsbayes: compiling numerical kernels (once per machine; later runs load them "
          "from the cache) ...", file=sys.stderr, flush=True)
    announced()
    cpu0, wall0 = time.process_time(), time.perf_counter()

    def progress(done: int, total: int) -> None:
        if sys.stderr.isatty():
            print(f"\r  {done}/{total} groups of kernels", end="", file=sys.stderr, flush=True)

    n_calls = compile_kernels(progress=progress)
    if sys.stderr.isatty():
        print(file=sys.stderr)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    payload = {"calls": n_calls, "cpu_seconds": cpu, "wall_seconds": wall, "cache": folder,
               "cache_kind": how}
    where = folder if folder is not None else "nowhere (no writable folder: not cached)"
    emit(args, payload, f"Compiled kernels ready ({n_calls} small calls, {cpu:.1f} s CPU, "
                        f"{wall:.1f} s wall); cache ({how}): {where}")
    return 0
