"""Save / load of the ML and selection results, summaries as DataFrames, short reprs."""

import numpy as np
import pytest

import olsbayes as ob
from olsbayes import InputError, Model, Ring, fit_ml, select_k
from olsbayes.ml import MLResult
from olsbayes.select import SelectionResult

FIG3 = np.array([0.37, 1.0, 0.37 - np.pi, 0.2])


@pytest.fixture(scope="module")
def fig3():
    model = Model(Ring(30), sigma=1e-2)
    return model, model.simulate(FIG3, rng=1)


def _assert_ml_equal(a: MLResult, b: MLResult) -> None:
    for name in ("params", "log_likelihood", "converged", "n_evaluations", "cov", "rival_gap"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True), name
    assert (a.method, a.n_sources) == (b.method, b.n_sources)
    assert a.model.array == b.model.array and repr(a.model) == repr(b.model)
    assert a.model.sigma == b.model.sigma


@pytest.mark.parametrize("model", [
    Model(Ring(30), sigma=1e-2),
    Model(ob.Sphere.grid(5, 6), sigma=1e-2, sensitivity=ob.CosinePower(3.0)),
    Model(ob.Plate.grid(4, 4, 0.5), sigma=1e-2),
])
def test_ml_result_saves_and_loads_back_equal(model, tmp_path):
    x = {"angle": FIG3, "lonlat": np.array([0.3, 0.2, 1.0]),
         "position": np.array([0.1, 0.2, 0.8, 1.0])}[model.kind]
    data = model.simulate(x, rng=2)
    res = fit_ml(model, data, model.n_sources_of(x))
    back = MLResult.load(res.save(tmp_path / "ml.nc", data=data, seed=2))
    _assert_ml_equal(res, back)
    np.testing.assert_array_equal(back.model.response(back.params), model.response(res.params))
    batch = fit_ml(model, np.stack([data, data]), model.n_sources_of(x))
    _assert_ml_equal(batch, MLResult.load(batch.save(tmp_path / "batch.nc")))


def test_a_custom_law_needs_the_model_to_load(tmp_path):
    law = ob.CustomSensitivity(lambda c: np.maximum(c, 0) ** 2, lambda c: 2 * np.maximum(c, 0))
    model = Model(Ring(12), sigma=1e-2, sensitivity=law)
    data = model.simulate(np.array([0.3, 1.0]), rng=1)
    res = fit_ml(model, data, 1, method="multistart", rng=1)
    path = res.save(tmp_path / "custom.nc")
    back = MLResult.load(path, model=model)
    assert back.model is model
    np.testing.assert_array_equal(back.params, res.params)


def test_loading_the_wrong_kind_of_file_is_refused(fig3, tmp_path):
    model, data = fig3
    path = fit_ml(model, data, 2).save(tmp_path / "ml.nc")
    with pytest.raises(InputError, match="not a SelectionResult"):
        SelectionResult.load(path)
    with pytest.raises(InputError, match="not a file"):
        MLResult.load(tmp_path / "missing.nc")


def test_selection_result_saves_and_loads_back_equal(fig3, tmp_path):
    model, data = fig3
    res = select_k(model, data, 3, rng=1)
    back = SelectionResult.load(res.save(tmp_path / "sel.nc", data=data, seed=1))
    for name in ("ks", "log_evidence", "error", "log_prior_k", "probabilities"):
        np.testing.assert_array_equal(getattr(res, name), getattr(back, name))
    assert (res.best, res.method, res.notes, res.seconds) == (back.best, back.method,
                                                              back.notes, back.seconds)
    assert dict(res.escalated) == dict(back.escalated)
    for a, b in zip(res.evidences, back.evidences):
        np.testing.assert_array_equal(a.params, b.params)
        assert (a.k, a.method, a.trusted, a.reasons, a.origin) == (b.k, b.method, b.trusted,
                                                                   b.reasons, b.origin)
        if a.fit is not None:
            _assert_ml_equal(a.fit, b.fit)
    assert res.table() == back.table() and res.summary().equals(back.summary())


def test_every_result_summary_is_a_dataframe_and_reprs_are_short(fig3):
    import pandas as pd

    model, data = fig3
    ml = fit_ml(model, data, 2)
    sel = select_k(model, data, 3, rng=1)
    img = ob.image(model, data, FIG3[0::2], "gaussian")
    post = ob.sample_posterior(model, data, 2, rng=1, progress=False,
                               options=ob.SamplerOptions(n_steps=100))
    for res in (ml, sel, img, post):
        assert isinstance(res.summary(), pd.DataFrame), type(res)
        assert len(repr(res)) < 200, repr(res)
    assert len(str(sel)) < 200 and "best=2" in str(sel)
    assert list(ml.summary().index) == model.param_names(2)
    assert list(sel.summary().index) == [0, 1, 2, 3]
    np.testing.assert_allclose(sel.summary()["probability"].sum(), 1.0)
