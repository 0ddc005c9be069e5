"""CLI hardening: usage errors as `olsbayes: error:`, warnings in --json, safe output
files, typed data files, ranges, and the multi-row fit computing its errors once."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.cli import main

DATA = ob.Model(ob.Ring(30), 0.01).simulate(
    ob.Scene(directions=[0.37, -2.77], intensities=[1.0, 0.2]), rng=3, size=5)


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _one_line_error(code, err, match=None):
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, (code, err)
    assert lines[0].startswith("olsbayes: error: ") and "Traceback" not in err, err
    if match is not None:
        assert match in lines[0], lines[0]


def _cases(tmp: Path) -> list[tuple[list, str]]:
    """(argv, text the error line must hold) of bad CLI inputs new to this catalogue."""
    np.save(tmp / "struct.npy", np.zeros(30, dtype=[("a", float), ("b", int)]))
    np.save(tmp / "cplx.npy", DATA + 1j)
    np.save(tmp / "dt.npy", np.arange(30).astype("datetime64[s]"))
    np.savez(tmp / "z.npz", a=DATA)
    os.replace(tmp / "z.npz", tmp / "npz.npy")
    from numpy.lib import format as fmt

    with open(tmp / "huge.npy", "wb") as f:
        fmt.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False,
                                       "shape": (10**9, 30)})
    (tmp / "secret.txt").write_text("SECRET_TOKEN=hunter2 1 2\n")
    (tmp / "deep.toml").write_text("x = " + "{a = " * 50_000 + "1" + "}" * 50_000 + "\n")
    (tmp / "normals.txt").write_text("1 0\nAWS_KEY=hunter2 1\n0 1\n")
    (tmp / "custom.toml").write_text('[sensor]\ngeometry = "custom"\nsigma = 0.1\n'
                                     'normals_file = "normals.txt"\n[scene]\n'
                                     'directions = [0.1]\nintensities = [1.0]\n')
    study = tmp / "study.toml"
    study.write_text('[study]\ntrial = "noise_check"\nn_trials = 2\nseed = 1\n'
                     'out = "s.nc"\nexecutor = "serial"\n[grid]\nsigma = [0.01]\n')
    fifo = tmp / "fifo"
    os.mkfifo(fifo)
    fit2 = ["fit", "--n-sources", 2, "--data"]
    return [
        (fit2 + [tmp / "struct.npy"], "structured"),
        (fit2 + [tmp / "cplx.npy"], "complex"),
        (fit2 + [tmp / "dt.npy"], "datetime"),
        (fit2 + [tmp / "npz.npy"], ".npz archive"),
        (fit2 + [tmp / "huge.npy"], "header says shape (1000000000, 30)"),
        (fit2 + [tmp / "secret.txt"], "line 1, field 1 is not a number"),
        (fit2 + [fifo], "not a regular file"),
        (["crlb", tmp / "deep.toml"], "nested too deeply"),
        (["crlb", tmp / "custom.toml"], "line 2, field 1 is not a number"),
        (["crlb", "--set", "sensor.sigma=1e-320"], "sigma must be in [1e-100, 1e+100]"),
        (["fit", "--set", "sensor.sigma=1e-200"], "sigma must be in"),
        (["crlb", "--set", "sensor.sigma=1e155"], "magnitude"),
        (["fit", "--n-sources", "abc"], "fit: argument --n-sources"),
        (["select", "--k-max", "x"], "select: argument --k-max"),
        (["study", study, "--executor", "dask", "--scheduler", "garbage"],
         "cannot reach the Dask scheduler"),
        (["simulate", "--out", fifo], "is a FIFO"),
        (["simulate", "--out", tmp], "is a folder"),
    ]


def test_cli_hardening_catalogue(tmp_path, capsys):
    cases = _cases(tmp_path)
    for argv, match in cases:
        code, _, err = _run(capsys, *argv)
        _one_line_error(code, err, match)
        assert "hunter2" not in err
    assert len(cases) >= 17
    assert (tmp_path / "fifo").exists()


def test_a_device_is_refused_without_writing():
    """Checked on the path alone (a regression must not replace a real device node)."""
    from olsbayes._io import write_target
    from olsbayes.errors import InputError

    with pytest.raises(InputError, match="is a character device"):
        write_target("/dev/null", "--out")
    assert Path("/dev/null").is_char_device()


def test_a_deeply_nested_study_file_is_one_line(tmp_path, capsys):
    deep = tmp_path / "deep.toml"
    deep.write_text('[study]\ntrial = "noise_check"\nx = ' + "{a = " * 50_000 + "1"
                    + "}" * 50_000 + "\n")
    code, _, err = _run(capsys, "study", deep)
    _one_line_error(code, err, "nested too deeply")


def test_usage_errors_of_subcommands_start_with_olsbayes(capsys):
    code, _, err = _run(capsys, "crlb", "--frob")
    _one_line_error(code, err, "olsbayes: error: ")
    assert "olsbayes crlb: error" not in err


def test_out_through_a_symlink_writes_the_file_and_keeps_the_link(tmp_path, capsys):
    target = tmp_path / "real.txt"
    target.write_text("old\n")
    target.chmod(0o640)
    link = tmp_path / "link.txt"
    link.symlink_to(target)
    code, _, err = _run(capsys, "simulate", "--out", link)
    assert code == 0, err
    assert link.is_symlink() and link.resolve() == target.resolve()
    assert target.read_text().startswith("# olsbayes simulate")
    assert target.stat().st_mode & 0o777 == 0o640  # the file's own permissions kept
    dangling = tmp_path / "dangling.txt"
    dangling.symlink_to(tmp_path / "new.txt")
    assert _run(capsys, "simulate", "--out", dangling)[0] == 0
    assert dangling.is_symlink() and (tmp_path / "new.txt").is_file()


def test_symlink_loop_is_one_line(tmp_path, capsys):
    loop = tmp_path / "loop.txt"
    loop.symlink_to(loop)
    code, _, err = _run(capsys, "simulate", "--out", loop)
    _one_line_error(code, err, "cannot be written")


def test_json_lists_the_warnings(capsys):
    code, out, err = _run(capsys, "crlb", "--json", "--set", "scene.directions=[0.3, 0.3]")
    assert code == 0
    payload = json.loads(out)
    assert [w["category"] for w in payload["warnings"]] == ["ResolutionWarning"]
    assert err.startswith("olsbayes: warning: ResolutionWarning: ")
    code, out, _ = _run(capsys, "crlb", "--json")
    assert json.loads(out)["warnings"] == []


def test_fit_json_reports_a_poor_fit(tmp_path, capsys):
    path = tmp_path / "r.txt"
    np.savetxt(path, DATA[:1])
    code, out, err = _run(capsys, "fit", "--data", path, "--n-sources", 1, "--json")
    assert code == 0
    cats = [w["category"] for w in json.loads(out)["warnings"]]
    assert "ConvergenceWarning" in cats and "do not describe the readings" in err


def test_multi_row_fit_computes_the_errors_once(tmp_path, capsys, monkeypatch):
    """MLResult.std, a (T, P) array, is computed once, not once per printed row (O(T^2))."""
    from olsbayes.ml.result import MLResult

    calls = []
    std = MLResult.std.fget
    monkeypatch.setattr(MLResult, "std", property(lambda self: calls.append(1) or std(self)))
    path = tmp_path / "rows.txt"
    np.savetxt(path, np.tile(DATA, (8, 1)))  # 40 rows
    code, out, _ = _run(capsys, "fit", "--data", path, "--n-sources", 2)
    assert code == 0 and len(calls) == 1
    lines = out.splitlines()
    head = next(i for i, line in enumerate(lines) if line.split()[:2] == ["row", "k"])
    assert len(lines) == head + 2 + 40 * 2  # header, rule, a line per row and source
    calls.clear()
    code, out, _ = _run(capsys, "fit", "--data", path, "--n-sources", 2, "--json")
    payload = json.loads(out)
    assert code == 0 and len(calls) == 1 and np.shape(payload["std"]) == (40, 4)
    api = ob.fit_ml(ob.Model(ob.Ring(30), 0.01), np.loadtxt(path), 2)
    np.testing.assert_allclose(payload["params"], api.params, rtol=1e-12)


@pytest.mark.parametrize("argv", [["simulate", "--out", "{fifo}"],
                                  ["image", "--figure", "{fifo}"]])
def test_special_outputs_are_refused_before_the_work(tmp_path, capsys, argv, monkeypatch):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    import olsbayes.model

    def boom(*a, **k):
        raise AssertionError("work started before the output was checked")

    monkeypatch.setattr(olsbayes.model.Model, "simulate", boom)
    code, _, err = _run(capsys, *[a.format(fifo=fifo) for a in argv],
                        *(["--set", 'sensor.geometry="sphere"', "--set", "sensor.n_lat=4",
                           "--set", "sensor.n_lon=6"] if argv[0] == "image" else []))
    assert code == 2 and "olsbayes: error:" in err
