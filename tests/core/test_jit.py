"""numba's cache folder: chosen before numba loads, never a traceback on a read-only install."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import olsbayes._jit as jit

_VARS = ("NUMBA_CACHE_DIR", "NUMBA_CACHE_LOCATOR_CLASSES")


@pytest.fixture
def fresh(monkeypatch, tmp_path):
    """_choose() with no NUMBA_* variables, a package folder and homes under tmp_path."""
    saved = {var: os.environ.pop(var, None) for var in _VARS}
    kernels = tmp_path / "pkg"
    kernels.mkdir()
    monkeypatch.setattr(jit, "_KERNELS", kernels)
    monkeypatch.setattr(jit, "_user_cache", lambda: tmp_path / "user")
    monkeypatch.setattr(jit, "_temporary", lambda: tmp_path / "tmp")
    yield tmp_path
    for var, value in saved.items():  # _choose() sets them: never leak them to other tests
        os.environ.pop(var, None)
        if value is not None:
            os.environ[var] = value


def _unwritable(monkeypatch, *names):
    real = jit._writable
    monkeypatch.setattr(jit, "_writable", lambda folder: (
        not any(part in names for part in Path(folder).parts) and real(folder)))


def test_a_given_cache_folder_is_kept(fresh):
    os.environ["NUMBA_CACHE_DIR"] = str(fresh / "mine")
    assert jit._choose() == ("NUMBA_CACHE_DIR", str(fresh / "mine"))


def test_writable_package_folder_keeps_numba_default(fresh):
    assert jit._choose()[0] == "next to the modules"
    assert "NUMBA_CACHE_DIR" not in os.environ


def test_read_only_install_falls_back_to_user_then_temporary(fresh, monkeypatch):
    _unwritable(monkeypatch, "pkg")
    assert jit._choose() == ("user cache", str(fresh / "user"))
    assert os.environ.pop("NUMBA_CACHE_DIR") == str(fresh / "user")
    _unwritable(monkeypatch, "pkg", "user")
    assert jit._choose() == ("temporary", str(fresh / "tmp"))


def test_read_only_install_with_prebuilt_kernels_reads_them(fresh, monkeypatch):
    (fresh / "pkg" / "__pycache__").mkdir()
    (fresh / "pkg" / "__pycache__" / "lm.kernel-1.py311.nbi").write_bytes(b"")
    _unwritable(monkeypatch, "pkg")
    assert jit._choose()[0] == "prebuilt, read-only"
    assert os.environ["NUMBA_CACHE_LOCATOR_CLASSES"] == "olsbayes._jit.NoSaveLocator"


def test_nothing_writable_turns_saving_off(fresh, monkeypatch):
    _unwritable(monkeypatch, "pkg", "user", "tmp")
    assert jit._choose() == ("none", None)
    assert os.environ["NUMBA_CACHE_LOCATOR_CLASSES"] == "olsbayes._jit.NoSaveLocator"


def test_no_writable_folder_at_all_fits_with_one_warning_and_no_traceback(tmp_path):
    """A fresh process where no folder can be written still fits (kernels not saved)."""
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    script = textwrap.dedent(f"""
        import json, warnings
        from pathlib import Path
        import olsbayes._jit as jit
        jit._KERNELS = Path({str(blocked)!r}) / "pkg"
        jit._temporary = lambda: None
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            import olsbayes as ob
            model = ob.Model(ob.Ring(12), 0.01)
            fit = ob.fit_ml(model, model.response([0.3, 1.0]), 1, warn=False)
        print(json.dumps({{"how": jit.cache_location()[0], "theta": float(fit.params[0]),
                          "warnings": [str(w.message) for w in caught]}}))
    """)
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update(HOME=str(blocked), XDG_CACHE_HOME=str(blocked / "cache"))
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    out = json.loads(proc.stdout)
    assert out["how"] == "none"
    assert abs(out["theta"] - 0.3) < 1e-6
    assert len(out["warnings"]) == 1 and "NUMBA_CACHE_DIR" in out["warnings"][0]


def test_other_numba_functions_compile_beside_the_notice(tmp_path):
    """The compile notice listens to every numba compile in the process; a function
    without a module (built by exec) or of another package compiles undisturbed."""
    script = textwrap.dedent("""
        import olsbayes, olsbayes._jit as jit
        jit.prepare()  # the listener is registered
        import numba
        namespace = {}
        exec("def f(x):\\n    return 2 * x", namespace)  # no __name__: __module__ is None
        assert namespace["f"].__module__ is None
        print(numba.njit(namespace["f"])(21), numba.njit(lambda x: x + 1)(41))
    """)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["42", "42"]
    assert "compiling numerical kernels" not in proc.stderr  # not a package kernel


def test_the_kernels_stamp_covers_every_kernel_module(tmp_path, monkeypatch):
    """The stamp hashes each module with cached kernels, and only those."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text("@numba.njit(cache=True)\ndef f(x):\n    return x\n")
    (pkg / "sub" / "b.py").write_text("@numba.njit(cache=True)\ndef g(x):\n    return x\n")
    (pkg / "c.py").write_text("x = 1\n")
    monkeypatch.setattr(jit, "_PACKAGE", pkg)
    stamps = []
    for edit in (None, pkg / "c.py", pkg / "sub" / "b.py", pkg / "a.py"):
        if edit is not None:
            edit.write_text(edit.read_text() + "# edited\n")
        jit.kernels_stamp.cache_clear()
        stamps.append(jit.kernels_stamp())
    jit.kernels_stamp.cache_clear()
    assert stamps[0] == stamps[1]  # not a kernel module
    assert len(set(stamps[1:])) == 3  # each kernel module's edit changes it


def test_package_kernels_are_stamped_with_every_kernel_module():
    """A cached kernel is stamped with all kernel sources, so an edit or an upgrade of a
    kernel it calls from another module compiles it again instead of loading stale code."""
    from olsbayes.ml._numba import model as kernel_model

    jit.prepare()
    locator = kernel_model._residual._cache._impl.locator
    if os.environ.get("NUMBA_CACHE_LOCATOR_CLASSES") and jit.cache_location()[0] not in (
            "prebuilt, read-only", "none"):
        pytest.skip("numba's cache locators are the user's choice")
    stamp = locator.get_source_stamp()
    assert isinstance(stamp, tuple) and stamp[1] == jit.kernels_stamp()
    files = {p.name for p in (Path(jit.__file__).parent / "ml" / "_numba").glob("*.py")}
    assert {"lm.py", "model.py", "fit.py"} <= files


def test_a_later_burst_of_compiling_says_so_again(monkeypatch, capsys):
    """The first compile prints one line; a compile starting a new burst (after a
    pause) at least AGAIN_AFTER s after the last line prints one more; compiles in a
    burst, soon after a line, or after announced() print nothing."""
    state = {"how": "NUMBA_CACHE_DIR", "folder": "x", "said": False, "again": True,
             "said_at": -float("inf"), "ended": -float("inf")}
    monkeypatch.setattr(jit, "_STATE", state)
    gap, again = jit.BURST_GAP, jit.AGAIN_AFTER

    def compile_at(start, end):
        jit.say_compiling(start)
        state["ended"] = end
        return capsys.readouterr().err

    assert compile_at(0.0, 1.0).startswith("olsbayes: compiling numerical kernels for their "
                                           "first use")
    assert compile_at(1.0 + gap / 2, 30.0) == ""  # the same burst
    assert compile_at(30.0 + 2 * gap, 31.0) == "olsbayes: compiling more numerical kernels " \
                                                "for their first use ...\n"
    assert compile_at(31.0 + 2 * gap, 32.0) == ""  # a new burst, but the line is recent
    assert compile_at(30.0 + 2 * gap + again + 1.0, 50.0) != ""
    jit.announced()  # the caller (olsbayes compile) has said it: no more lines
    assert compile_at(100.0, 101.0) == ""
