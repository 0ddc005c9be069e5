"""`olsbayes image`: JSON output, figure, bad input -> exit status 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from olsbayes.cli import main

SCENE = """
[sensor]
geometry = "sphere"
n_lat = 5
n_lon = 8
sigma = 0.01

[scene]
directions = [[0.1, 0.2], [1.0, -0.3], [-2.0, 0.4]]
intensities = [1.0, 0.0, 0.5]

[data]
simulate = true
seed = 3

[image]
n_samples = 40
"""


@pytest.fixture
def scene(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(SCENE)
    return path


def test_image_json_and_figure(scene, tmp_path, capsys):
    png = tmp_path / "olss.png"
    assert main(["image", str(scene), "--json", "--seed", "1", "--figure", str(png)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["prior"] == "bounded" and out["rank"] == 3 and out["nullity"] == 0
    assert np.allclose(out["mean"], [1.0, 0.0, 0.5], atol=0.05)
    assert out["error_sd"] < 0.05 and png.stat().st_size > 0


def test_image_gaussian_reports_evidence(tmp_path, capsys):
    path = tmp_path / "closed.toml"
    path.write_text(SCENE.replace("[image]\nn_samples = 40\n", ""))
    assert main(["image", str(path), "--json", "--prior", "gaussian", "--i-max", "2"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["log_evidence"] is not None and out["sampler"] == "closed-form"
    assert out["prior"] == "gaussian" and out["effective_rank"] == 3


@pytest.mark.parametrize("extra,match", [
    (["--prior", "gaussian"], "n_samples = 40 does not apply to prior 'gaussian'"),
    (["--set", "image.prior_bright=0.3"], "prior_bright = 0.3 does not apply to prior 'bounded'"),
    (["--set", "image.window=3", "--set", "image.sampler=hmc"], "window = 3 does not apply"),
    (["--prior", "two-level", "--i-max", "1", "--n-samples", "0", "--set",
      "image.n_chains=2"], "n_chains = 2 does not apply to prior 'two-level'"),
    (["--prior", "two-level", "--n-samples", "0"], "needs --i-max"),
])
def test_image_setting_the_prior_does_not_use_exits_2(scene, capsys, extra, match):
    assert main(["image", str(scene), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("olsbayes: error:") and match in err and err.count("\n") == 1


@pytest.mark.parametrize("extra,match", [(["--i-max", "0"], "i_max"),
                                         (["--set", "image.bogus=1"], "bogus")])
def test_image_bad_input_exits_2(scene, capsys, extra, match):
    assert main(["image", str(scene), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("olsbayes: error:") and match in err and err.count("\n") == 1


def test_image_mode_only_and_two_level(scene, capsys):
    assert main(["image", str(scene), "--json", "--n-samples", "0"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["sampler"] == "mode-only" and out["n_draws"] == 0 and out["sd"][0] is None
    assert main(["image", str(scene), "--prior", "two-level", "--i-max", "1",
                 "--n-samples", "0"]) == 0
    text = capsys.readouterr().out
    assert "MAP search" in text and "local optimum True" in text


def test_image_default_prior_does_not_clip_bright_sources(capsys):
    """Intensities 5 and 2 on the default ring scene: the default bounded prior takes its
    bound from the readings, so the estimates are ~5 and ~2 within a few sd and the 90 %
    intervals cover them (with the old fixed i_max = 1 both came out as 1 +- 1e-5)."""
    argv = ["image", "--set", "scene.intensities=[5.0, 2.0]", "--seed", "2", "--json"]
    assert main(argv) == 0
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert "PriorBoundWarning" not in captured.err
    assert out["i_max"] > 5 and out["n_at_bound"] == 0
    truth = np.array(out["truth"])
    assert np.all(np.abs(np.array(out["mean"]) - truth) < 5 * np.array(out["sd"]))
    assert out["coverage"] == 1.0


def test_image_bound_below_the_truth_warns_and_flags(capsys):
    argv = ["image", "--set", "scene.intensities=[5.0, 2.0]", "--i-max", "1", "--seed", "2",
            "--json"]
    assert main(argv) == 0
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert "olsbayes: warning: PriorBoundWarning" in captured.err
    assert out["at_bound"] == [True, True] and out["i_max"] == 1.0


def test_image_figure_on_a_ring(tmp_path, capsys):
    """--figure used to need a sphere; a ring draws intensity against direction angle."""
    png = tmp_path / "ring.png"
    assert main(["image", "--seed", "1", "--figure", str(png)]) == 0
    assert f"Figure: {png}" in capsys.readouterr().out and png.stat().st_size > 1000
