"""The package's version (``olsbayes.__version__``), the one place it is written.

``pyproject.toml`` reads it from here (``[tool.setuptools.dynamic]``), so the
installed metadata and the attribute agree, and importing the package does not
import :mod:`importlib.metadata` (about 0.05-0.1 s of a process's start).
"""

__all__ = ["__version__"]

__version__: str = "0.1.0"
