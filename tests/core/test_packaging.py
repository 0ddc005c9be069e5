"""Packaging: dependencies exactly as imported, python -m olsbayes, typed marker, licence."""

import ast
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import olsbayes

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = Path(olsbayes.__file__).parent
#: Distribution name of an imported top-level module where the two differ.
DISTRIBUTION = {"distributed": "distributed"}
#: Used by name rather than imported: the NetCDF engine of xarray and ArviZ.
ENGINES = {"h5netcdf"}
#: Imported only by the optional Dask executor (the ``dask`` extra).
OPTIONAL = {"dask", "distributed"}


def _imported_top_level() -> set[str]:
    names = set()
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return {n for n in names if n not in sys.stdlib_module_names and n != "olsbayes"}


def _declared() -> tuple[set[str], set[str]]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]

    def name(req: str) -> str:
        for sep in "<>=[; ":
            req = req.split(sep)[0]
        return req.strip().lower()

    extras = {name(r) for reqs in project["optional-dependencies"].values() for r in reqs}
    return {name(r) for r in project["dependencies"]}, extras


def test_dependencies_are_exactly_the_imported_packages():
    imported = {DISTRIBUTION.get(n, n).lower() for n in _imported_top_level()}
    required, extras = _declared()
    assert imported - OPTIONAL == required - ENGINES, (imported, required)
    assert OPTIONAL <= extras


def test_python_dash_m_olsbayes_runs_the_command_line():
    proc = subprocess.run([sys.executable, "-m", "olsbayes", "--version"], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0 and proc.stdout.strip() == f"olsbayes {olsbayes.__version__}"


def test_importing_the_package_loads_no_heavy_dependency():
    """scipy, numba, plotting and Dask load on first use: `import olsbayes` (every command
    line call, every new worker process) takes about half the CPU it took with scipy."""
    heavy = ("scipy", "numba", "matplotlib", "arviz", "xarray", "dask", "emcee", "dynesty")
    script = ("import sys, olsbayes; "
              f"print(sorted({{m.split('.')[0] for m in sys.modules}} & set({heavy!r})))")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    assert proc.returncode == 0 and proc.stdout.strip() == "[]", proc.stdout + proc.stderr


def test_the_wings_load_on_first_use_and_every_public_name_resolves():
    """Imaging, posteriors, model selection, studies and calibration load when first
    touched (a fit or a study worker needs none of them); every name of ``__all__``
    and every submodule is then an attribute as before."""
    wings = ("calibration", "imaging", "posterior", "select", "studies")
    script = ("import sys, olsbayes as ob; "
              f"print(sorted(w for w in {wings!r} if 'olsbayes.' + w in sys.modules)); "
              "print(ob.image is ob.imaging.image, ob.sample_posterior is ob.posterior.sample, "
              "'select_k' in dir(ob), 'imaging' in dir(ob)); "
              "from olsbayes import *; print(all(n in globals() for n in ob.__all__))")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["[]", "True", "True", "True", "True", "True"], proc.stdout
    for name in olsbayes.__all__:
        assert getattr(olsbayes, name) is not None, name
    for name in olsbayes._SUBMODULES:
        assert getattr(olsbayes, name).__name__ == f"olsbayes.{name}"
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        olsbayes.nope  # noqa: B018


def test_the_version_is_written_once_and_is_the_installed_metadata():
    from importlib.metadata import version

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "version" in project["project"]["dynamic"]
    attr = project["tool"]["setuptools"]["dynamic"]["version"]["attr"]
    assert attr == "olsbayes._version.__version__"
    assert version("olsbayes") == olsbayes.__version__


def test_typed_marker_licence_and_citation_ship_with_the_package():
    assert (PACKAGE / "py.typed").is_file()
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert project["tool"]["setuptools"]["package-data"]["olsbayes"] == ["py.typed"]
    licence = (ROOT / "LICENSE").read_text()
    assert project["project"]["license"] == "BSD-3-Clause" and "BSD 3-Clause License" in licence
    citation = (ROOT / "CITATION.cff").read_text(encoding="utf-8")
    assert "Optics-less Sensors for Localization of Radiation Sources" in citation
    assert f'version: "{olsbayes.__version__}"' in citation
