"""``olsbayes fit`` with [noise], [calibration], [background], [prior], [posterior]."""

from __future__ import annotations

import json

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.build import model_from_config
from olsbayes.calibration import Calibration
from olsbayes.cli import main
from olsbayes.config import parse_config
from olsbayes.noise import GaussianPerSensor, GaussianUnknown, Poisson

RING = '[sensor]\ngeometry = "ring"\nn = 24\n'
SCENE = "[scene]\ndirections = [0.4]\nintensities = [50.0]\n"
POISSON = '[noise]\nmodel = "poisson"\nexposure = 2.0\ndark = 1.0\n'


def _write(tmp_path, text, name="cfg.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _fit(capsys, *argv):
    code = main(["fit", *argv, "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out)


def test_models_from_the_sections(tmp_path):
    np.savetxt(tmp_path / "sd.txt", np.full(24, 0.2))
    m = model_from_config(parse_config(RING + POISSON + "[background]\ninfer = true\nmax = 5.0\n"
                                       "[calibration]\ngain_sd = 0.1\n"))
    assert m.noise == Poisson(2.0, 1.0)
    assert m.nuisance.infer_background and m.nuisance.infer_gains
    m = model_from_config(parse_config(RING + '[noise]\nmodel = "gaussian-unknown"\nsigma = 0.3'))
    assert m.noise == GaussianUnknown(0.3)
    m = model_from_config(parse_config(RING + '[noise]\nsigma_file = "sd.txt"\n',
                                       base_dir=tmp_path))
    assert isinstance(m.noise, GaussianPerSensor)
    plain = model_from_config(parse_config(RING + "sigma = 0.1\n"))
    assert plain.noise.is_default and plain.nuisance.is_trivial


def test_fit_counts_as_frames(tmp_path, capsys):
    """Poisson frames from [data] are fitted jointly; Pearson's chi^2 is reported."""
    text = (RING + POISSON + "frames = true\n" + SCENE
            + "[data]\nsimulate = true\nseed = 5\nrepeats = 3\n")
    out = _fit(capsys, str(_write(tmp_path, text)), "--seed", "1")
    assert out["frames"] == 3
    assert abs(out["params"][0] - 0.4) < 5 * out["std"][0]
    assert 0.3 < out["chi2_dof"] < 3.0


def test_fit_posterior_with_unknown_sigma_and_priors(tmp_path, capsys):
    text = (RING + '[noise]\nmodel = "gaussian-unknown"\nsigma = 1.0\n' + SCENE
            + "[data]\nsimulate = true\nseed = 2\n[prior]\ni_max = 100.0\nsigma_min = 0.1\n"
            "sigma_max = 10.0\n[posterior]\nwalkers = 12\nsteps = 300\n")
    out = _fit(capsys, str(_write(tmp_path, text)), "--seed", "1", "--posterior")
    assert out["extra_names"] == ["sigma"]
    post = out["posterior"]
    assert post["names"][-1] == "sigma" and post["n_steps"] <= 300


def _cal(tmp_path, n):
    cal = Calibration(gains=np.ones(n), offsets=np.zeros(n), gain_sd=np.full(n, 0.1),
                      offset_sd=np.zeros(n), normals=ob.Ring(n).normals)
    return cal.save(tmp_path / f"cal{n}.toml")


def _cases(tmp_path):
    counts = _write(tmp_path, " ".join(["3"] * 23 + ["-1"]) + "\n", "neg.txt")
    halves = _write(tmp_path, " ".join(["2.5"] * 24) + "\n", "half.txt")
    ragged = _write(tmp_path, " ".join(["3"] * 24) + "\n" + " ".join(["3"] * 23) + "\n",
                    "ragged.txt")
    np.savetxt(tmp_path / "sd23.txt", np.full(23, 0.1))
    np.savetxt(tmp_path / "sd0.txt", np.r_[np.full(23, 0.1), 0.0])
    _cal(tmp_path, 20)
    cfg = {
        "poisson": RING + POISSON + SCENE,
        "expo0": RING + '[noise]\nmodel = "poisson"\nexposure = 0.0\n' + SCENE,
        "expo_gauss": RING + "sigma = 0.1\n[noise]\nexposure = 2.0\n" + SCENE,
        "sigma_poisson": RING + "sigma = 0.1\n" + POISSON + SCENE,
        "sd23": RING + '[noise]\nsigma_file = "sd23.txt"\n' + SCENE,
        "sd0": RING + '[noise]\nsigma_file = "sd0.txt"\n' + SCENE,
        "gain0": RING + "sigma = 0.1\n[calibration]\ngain_sd = 0.0\n" + SCENE,
        "cal_other": RING + 'sigma = 0.1\n[calibration]\nfile = "cal20.toml"\n' + SCENE,
        "bg_no_max": RING + "sigma = 0.1\n[background]\ninfer = true\n" + SCENE,
        "sigma_prior": RING + POISSON + SCENE + "[prior]\nsigma_min = 0.1\nsigma_max = 1.0\n",
        "walkers": RING + "sigma = 0.1\n" + SCENE + "[posterior]\nwalkers = 2\n",
    }
    paths = {k: str(_write(tmp_path, v, f"{k}.toml")) for k, v in cfg.items()}
    return [
        ([paths["poisson"], "--data", str(counts)], "counts"),
        ([paths["poisson"], "--data", str(halves)], "integers"),
        ([paths["poisson"], "--data", str(ragged)], "different lengths"),
        ([paths["expo0"]], "exposure"),
        ([paths["expo_gauss"]], "exposure applies only"),
        ([paths["sigma_poisson"]], "takes no sigma"),
        ([paths["sd23"]], "24"),
        ([paths["sd0"]], "zeros"),
        ([paths["gain0"]], "gain_sd"),
        ([paths["cal_other"]], "20 sub-sensors"),
        ([paths["bg_no_max"]], "needs max"),
        ([paths["sigma_prior"], "--posterior", "--data", str(tmp_path / "ok.txt")],
         "gaussian-unknown"),
        ([paths["walkers"], "--posterior"], "walkers"),
    ]


def test_bad_measurement_input_is_one_line_exit_2(tmp_path, capsys):
    _write(tmp_path, " ".join(["3"] * 24) + "\n", "ok.txt")
    for argv, match in _cases(tmp_path):
        code = main(["fit", *argv])
        _, err = capsys.readouterr()
        lines = err.strip().splitlines()
        assert code == 2, (argv, err)
        assert len(lines) == 1 and "Traceback" not in err, (argv, err)
        assert match in lines[0], (argv, lines[0])


@pytest.mark.parametrize("text, match", [
    (RING + '[noise]\nmodel = "laplace"\n', "model must be one of"),
    (RING + "[noise]\ndark = -1.0\n", "dark"),
    (RING + "[posterior]\nsteps = 0\n", "steps"),
    (RING + "[prior]\nintensity = \"flat\"\n", "intensity must be one of"),
])
def test_bad_measurement_sections(text, match):
    with pytest.raises(ob.ConfigError, match=match):
        parse_config(text)


def test_fit_with_more_free_parameters_than_readings_says_why_there_is_no_chi2_dof(
        tmp_path, capsys):
    """Free gains of every sub-sensor leave no degrees of freedom: chi^2 is printed with the
    reason, not a chi^2/dof of nan."""
    text = (RING + "sigma = 0.1\n[calibration]\ngain_sd = 0.1\n" + SCENE
            + "[data]\nsimulate = true\nseed = 5\n")
    assert main(["fit", str(_write(tmp_path, text)), "--seed", "1"]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("log-likelihood"))
    assert "nan" not in line and "chi^2/dof" not in line.split("(")[0]
    assert "no chi^2/dof: 26 free parameters for 24 readings per frame" in out


def test_model_repr_names_the_noise_not_a_nominal_sigma():
    m = ob.Model(ob.Ring(12), noise=Poisson(exposure=10.0))
    assert repr(m) == ("Model(Ring(n=12, offset=0.0), noise=Poisson(exposure=10.0, dark=0.0), "
                       "sensitivity=Cosine())")
    assert "sigma=0.01" in repr(ob.Model(ob.Ring(12), 0.01))
