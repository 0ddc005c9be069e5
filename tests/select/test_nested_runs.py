"""Nested runs kept (dynesty's results, plots, save/load), checkpointed and resumed, shown."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from olsbayes import InputError, Model, Ring
from olsbayes.priors import default_priors
from olsbayes.select import NestedOptions, SelectionResult, SelectOptions, select_k
from olsbayes.select.engine import scalar_log_likelihood
from olsbayes.select.nested import NestedCheckpoint, NestedRun, nested_log_evidence

pytestmark = pytest.mark.filterwarnings("ignore:the chosen K = 1 is k_max")  # K <= 1 here

MODEL = Model(Ring(12), 0.05)
DATA = MODEL.simulate(np.array([0.4, 1.0]), rng=np.random.default_rng(2))
OPTS = SelectOptions(nested=NestedOptions(maxcall=20_000, n_live=30, dlogz=1.0))


@pytest.fixture(scope="module")
def nested_selection():
    return select_k(MODEL, DATA, k_max=1, method="nested", options=OPTS, rng=3, i_max=2.0,
                    progress=False)


def test_selection_keeps_dynesty_results_with_run_and_trace_plots(nested_selection, tmp_path):
    import matplotlib.pyplot as plt

    run = nested_selection[1].nested
    assert isinstance(run, NestedRun)
    a = run.arrays
    # dynesty's own final log Z is the evidence reported
    assert float(a["logz"][-1]) == nested_selection[1].log_evidence
    assert a["samples"].shape[1] == 2 and a["logwt"].shape == a["logl"].shape
    for kind in ("run", "trace"):
        fig = nested_selection.nested_plot(1, kind)
        assert fig.axes
        plt.close(fig)
    with pytest.raises(InputError, match="no nested-sampling run"):
        nested_selection.nested_plot(0)
    path = nested_selection.save(tmp_path / "sel.nc")
    back = SelectionResult.load(path)
    for name, arr in run.arrays.items():
        np.testing.assert_array_equal(back[1].nested.arrays[name], arr, err_msg=name)


def test_scalar_log_likelihood_pickles_and_equals_the_model():
    f = pickle.loads(pickle.dumps(scalar_log_likelihood(MODEL, DATA)))
    x = np.array([0.5, 0.9])
    assert f(x) == pytest.approx(float(MODEL.log_likelihood(x, DATA)), rel=1e-12)


def _run(tmp_path, maxcall, key="k"):
    prior = default_priors(MODEL, 1, i_max=2.0)
    return nested_log_evidence(
        scalar_log_likelihood(MODEL, DATA), prior.ppf, 2, periodic=prior.periodic_indices,
        rng=5, maxcall=maxcall, n_live=30, dlogz=0.5,
        checkpoint=NestedCheckpoint(tmp_path / "n.pkl", key))


@pytest.mark.filterwarnings("ignore:nested sampling stopped at the cap")
def test_nested_checkpoint_continues_a_capped_run_to_the_uninterrupted_result(tmp_path):
    """A run stopped by its call cap leaves dynesty's checkpoint; the same call with a
    larger cap continues it and reaches exactly the result of one run with that cap."""
    capped = _run(tmp_path, 1_000)
    assert not capped.converged and (tmp_path / "n.pkl").exists()
    resumed = _run(tmp_path, 20_000)
    one_go = _run(tmp_path / "fresh", 20_000)
    assert resumed.converged and resumed.log_evidence == one_go.log_evidence
    np.testing.assert_array_equal(resumed.samples, one_go.samples)
    with pytest.raises(InputError, match="belongs to another nested run"):
        _run(tmp_path, 20_000, key="other")
    (tmp_path / "junk.pkl").write_bytes(b"junk")
    with pytest.raises(InputError, match="not a dynesty checkpoint"):
        prior = default_priors(MODEL, 1, i_max=2.0)
        nested_log_evidence(scalar_log_likelihood(MODEL, DATA), prior.ppf, 2, rng=5,
                            checkpoint=NestedCheckpoint(tmp_path / "junk.pkl"))


def test_select_k_nested_checkpoint_dir(tmp_path):
    opts = SelectOptions(nested=NestedOptions(maxcall=20_000, n_live=30, dlogz=1.0,
                                              checkpoint_dir=tmp_path / "ck"))
    first = select_k(MODEL, DATA, k_max=1, method="nested", options=opts, rng=3, i_max=2.0,
                     progress=False)
    assert (tmp_path / "ck" / "nested-k1.pkl").exists()
    again = select_k(MODEL, DATA, k_max=1, method="nested", options=opts, rng=3, i_max=2.0,
                     progress=False)
    assert again[1].log_evidence == first[1].log_evidence
    with pytest.raises(InputError, match="checkpoint_dir"):
        NestedOptions(checkpoint_dir=3)


def test_select_k_status_line(monkeypatch, capsys):
    monkeypatch.setattr("olsbayes._progress.DELAY", 0.0)
    select_k(MODEL, DATA, k_max=1, method="nested", options=OPTS, rng=3, i_max=2.0)
    err = capsys.readouterr().err
    assert "select_k" in err and "K = 1: nested sampling" in err
    assert "nested sampling" in err and "needs <" in err and "calls" in err
    select_k(MODEL, DATA, k_max=1, method="nested", options=OPTS, rng=3, i_max=2.0,
             progress=False)
    assert capsys.readouterr().err == ""
