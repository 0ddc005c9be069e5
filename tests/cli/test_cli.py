"""The olsbayes command line: subcommands, --json, errors as one line + exit 2."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from olsbayes import Model, Ring, Scene, crlb
from olsbayes.cli import COMMANDS, build_parser, main
from olsbayes.cli._common import DEFAULT_CONFIG


def run_cli(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code, err):
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "error" in lines[0]
    assert "Traceback" not in err


def test_every_command_has_help(capsys):
    for name in (None, *COMMANDS):
        code, out, _ = run_cli(capsys, *([name] if name else []), "--help")
        assert code == 0
        assert out.startswith("usage: olsbayes")


def test_parser_lists_every_command():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert set(COMMANDS) <= set(sub.choices)


def test_crlb_json_matches_library(capsys):
    code, out, _ = run_cli(capsys, "crlb", "--json")
    assert code == 0
    payload = json.loads(out)
    model = Model(Ring(30), 0.01)
    scene = Scene(directions=[0.37, 0.37 - np.pi], intensities=[1.0, 0.2])
    ref = crlb(model, scene)
    np.testing.assert_allclose(payload["crlb"]["direction_std"], ref.direction_std, rtol=1e-12)
    np.testing.assert_allclose(payload["crlb"]["intensity_std"], ref.intensity_std, rtol=1e-12)
    # two sources pi apart are two independent single-source problems: Eq. 3 holds
    np.testing.assert_allclose(payload["paper"]["eq3_direction_std"], ref.direction_std, rtol=1e-9)


def test_crlb_set_override_and_singular_json(capsys):
    code, out, err = run_cli(capsys, "crlb", "--json", "--set", "scene.directions=[0.1, 0.1]")
    assert code == 0
    payload = json.loads(out)  # strict JSON: inf became null
    assert payload["crlb"]["resolvable"] is False
    assert payload["crlb"]["direction_std"] == [None, None]
    assert "ResolutionWarning" in err and len(err.strip().splitlines()) == 1


def test_simulate_writes_file_fit_can_read(tmp_path, capsys):
    out_file = tmp_path / "r.txt"
    code, out, _ = run_cli(capsys, "simulate", "--seed", "5", "--repeats", "3",
                           "--out", str(out_file))
    assert code == 0 and "wrote 3 row(s)" in out
    rows = np.loadtxt(out_file)
    assert rows.shape == (3, 30)
    model = Model(Ring(30), 0.01)
    expect = model.simulate(Scene(directions=[0.37, 0.37 - np.pi], intensities=[1.0, 0.2]),
                            rng=5, size=3)
    np.testing.assert_allclose(rows, expect, rtol=0, atol=1e-14)  # %.17g round trip


def test_simulate_to_npy_writes_an_array_fit_reads_back(tmp_path, capsys):
    """An --out name ending in .npy gets numpy's format (not text under that name),
    which `fit --data` reads back: the same numbers to the bit and the same fit."""
    npy, txt = tmp_path / "r.NPY", tmp_path / "r.txt"
    for out_file in (npy, txt):
        code, out, _ = run_cli(capsys, "simulate", "--seed", "5", "--repeats", "3",
                               "--out", str(out_file))
        assert code == 0 and "wrote 3 row(s)" in out
    rows = np.load(npy, allow_pickle=False)
    assert rows.shape == (3, 30) and rows.dtype == np.float64
    np.testing.assert_array_equal(rows, np.loadtxt(txt))
    fits = [run_cli(capsys, "fit", "--data", str(f), "--n-sources", "2", "--seed", "1",
                    "--json") for f in (npy, txt)]
    assert fits[0][0] == fits[1][0] == 0
    a, b = (json.loads(f[1]) for f in fits)
    assert a["params"] == b["params"] and a["log_likelihood"] == b["log_likelihood"]
    one = tmp_path / "one.npy"
    assert run_cli(capsys, "simulate", "--seed", "5", "--out", str(one))[0] == 0
    assert np.load(one).shape == (30,)  # one measurement, as one row of text reads back


def test_simulate_json_with_config(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text(
        '[sensor]\ngeometry = "sphere"\nlayout = "fibonacci"\nn = 40\nsigma = 0.1\n'
        "[scene]\ndirections = [[0.0, 0.2]]\nintensities = [2.0]\n"
    )
    code, out, _ = run_cli(capsys, "simulate", str(cfg), "--json", "--seed", "1")
    assert code == 0
    assert np.asarray(json.loads(out)["readings"]).shape == (1, 40)


def test_demo_writes_figure_and_json(tmp_path, capsys):
    code, out, _ = run_cli(capsys, "demo", "--out", str(tmp_path / "d"), "--json",
                           "--no-posterior")
    assert code == 0
    payload = json.loads(out)
    assert "posterior" not in payload
    # an efficient estimator: every error below 5 CRLB standard deviations
    assert np.all(np.abs(payload["fit"]["error_over_std"]) < 5.0)
    assert payload["n_sensors"] == 30 and payload["sigma"] == 0.01
    assert payload["truth"]["intensities"] == [0.2, 1.0]  # canonical order (by angle)
    for fig in payload["figures"]:
        assert Path(fig).stat().st_size > 1000


def test_demo_print_config_round_trips(capsys):
    code, out, _ = run_cli(capsys, "demo", "--print-config")
    assert code == 0 and out == DEFAULT_CONFIG


@pytest.mark.parametrize(
    "argv",
    [
        ["nonsense"],
        ["crlb", "--bogus"],
        ["crlb", "/no/such/file.toml"],
        ["crlb", "--set", "sensor.n=2"],
        ["crlb", "--set", "sensor.colour=1"],
        ["crlb", "--set", "nodot=1"],
        ["demo", "--seed", "-3"],
        ["simulate", "--repeats", "0"],
    ],
)
def test_bad_input_is_one_line_exit_2(argv, capsys):
    code, _, err = run_cli(capsys, *argv)
    assert_one_line_error(code, err)


@pytest.mark.slow
def test_real_subprocess_demo(tmp_path):
    env = dict(os.environ, MPLBACKEND="Agg")
    exe = Path(sys.executable).with_name("olsbayes")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-c",
                                            "import sys; from olsbayes.cli import main; "
                                            "sys.exit(main())"]
    proc = subprocess.run(cmd + ["demo", "--out", str(tmp_path / "demo")], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "CRLB" in proc.stdout and "Posterior" in proc.stdout
    for name in ("response.png", "posterior/corner.png", "posterior/report.html"):
        assert (tmp_path / "demo" / name).stat().st_size > 1000


def test_fit_recovers_simulated_scene_within_crlb(tmp_path, capsys):
    readings = tmp_path / "r.txt"
    assert main(["simulate", "--seed", "9", "--out", str(readings)]) == 0
    capsys.readouterr()
    cfg = tmp_path / "c.toml"
    cfg.write_text(DEFAULT_CONFIG.split("[data]")[0] + f'[data]\nfile = "{readings.name}"\n')
    code, out, _ = run_cli(capsys, "fit", str(cfg), "--json")
    assert code == 0
    payload = json.loads(out)
    assert payload["converged"] is True
    # estimation errors of an efficient estimator: |err| / CRLB below 5 (5-sigma)
    assert np.all(np.abs(payload["error_over_std"]) < 5.0)


def test_fit_batch_file_and_missing_k(tmp_path, capsys):
    readings = tmp_path / "r.txt"
    main(["simulate", "--seed", "2", "--repeats", "2", "--out", str(readings)])
    capsys.readouterr()
    code, out, _ = run_cli(capsys, "fit", "--data", str(readings), "--n-sources", "2", "--json")
    assert code == 0
    assert np.asarray(json.loads(out)["params"]).shape == (2, 4)
    code, _, err = run_cli(capsys, "fit", "--data", str(readings))
    assert_one_line_error(code, err)
    assert "--n-sources" in err


@pytest.mark.slow
def test_fit_posterior_report(tmp_path, capsys):
    """--report runs emcee from the ML point and writes the report; a short run warns."""
    rep = tmp_path / "rep"
    code, out, err = run_cli(capsys, "fit", "--report", str(rep), "--seed", "1",
                             "--max-steps", "200", "--json")
    assert code == 0
    post = json.loads(out)["posterior"]
    assert (rep / "report.html").exists() and (rep / "corner.png").exists()
    assert np.all(np.isfinite(post["crlb_sd"])) and len(post["estimate"]) == 4
    # 200 steps are too few for 50 autocorrelation times: one line, a warning; and one
    # status line as the report's figures start
    said = f"olsbayes: writing the posterior report to {rep} (figures, tables, NetCDF, HTML) ..."
    lines = err.strip().splitlines()
    assert lines.count(said) == 1 and len(lines) == 2
    assert [ln for ln in lines if ln != said][0].startswith("olsbayes: warning: ConvergenceWarning")


def test_fit_posterior_uses_the_ml_order_in_every_output(tmp_path, capsys):
    """Sources pi apart: the text, the JSON posterior block (with names), summary.csv,
    summary.json and posterior.nc list the sources in the ML table's order; the seed,
    data hash and version are recorded."""
    import csv

    from olsbayes.posterior import PosteriorResult

    rep = tmp_path / "rep"
    code, out, err = run_cli(capsys, "fit", "--report", str(rep), "--seed", "4",
                             "--max-steps", "300", "--json")
    assert code == 0, err
    payload = json.loads(out)
    post = payload["posterior"]
    assert post["names"] == payload["param_names"] == ["theta[0]", "I[0]", "theta[1]", "I[1]"]
    ml, est = np.array(payload["params"]), np.array(post["estimate"])
    sd = np.array(post["crlb_sd"])
    assert np.all(np.abs(np.angle(np.exp(1j * (est - ml)))) < 5 * sd)  # same source per label
    assert payload["provenance"]["seed"] == 4 and len(payload["provenance"]["data_sha256"]) == 64
    assert 0 <= post["model_check"]["ppp"] <= 1 and post["model_check"]["dof"] == 26
    summary = json.loads((rep / "summary.json").read_text())
    assert summary["names"] == post["names"] == list(summary["parameters"])
    with (rep / "summary.csv").open() as fh:
        assert [row[0] for row in csv.reader(fh)][1:] == post["names"]
    back = PosteriorResult.from_netcdf(rep / "posterior.nc")
    assert list(back.names) == post["names"]
    np.testing.assert_allclose(back.estimate, est, rtol=1e-12)
    assert back.seed is not None and summary["run"]["seed"] == back.seed


def test_fit_draws_prints_and_records_a_seed_when_none_is_given(capsys):
    code, out, _ = run_cli(capsys, "fit")
    assert code == 0
    line = next(ln for ln in out.splitlines() if ln.startswith("seed "))
    assert "drawn" in line and int(line.split()[1]) >= 0
    code, out, _ = run_cli(capsys, "fit", "--json")
    payload = json.loads(out)
    assert isinstance(payload["provenance"]["seed"], int)
    assert abs(payload["chi2_dof"] - 1) < 3 * np.sqrt(2 / payload["dof"])


def test_fit_honours_degrees_on_output(tmp_path, capsys):
    cfg = tmp_path / "deg.toml"
    cfg.write_text(DEFAULT_CONFIG.replace(
        "directions = [0.37, -2.7715926535897933]   # rad, pi apart",
        'directions = [21.2, -158.8]\nangle_unit = "deg"'))
    code, out, _ = run_cli(capsys, "fit", str(cfg), "--json", "--seed", "1")
    assert code == 0
    payload = json.loads(out)
    assert payload["angle_unit"] == "deg"
    np.testing.assert_allclose(payload["params"][0::2], [-158.8, 21.2], atol=3)
    np.testing.assert_allclose(payload["truth"][0::2], [-158.8, 21.2], atol=1e-9)
    code, out, _ = run_cli(capsys, "fit", str(cfg), "--seed", "1")
    assert "locations in deg" in out


def test_fit_posterior_rejects_contradictory_options(tmp_path, capsys):
    readings = tmp_path / "r.txt"
    main(["simulate", "--repeats", "2", "--out", str(readings)])
    capsys.readouterr()
    code, _, err = run_cli(capsys, "fit", "--data", str(readings), "--n-sources", "2",
                           "--posterior")
    assert_one_line_error(code, err)
    assert "one measurement" in err
    code, _, err = run_cli(capsys, "fit", "--posterior", "--max-steps", "0")
    assert_one_line_error(code, err)


def test_import_and_help_stay_light():
    """`import olsbayes` and `olsbayes --help` load no plotting/sampling/cluster stack."""
    heavy = ("matplotlib", "arviz", "dask", "distributed", "emcee", "dynesty", "corner",
             "xarray", "pandas")
    code = ("import sys, olsbayes, olsbayes.cli; olsbayes.cli.build_parser(); "
            f"print(','.join(m for m in {heavy!r} if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == ""


SPHERE_TOML = """[sensor]
geometry = "sphere"
n_lat = 15
n_lon = 20
sigma = 0.01
[scene]
directions = [[20.0, 10.0], [-100.0, -30.0]]
angle_unit = "deg"
intensities = [1.0, 0.5]
[data]
simulate = true
seed = 3
"""

PLATE_TOML = """[sensor]
geometry = "plate"
nx = 8
ny = 8
pitch = 0.5
sigma = 0.001
[scene]
positions = [[0.3, -0.2, 1.5]]
intensities = [1.0]
[data]
simulate = true
seed = 3
"""


@pytest.mark.parametrize("text,n_params", [(SPHERE_TOML, 6), (PLATE_TOML, 4)])
def test_fit_and_crlb_on_sphere_and_plate(tmp_path, capsys, text, n_params):
    cfg = tmp_path / "c.toml"
    cfg.write_text(text)
    code, out, _ = run_cli(capsys, "fit", str(cfg), "--json")
    assert code == 0
    payload = json.loads(out)
    assert len(payload["params"]) == n_params
    assert np.all(np.abs(payload["error_over_std"]) < 5.0)  # within 5 CRLB sd
    code, out, _ = run_cli(capsys, "crlb", str(cfg), "--json")
    bound = json.loads(out)["crlb"]
    assert code == 0 and bound["resolvable"] is True
    key = "position_std" if "plate" in text else "direction_std"
    assert np.asarray(bound[key]).shape == (n_params // (4 if "plate" in text else 3),
                                            3 if "plate" in text else 2)


def test_fit_exact_method_ring_only(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text(SPHERE_TOML)
    code, _, err = run_cli(capsys, "fit", str(cfg), "--method", "exact")
    assert_one_line_error(code, err)
    assert "needs a Ring model" in err
    code, out, _ = run_cli(capsys, "fit", "--method", "exact", "--json")
    assert code == 0 and json.loads(out)["method"] == "exact"


def test_compile_reports_its_cache_in_json(capsys):
    assert main(["compile", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["calls"] > 10 and out["cache_kind"] and out["cpu_seconds"] >= 0
