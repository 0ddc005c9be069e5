"""``olsbayes select``, ``crlb`` and ``simulate`` with the measurement sections.

[noise], [calibration], [background] and [prior], as ``olsbayes fit`` reads them.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from olsbayes.cli import main

RING = '[sensor]\ngeometry = "ring"\nn = 16\n'
SCENE = "[scene]\ndirections = [0.4, 2.6]\nintensities = [40.0, 25.0]\n"


def _poisson(exposure="2.0", frames=False):
    return (f'[noise]\nmodel = "poisson"\nexposure = {exposure}\n'
            + ("frames = true\n" if frames else ""))


def _write(tmp_path, text, name="cfg.toml"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _json(capsys, *argv):
    code = main([*argv, "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out)


def test_select_picks_the_true_k_of_clear_count_frames(tmp_path, capsys):
    """Three frames of ~100 counts per lit sub-sensor: K = 2 with p(K) ~ 1 (a prior on K)."""
    cfg = _write(tmp_path, RING + _poisson(frames=True) + SCENE
                 + "[data]\nsimulate = true\nseed = 4\nrepeats = 3\n"
                 "[prior]\nk_prior = \"poisson\"\nk_mean = 1.0\n")
    out = _json(capsys, "select", cfg, "--seed", "1", "--k-max", "3", "--method", "laplace",
                "--quiet")
    assert out["true_k"] == 2 and len(out["results"]) == 1  # the frames: one selection
    res = out["results"][0]
    assert res["best"] == 2
    cand = res["candidates"]
    assert cand[2]["probability"] > 0.99
    # the truncated Poisson(1) prior on 0..3: log P(K) = -log K! + const
    lp = np.array([c["log_prior_k"] for c in cand])
    np.testing.assert_allclose(lp - lp[0], -np.log([1.0, 1.0, 2.0, 6.0]), atol=1e-12)


def test_select_intensity_prior_from_the_prior_section(tmp_path, capsys):
    """[prior] i_max sets the Occam factor: a 10x wider prior costs log 10 per source."""
    text = RING + _poisson() + SCENE + "[data]\nsimulate = true\nseed = 4\n"
    base = ["select", "--seed", "1", "--k-max", "2", "--method", "laplace", "--quiet"]
    z = [np.array([c["log_evidence"] for c in _json(
        capsys, *base, _write(tmp_path, text + f"[prior]\ni_max = {i}\n", f"p{i}.toml")
    )["results"][0]["candidates"]]) for i in (100.0, 1000.0)]
    np.testing.assert_allclose(z[0] - z[1], np.log(10.0) * np.arange(3), atol=1e-6)


def test_crlb_of_counts_scales_as_one_over_sqrt_exposure(tmp_path, capsys):
    """Poisson Fisher information is proportional to the total exposure (frames x exposure)."""
    sd = {}
    for name, noise in [("e1", _poisson("1.0")), ("e4", _poisson("4.0")),
                        ("f4", _poisson("1.0", frames=True) + "[data]\nsimulate = true\n"
                         "seed = 1\nrepeats = 4\n")]:
        out = _json(capsys, "crlb", _write(tmp_path, RING + noise + SCENE, f"{name}.toml"))
        sd[name] = np.array(out["crlb"]["direction_std"] + out["crlb"]["intensity_std"])
    np.testing.assert_allclose(sd["e1"] / sd["e4"], 2.0, rtol=1e-9)
    np.testing.assert_allclose(sd["f4"], sd["e4"], rtol=1e-9)


def test_crlb_marginalises_an_inferred_background(tmp_path, capsys):
    cfg = _write(tmp_path, RING + _poisson() + SCENE + "[background]\ninfer = true\nmax = 10.0\n")
    out = _json(capsys, "crlb", cfg)["crlb"]
    assert out["extra_names"] == ["b"]
    assert np.all(np.array(out["nuisance_cost"]) >= 1.0 - 1e-12)


def test_simulate_writes_count_frames(tmp_path, capsys):
    out_file = tmp_path / "counts.txt"
    cfg = _write(tmp_path, RING + _poisson("[1.0, 2.0, 0.5]", frames=True) + SCENE
                 + "[background]\nvalue = 1.0\n")
    assert main(["simulate", cfg, "--seed", "3", "--out", str(out_file)]) == 0
    capsys.readouterr()
    counts = np.loadtxt(out_file)
    assert counts.shape == (3, 16)
    assert np.all(counts >= 0) and np.all(counts == np.round(counts))
    # the exposures 1 : 2 : 0.5 show in the frames' totals (each total ~ 500-1000 counts)
    totals = counts.sum(axis=1)
    assert totals[1] > totals[0] > totals[2]
    # fit reads them back as frames of the same scene
    fit = _json(capsys, "fit", cfg, "--data", str(out_file), "--seed", "1")
    assert fit["frames"] == 3


def _bad_cases(tmp_path):
    _write(tmp_path, " ".join(["3"] * 15 + ["-1"]) + "\n", "neg.txt")
    base = RING + _poisson() + SCENE + "[data]\nsimulate = true\nseed = 1\n"
    cfg = {
        "kmean": base + "[prior]\nk_prior = \"poisson\"\n",
        "kmean_uniform": base + "[prior]\nk_prior = \"uniform\"\nk_mean = 2.0\n",
        "kprior": base + "[prior]\nk_prior = \"geometric\"\n",
        "imax": base + "[prior]\ni_max = 50.0\n",
        "sigma_prior": base + "[prior]\nsigma_min = 0.1\nsigma_max = 1.0\n",
        "expo_frames": RING + _poisson("[1.0, 2.0]", frames=True) + SCENE
        + "[data]\nsimulate = true\nseed = 1\nrepeats = 3\n",
        "sigma_poisson": RING + "sigma = 0.1\n" + _poisson() + SCENE,
        "bg_no_max": RING + _poisson() + SCENE + "[background]\ninfer = true\n",
        "gain0": RING + _poisson() + SCENE + "[calibration]\ngain_sd = 0.0\n",
    }
    p = {k: _write(tmp_path, v, f"{k}.toml") for k, v in cfg.items()}
    neg = str(tmp_path / "neg.txt")
    return [
        (["select", p["imax"], "--data", neg], "counts"),
        (["select", p["kmean"]], "k_mean"),
        (["select", p["kmean_uniform"]], "k_mean"),
        (["select", p["kprior"]], "k_prior must be one of"),
        (["select", p["imax"], "--i-max", "10"], "intensity bound once"),
        (["select", p["sigma_prior"]], "gaussian-unknown"),
        (["select", p["bg_no_max"]], "needs max"),
        (["crlb", p["expo_frames"]], "exposure gives 2 frames"),
        (["crlb", p["sigma_poisson"]], "takes no sigma"),
        (["crlb", p["gain0"]], "gain_sd"),
        (["simulate", p["expo_frames"]], "exposure gives 2 frames"),
        (["simulate", p["imax"], "--repeats", "0"], "--repeats"),
        (["simulate", p["bg_no_max"]], "needs max"),
    ]


def test_bad_measurement_input_in_each_command_is_one_line_exit_2(tmp_path, capsys):
    for argv, match in _bad_cases(tmp_path):
        code = main([*argv, "--quiet"] if argv[0] == "select" else argv)
        _, err = capsys.readouterr()
        lines = err.strip().splitlines()
        assert code == 2, (argv, err)
        assert len(lines) == 1 and "Traceback" not in err, (argv, err)
        assert match in lines[0], (argv, lines[0])


@pytest.mark.parametrize("command", ["select", "crlb", "simulate"])
def test_default_scene_output_is_unchanged_by_the_sections(command, capsys):
    """Without the new sections each command runs its plain Gaussian path."""
    argv = [command] + (["--k-max", "1", "--method", "bic", "--quiet"]
                        if command == "select" else [])
    out = _json(capsys, *argv)
    assert "noise=" not in out.get("model", "")
