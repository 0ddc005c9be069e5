"""No use of numpy's legacy global random state anywhere in the package.

Randomness must flow through explicit ``rng`` arguments (``numpy.random.Generator``
built by ``as_rng`` / ``default_rng``, streams split with ``SeedSequence.spawn``).
This test parses every module of the package and fails on any reference to a
``numpy.random`` attribute outside the explicit-state API -- ``np.random.seed``,
``np.random.normal``, ``np.random.rand`` ... -- however numpy was imported.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import olsbayes

#: numpy.random names that create or describe explicit state (allowed).
ALLOWED = {
    "default_rng",
    "Generator",
    "SeedSequence",
    "BitGenerator",
    "PCG64",
    "PCG64DXSM",
    "Philox",
    "SFC64",
    "MT19937",
    # a *local* legacy generator object, used only to hand emcee a state derived
    # from the user's Generator (RandomState(seed).get_state()); never the global one
    "RandomState",
}

PACKAGE = Path(olsbayes.__file__).parent
MODULES = sorted(PACKAGE.rglob("*.py"))


def _violations(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, name) of every numpy.random attribute outside ALLOWED."""
    numpy_names = {"numpy"}  # local names bound to the numpy module
    random_names: set[str] = set()  # local names bound to numpy.random
    bad: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "numpy":
                    numpy_names.add(alias.asname or "numpy")
                elif alias.name == "numpy.random":
                    if alias.asname:
                        random_names.add(alias.asname)
                    # `import numpy.random` binds `numpy`, already covered
        elif isinstance(node, ast.ImportFrom) and node.module:
            if node.module == "numpy":
                for alias in node.names:
                    if alias.name == "random":
                        random_names.add(alias.asname or "random")
            elif node.module == "numpy.random":
                for alias in node.names:
                    if alias.name not in ALLOWED:
                        bad.append((node.lineno, f"from numpy.random import {alias.name}"))
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute):
            continue
        base = node.value
        is_random = (
            isinstance(base, ast.Attribute)
            and base.attr == "random"
            and isinstance(base.value, ast.Name)
            and base.value.id in numpy_names
        ) or (isinstance(base, ast.Name) and base.id in random_names)
        if is_random and node.attr not in ALLOWED:
            bad.append((node.lineno, f"numpy.random.{node.attr}"))
    return bad


def test_package_modules_found():
    assert len(MODULES) >= 10


@pytest.mark.parametrize("path", MODULES, ids=[str(p.relative_to(PACKAGE)) for p in MODULES])
def test_no_legacy_global_random_state(path):
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    assert _violations(tree) == [], f"{path}: legacy numpy.random global-state use"


@pytest.mark.parametrize(
    "source,expected",
    [
        ("import numpy as np\nnp.random.seed(1)\n", ["numpy.random.seed"]),
        ("import numpy\nx = numpy.random.normal()\n", ["numpy.random.normal"]),
        ("from numpy import random as r\nr.rand(3)\n", ["numpy.random.rand"]),
        ("import numpy.random as npr\nnpr.shuffle(a)\n", ["numpy.random.shuffle"]),
        ("from numpy.random import choice\n", ["from numpy.random import choice"]),
        ("import numpy as np\ng = np.random.default_rng(1)\ng.normal()\n", []),
        ("import numpy as np\nnp.random.SeedSequence(3).spawn(2)\n", []),
    ],
)
def test_scanner_catches_every_import_style(source, expected):
    assert [name for _, name in _violations(ast.parse(source))] == expected
