"""Shared pytest set-up: a non-interactive matplotlib backend for every test.

The numpy references of the compiled kernels live in ``tests/reference`` (import
them as ``from reference.<module> import ...``); pytest puts this folder on
``sys.path`` because it holds this conftest.
"""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
