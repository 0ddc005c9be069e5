"""Files are written atomically: an interrupted run never leaves a half-written result.

Two parts: the behaviour of :mod:`olsbayes._io` (temporary file + rename), and an
AST scan of the package that fails when a module writes a file by any route
other than a temporary path from ``atomic_path`` (or an in-memory buffer).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import olsbayes
from olsbayes._io import atomic_path, write_text_atomic

PACKAGE = Path(olsbayes.__file__).parent
MODULES = sorted(p for p in PACKAGE.rglob("*.py") if p.name != "_io.py")

#: Methods/functions that write their first argument as a file.
WRITERS = {"savefig", "to_netcdf", "write_text", "write_bytes", "savez", "savez_compressed",
           "save", "savetxt", "to_csv", "to_json", "to_parquet", "to_zarr", "tofile"}

#: Calls that delegate to an atomic writer by contract (checked where they are defined).
DELEGATES = {("posterior/report.py", "result.to_netcdf")}

#: Deliberate non-atomic writes: the study checkpoint is an append-only journal of
#: length-prefixed, checksummed frames (a torn last frame is detected and dropped).
APPEND_ONLY = {"studies/checkpoint.py"}


def _dotted(node: ast.AST) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return f"{_dotted(node.value)}.{node.attr}"
    return "?"


def _safe_names(func: ast.AST) -> set[str]:
    """Names bound to atomic temporary paths or in-memory buffers inside ``func``."""
    names: set[str] = set()
    for node in ast.walk(func):
        if isinstance(node, (ast.With, ast.AsyncWith)):
            for item in node.items:
                call = item.context_expr
                if (isinstance(call, ast.Call) and _dotted(call.func).endswith("atomic_path")
                        and isinstance(item.optional_vars, ast.Name)):
                    names.add(item.optional_vars.id)
        elif isinstance(node, ast.Assign) and isinstance(node.value, ast.Call):
            if _dotted(node.value.func).split(".")[-1] in ("BytesIO", "StringIO"):
                names.update(t.id for t in node.targets if isinstance(t, ast.Name))
    return names


def _target_name(arg: ast.AST) -> str | None:
    while isinstance(arg, ast.Call) and _dotted(arg.func) == "str" and arg.args:
        arg = arg.args[0]  # str(tmp)
    return arg.id if isinstance(arg, ast.Name) else None


def non_atomic_writes(tree: ast.AST, rel: str) -> list[str]:
    bad = []
    funcs = [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
    for func in funcs:
        safe = _safe_names(func)
        for node in ast.walk(func):
            if not isinstance(node, ast.Call):
                continue
            name = _dotted(node.func)
            last = name.split(".")[-1]
            if last in WRITERS and isinstance(node.func, ast.Attribute):
                if (rel, name) in DELEGATES or not (node.args or node.keywords):
                    continue  # e.g. table.to_csv() returns a string
                if last in ("write_text", "write_bytes"):  # Path method: the receiver
                    target = node.func.value
                else:
                    target = node.args[0] if node.args else None
                if target is None or _target_name(target) not in safe:
                    bad.append(f"{rel}:{node.lineno} {name}(...)")
            elif name == "open" and len(node.args) >= 2:
                mode = node.args[1]
                if isinstance(mode, ast.Constant) and set(str(mode.value)) & set("wax+"):
                    bad.append(f"{rel}:{node.lineno} open(..., {mode.value!r})")
            elif (name == "os.open" and rel not in APPEND_ONLY
                  and not (node.args and _dotted(node.args[0]) == "os.devnull")):
                bad.append(f"{rel}:{node.lineno} os.open(...)")
    return bad


@pytest.mark.parametrize("path", MODULES, ids=[str(p.relative_to(PACKAGE)) for p in MODULES])
def test_package_writes_files_atomically(path):
    rel = str(path.relative_to(PACKAGE))
    tree = ast.parse(path.read_text(encoding="utf-8"))
    assert non_atomic_writes(tree, rel) == []


def test_scanner_flags_direct_writes():
    src = (
        "def f(fig, ds, p):\n"
        "    fig.savefig(p)\n"
        "    with atomic_path(p) as tmp:\n"
        "        ds.to_netcdf(str(tmp))\n"
        "    open(p, 'w')\n"
        "    buf = io.BytesIO()\n"
        "    np.save(buf, 1)\n"
        "    p.write_text('x')\n"
        "    with atomic_path(p) as t:\n"
        "        t.write_bytes(b'x')\n"
    )
    assert non_atomic_writes(ast.parse(src), "x.py") == ["x.py:2 fig.savefig(...)",
                                                         "x.py:5 open(..., 'w')",
                                                         "x.py:8 p.write_text(...)"]


def test_atomic_path_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "result.txt"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("interrupted")
    assert not target.exists()
    assert list(tmp_path.iterdir()) == []  # no temporary file left behind


def test_atomic_replace_keeps_old_file_until_complete(tmp_path):
    target = write_text_atomic(tmp_path / "r.txt", "old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("new but incomplete")
            raise RuntimeError
    assert target.read_text() == "old"
    write_text_atomic(target, "new")
    assert target.read_text() == "new" and len(list(tmp_path.iterdir())) == 1


def test_atomic_files_get_the_usual_permissions(tmp_path):
    """mkstemp creates 0600 files; results must be readable like any other file."""
    import os

    umask = os.umask(0o022)
    os.umask(umask)
    path = write_text_atomic(tmp_path / "r.txt", "x")
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask
