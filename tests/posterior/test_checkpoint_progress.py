"""A long posterior run kept on disk and resumed; its status line shows the stopping rule."""

from __future__ import annotations

import numpy as np
import pytest

from olsbayes import InputError, Model, Ring
from olsbayes.posterior import SamplerOptions, _checkpoint, sample
from olsbayes.posterior._logpost import LogPosterior


@pytest.fixture(scope="module")
def case():
    model = Model(Ring(16), sigma=0.02)
    truth = np.array([0.4, 1.0, 2.1, 0.6])
    return model, model.simulate(truth, rng=3)


FIELDS = ("samples", "estimate", "tau", "acceptance_fraction")


def _equal(a, b):
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    np.testing.assert_array_equal(a.idata.log_likelihood["obs"].values,
                                  b.idata.log_likelihood["obs"].values)
    assert a.n_steps == b.n_steps and a.converged == b.converged and a.seed == b.seed


def test_interrupted_run_resumes_to_the_draws_of_an_uninterrupted_one(case, tmp_path,
                                                                      monkeypatch):
    """An interrupt at the 150th log-posterior call (two per step: emcee moves the two
    halves of the ensemble in turn) leaves the ~74 steps done in the file; the same call
    again continues them, random stream and convergence checks included."""
    model, data = case
    opts = SamplerOptions(max_steps=3000, check_every=50, tau_multiple=20)
    ref = sample(model, data, 2, options=opts, rng=5, progress=False)
    path = tmp_path / "run.npz"
    calls = [0]
    real = LogPosterior.__call__

    def interrupting(self, z):
        calls[0] += 1
        if calls[0] == 150:
            raise KeyboardInterrupt
        return real(self, z)

    monkeypatch.setattr(LogPosterior, "__call__", interrupting)
    with pytest.raises(KeyboardInterrupt):
        sample(model, data, 2, options=opts, rng=5, progress=False, checkpoint=path)
    monkeypatch.setattr(LogPosterior, "__call__", real)
    with np.load(path) as f:
        assert 60 < f["chain"].shape[0] < 75 and int(f["seed"]) == 5
    resumed = sample(model, data, 2, options=opts, progress=False, checkpoint=path)  # seed read
    _equal(resumed, ref)
    # a finished checkpoint gives the same result again without stepping
    again = sample(model, data, 2, options=opts, rng=5, progress=False, checkpoint=path)
    _equal(again, ref)


def test_a_run_that_hit_its_step_limit_continues_with_a_larger_one(case, tmp_path):
    model, data = case
    path = tmp_path / "run.npz"
    short = sample(model, data, 2, options=SamplerOptions(n_steps=200), rng=2, progress=False,
                   checkpoint=path)
    longer = sample(model, data, 2, options=SamplerOptions(n_steps=500), rng=2, progress=False,
                    checkpoint=path)
    fresh = sample(model, data, 2, options=SamplerOptions(n_steps=500), rng=2, progress=False)
    assert short.n_steps == 200
    _equal(longer, fresh)


def test_checkpoint_of_another_problem_or_seed_is_refused(case, tmp_path):
    model, data = case
    path = tmp_path / "run.npz"
    sample(model, data, 2, options=SamplerOptions(n_steps=50), rng=1, progress=False,
           checkpoint=path)
    with pytest.raises(InputError, match="belongs to another run"):
        sample(model, data + 0.01, 2, options=SamplerOptions(n_steps=50), rng=1,
               progress=False, checkpoint=path)
    with pytest.raises(InputError, match="written with seed 1, not 2"):
        sample(model, data, 2, options=SamplerOptions(n_steps=50), rng=2, progress=False,
               checkpoint=path)
    (tmp_path / "junk.npz").write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="not an olsbayes posterior checkpoint"):
        sample(model, data, 2, options=SamplerOptions(n_steps=50), rng=1, progress=False,
               checkpoint=tmp_path / "junk.npz")
    with pytest.raises(InputError, match="checkpoint"):
        sample(model, data, 2, rng=1, progress=False, checkpoint=tmp_path)  # a folder


def test_status_line_shows_steps_tau_and_rhat_not_a_bar_to_max_steps(case, monkeypatch,
                                                                    capsys):
    """The status line counts steps without a total (the stopping rule decides the end)
    and shows tau with the steps it asks for."""
    model, data = case
    monkeypatch.setattr("olsbayes._progress.DELAY", 0.0)
    sample(model, data, 2, options=SamplerOptions(max_steps=20000, check_every=50),
           rng=4, progress=True)
    err = capsys.readouterr().err
    assert "posterior" in err and "step" in err and "tau" in err and "steps needed" in err
    assert "/20000" not in err and "%" not in err
    sample(model, data, 2, options=SamplerOptions(n_steps=300), rng=4, progress=False)
    assert capsys.readouterr().err == ""


def test_checkpoint_file_holds_numbers_only(case, tmp_path):
    model, data = case
    path = tmp_path / "run.npz"
    sample(model, data, 2, options=SamplerOptions(n_steps=60), rng=1, progress=False,
           checkpoint=path)
    with np.load(path, allow_pickle=False) as f:
        assert str(f["format"]) == _checkpoint.FORMAT
        assert f["chain"].shape[0] == 60 and f["log_prob"].shape == f["chain"].shape[:2]
