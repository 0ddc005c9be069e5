"""Angles in and out: Scene(unit="deg"), out-of-range degrees refused, angle_unit on output."""

from __future__ import annotations

import json
import textwrap

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.cli import main


def test_scene_in_degrees_equals_the_scene_in_radians():
    deg = ob.Scene(directions=[350.0, 10.0], intensities=[1.0, 2.0], unit="deg")
    rad = ob.Scene(directions=np.deg2rad([350.0, 10.0]), intensities=[1.0, 2.0])
    assert deg == rad
    np.testing.assert_allclose(deg.directions, np.deg2rad([-10.0, 10.0]), atol=1e-15)
    sphere = ob.Scene(directions=[[-180.0, 90.0], [45.0, -30.0]], intensities=[1.0, 1.0],
                      unit="deg")
    np.testing.assert_allclose(sphere.directions, [[np.pi, np.pi / 2], [np.pi / 4, -np.pi / 6]],
                               atol=1e-15)


@pytest.mark.parametrize("directions,match", [
    ([370.0, 10.0], r"\[-360, 360\]; got 370.0"),
    ([-361.0], r"\[-360, 360\]; got -361.0"),
    ([[0.0, 91.0]], r"latitudes in deg must lie in \[-90, 90\]; got 91.0"),
    ([[400.0, 0.0]], r"longitudes in deg must lie in \[-360, 360\]"),
])
def test_out_of_range_degrees_are_refused_not_wrapped(directions, match):
    with pytest.raises(ob.InputError, match=match):
        ob.Scene(directions=directions, intensities=np.ones(len(directions)), unit="deg")


def test_unit_is_checked():
    with pytest.raises(ob.InputError, match="unit must be one of"):
        ob.Scene(directions=[0.0], intensities=[1.0], unit="grad")
    with pytest.raises(ob.InputError, match="positions are lengths"):
        ob.Scene(positions=[[0.0, 0.0, 1.0]], intensities=[1.0], unit="deg")


def _deg_config(tmp_path, directions="[21.2, -158.8]"):
    path = tmp_path / "deg.toml"
    path.write_text(textwrap.dedent(f"""\
        [sensor]
        geometry = "ring"
        n = 30
        sigma = 0.01
        [scene]
        directions = {directions}
        intensities = [1.0, 0.2]
        angle_unit = "deg"
        [data]
        simulate = true
        seed = 3
        """))
    return path


def test_cli_crlb_prints_angles_in_the_scene_unit(tmp_path, capsys):
    assert main(["crlb", str(_deg_config(tmp_path)), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["angle_unit"] == "deg"
    np.testing.assert_allclose(out["truth"]["directions"], [21.2, -158.8])
    # Eq. 3 in deg: 2 sigma / (sqrt(N) I) rad
    np.testing.assert_allclose(out["crlb"]["direction_std"],
                               np.rad2deg(2 * 0.01 / np.sqrt(30) / np.array([1.0, 0.2])),
                               rtol=1e-9)


def test_cli_refuses_out_of_range_degrees_in_a_config(tmp_path, capsys):
    assert main(["crlb", str(_deg_config(tmp_path, "[370.0, 10.0]"))]) == 2
    assert "[-360, 360]; got 370.0" in capsys.readouterr().err


def test_cli_select_json_gives_ml_angles_in_the_scene_unit(tmp_path, capsys):
    code = main(["select", str(_deg_config(tmp_path)), "--k-max", "2", "--method", "laplace",
                 "--json", "--seed", "1"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["angle_unit"] == "deg"
    two = out["results"][0]["candidates"][2]
    theta = sorted(two["params"][0::2])
    # within 5 CRLB sd (about 1 deg for the weak source) of the truth, in degrees
    assert theta[0] == pytest.approx(-158.8, abs=5 * 1.05)
    assert theta[1] == pytest.approx(21.2, abs=5 * 0.21)
