"""Shared pytest set-up.

* A non-interactive matplotlib backend for every test.
* ``rng``: a ``numpy.random.Generator`` seeded from the test's own id, so every test
  has a fixed, distinct stream without sharing one.
* Every compiled kernel is built once per session before the first test (numba
  compiles on first call), so that no single test is charged with the compilation.
  The tests run in pytest-xdist workers (``addopts`` in pyproject.toml; ``-n 0``: one
  process): each worker is a session of its own and builds or loads the kernels once.
* No progress bar unless a test asks for one (``olsbayes._progress.DELAY`` is set to
  an hour; the bar tests set their own): a test's stderr then does not depend on how
  fast the machine ran it.
* The ``slow`` marker (``-m "not slow"`` skips the longest end-to-end tests).
* The numpy references of the compiled kernels live in ``tests/reference``: import
  them as ``from reference.<module> import ...`` (this folder is on ``sys.path``
  because it holds this conftest).
"""

import os
import zlib

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture
def rng(request) -> np.random.Generator:
    """A Generator seeded by the CRC-32 of the test's node id."""
    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()))


@pytest.fixture(autouse=True)
def _no_bar_unless_asked(monkeypatch) -> None:
    """Bars wait an hour before they show (a test that checks them sets its own delay)."""
    monkeypatch.setattr("olsbayes._progress.DELAY", 3600.0)


@pytest.fixture(scope="session", autouse=True)
def _compiled_kernels() -> None:
    """Compile (or load from numba's cache) every kernel once, before the first test.

    Then no further compile line: a kernel outside the warm-up that a test compiles
    (with an empty cache) says nothing, so a test's stderr does not depend on which
    kernels its worker had met before, nor on the clock.
    """
    from olsbayes._jit import announced
    from olsbayes.ml.warmup import compile_kernels

    compile_kernels()
    announced()
