"""Feedback on long commands: status lines on stderr by default, none with --quiet."""

from __future__ import annotations

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.cli import main


@pytest.fixture
def no_delay(monkeypatch):
    monkeypatch.setattr("olsbayes._progress.DELAY", 0.0)


def test_fit_posterior_shows_the_sampler_status_unless_quiet(no_delay, capsys):
    argv = ["fit", "--posterior", "--seed", "1", "--max-steps", "3000", "--set",
            "sensor.n=12"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "posterior" in err and "steps needed" in err
    assert main(argv + ["--quiet"]) == 0
    assert capsys.readouterr().err == ""


def test_select_and_image_take_quiet(no_delay, capsys):
    assert main(["select", "--k-max", "1", "--method", "nested", "--maxcall", "5000",
                 "--seed", "1", "--set", "sensor.n=12", "--set", "scene.directions=[0.3]",
                 "--set", "scene.intensities=[1.0]"]) == 0
    err = capsys.readouterr().err
    assert "nested sampling" in err
    assert main(["image", "--seed", "1", "--n-samples", "30", "--quiet"]) == 0
    assert "imaging" not in capsys.readouterr().err
    assert main(["image", "--seed", "1", "--n-samples", "30"]) == 0
    assert "imaging (gibbs" in capsys.readouterr().err


@pytest.mark.filterwarnings("ignore:the gibbs chains have not mixed")  # 20 draws: not the point
def test_image_api_progress_is_checked_and_off_means_silent(capsys):
    model = ob.Model(ob.Ring(12), 0.01)
    dirs = np.linspace(-np.pi, np.pi, 4, endpoint=False)
    data = model.simulate(np.column_stack([dirs, np.full(4, 0.5)]).ravel(), rng=1)
    with pytest.raises(ob.InputError, match="progress must be True or False"):
        ob.image(model, data, dirs, progress="yes")
    ob.image(model, data, dirs, options=ob.imaging.ImageOptions(n_samples=20), rng=1,
             progress=False)
    assert capsys.readouterr().err == ""


def test_demo_prints_each_part_as_it_is_computed(capsys, monkeypatch):
    """The ML and CRLB blocks are on stdout before the evidence is computed (a demo
    whose selection step fails has already shown them), not buffered to the end."""
    import olsbayes.select

    def fail(*args, **kwargs):
        raise RuntimeError("stop after the ML part")

    monkeypatch.setattr(olsbayes.select, "select_k", fail)
    with pytest.raises(RuntimeError, match="stop after the ML part"):
        main(["demo", "--no-figures", "--quiet"])
    out = capsys.readouterr().out
    assert "Maximum-likelihood estimate" in out and "CRLB" in out
    assert "Evidence for K" not in out


def test_building_a_large_search_says_so_unless_quiet(monkeypatch, capsys):
    """The set-up line of a large search (atoms beyond NOTICE_ENTRIES) prints on stderr
    for `olsbayes fit`, not with --quiet, and the silence ends with the command."""
    from olsbayes._notice import notice

    monkeypatch.setattr("olsbayes.ml.atoms.NOTICE_ENTRIES", 100)
    argv = ["fit", "--seed", "1", "--set", "sensor.n=12"]
    assert main(argv + ["--quiet"]) == 0
    assert "olsbayes: building the search" not in capsys.readouterr().err
    assert main(argv) == 0
    assert "olsbayes: building the search" in capsys.readouterr().err
    notice("still heard")
    assert capsys.readouterr().err == "olsbayes: still heard\n"


def test_study_quiet_silences_status_lines_too(tmp_path, capsys, monkeypatch):
    """``study --quiet`` (alias ``--no-progress``) hides the status lines as every other
    command's ``--quiet`` does, e.g. the one of a slow Dask scheduler connection."""
    from olsbayes._notice import notice
    from olsbayes.errors import InputError
    from olsbayes.studies import executors

    def slow(scheduler, **kwargs):
        notice(f"connecting to the Dask scheduler at {scheduler!r} ...")
        raise InputError("cannot reach the Dask scheduler")

    monkeypatch.setattr(executors, "_connect", slow)
    cfg = tmp_path / "s.toml"
    cfg.write_text(f'[study]\ntrial = "noise_check"\nn_trials = 2\nout = "{tmp_path / "s.nc"}"\n'
                   '\n[fixed]\nn_sensors = 8\n')
    for flags, said in (([], True), (["--quiet"], False), (["--no-progress"], False)):
        assert main(["study", str(cfg), "--scheduler", "tcp://h:1", *flags]) == 2
        err = capsys.readouterr().err
        assert ("connecting to the Dask scheduler" in err) is said, (flags, err)
        assert "cannot reach the Dask scheduler" in err
    assert not (tmp_path / "s.nc").exists()


def test_fit_prints_the_ml_table_before_sampling(capsys, monkeypatch):
    """`fit --posterior` shows the ML table as soon as it is fitted (a run whose
    sampling fails has shown it); the JSON object still comes whole at the end."""
    import olsbayes.posterior

    def fail(*args, **kwargs):
        raise RuntimeError("stop before the posterior")

    monkeypatch.setattr(olsbayes.posterior, "sample", fail)
    argv = ["fit", "--posterior", "--seed", "1", "--set", "sensor.n=12"]
    with pytest.raises(RuntimeError, match="stop before the posterior"):
        main(argv)
    assert "ML fit (fast) of K = 2" in capsys.readouterr().out
    with pytest.raises(RuntimeError, match="stop before the posterior"):
        main(argv + ["--json"])
    assert capsys.readouterr().out == ""


def test_fit_posterior_text_is_the_same_printed_in_two_parts(capsys):
    """The ML table printed before the sampling, the posterior after: the same text as
    one block, a blank line between them."""
    argv = ["fit", "--posterior", "--seed", "1", "--set", "sensor.n=12", "--max-steps", "300"]
    assert main(argv + ["--quiet"]) == 0
    out = capsys.readouterr().out
    ml, post = out.split("\n\nPosterior (emcee, 300 steps")
    assert ml.startswith("Model(Ring(n=12") and "Truth and error / sd:" in ml
    assert post.count("\n") >= 4 and "Model check" in post and "\n\n" not in post
