"""Imaging without silent clipping: data-derived bounds, bound warnings, files that load back."""

import warnings

import numpy as np
import pytest

import olsbayes as ob
from olsbayes import InputError, PriorBoundWarning
from olsbayes.imaging import (
    Bounded,
    ImageOptions,
    ImageResult,
    Sparse,
    TwoLevel,
    data_bound,
    design_matrix,
    image,
)


@pytest.fixture(scope="module")
def bright():
    """The README scene with intensities 5 and 2: brighter than the old fixed bound 1."""
    model = ob.Model(ob.Ring(30), sigma=0.01)
    dirs = np.array([0.37, 0.37 - np.pi])
    truth = np.array([5.0, 2.0])
    y = design_matrix(model, dirs) @ truth + 0.01 * np.random.default_rng(3).standard_normal(30)
    return model, dirs, truth, y


def test_data_bound_covers_every_intensity_the_readings_allow(bright):
    model, dirs, truth, y = bright
    a = design_matrix(model, dirs)
    hi = data_bound(a, y, model.sigma)
    # one source alone cannot exceed (max y + 3 sigma) / its best gain; the bound doubles it
    assert hi >= 2 * np.max(y) / a.max(axis=0).min()
    assert hi > truth.max()


@pytest.mark.parametrize("options", [ImageOptions(n_samples=400), ImageOptions(n_samples=0)])
def test_default_bounded_prior_recovers_bright_sources(bright, options):
    """Before: "bounded" meant U(0, 1), and both intensities came back as 1 with sd ~ 1e-5
    and no warning.  Now the bound comes from the readings: the estimates are the truth
    within a few sd (the CRLB sd is 2 sigma / sqrt(N) for sources pi apart)."""
    model, dirs, truth, y = bright
    with warnings.catch_warnings():
        warnings.simplefilter("error", PriorBoundWarning)
        res = image(model, y, dirs, options=options, rng=1)
    crlb_sd = 2 * model.sigma / np.sqrt(model.n_sensors)
    assert res.i_max > truth.max() and not res.at_bound.any()
    np.testing.assert_allclose(res.mean, truth, atol=5 * crlb_sd)
    if options.n_samples:
        assert np.all(res.covers(truth))
        np.testing.assert_allclose(res.sd, crlb_sd, rtol=0.3)


def test_a_bound_below_the_truth_is_flagged_and_warned(bright):
    model, dirs, _, y = bright
    with pytest.warns(PriorBoundWarning, match="i_max = 1"):
        res = image(model, y, dirs, Bounded(i_max=1.0), options=ImageOptions(n_samples=200),
                    rng=1)
    assert res.at_bound.all() and res.i_max == 1.0
    with pytest.warns(PriorBoundWarning, match="posterior mode"):
        mode = image(model, y, dirs, Bounded(i_max=1.0), options=ImageOptions(n_samples=0))
    assert mode.at_bound.all()
    assert mode.summary()["at_bound"].all()


def test_sparse_default_bound_and_two_level_needs_one(bright):
    model, dirs, truth, y = bright
    res = image(model, y, dirs, Sparse(), options=ImageOptions(n_samples=400), rng=2)
    assert res.i_max > truth.max()
    np.testing.assert_allclose(res.mean, truth, rtol=0.05)
    with pytest.raises(InputError, match="TwoLevel"):
        image(model, y, dirs, "two-level")
    tl = image(model, y, dirs, TwoLevel(i_max=5.0))
    assert tl.i_max == 5.0 and tl.at_bound is None


def _assert_same(a: ImageResult, b: ImageResult) -> None:
    for name in ("directions", "mean", "mode", "sd", "lower", "upper", "samples", "p_bright",
                 "at_bound"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            np.testing.assert_array_equal(x, y, err_msg=name)
    for name in ("prior", "level", "log_evidence", "acceptance", "sampler", "i_max"):
        assert getattr(a, name) == getattr(b, name), name
    assert np.array_equal(a.rhat, b.rhat, equal_nan=True)
    for name in ("matrix", "singular_values", "null_space", "null_fraction"):
        np.testing.assert_array_equal(getattr(a.design, name), getattr(b.design, name))
    assert a.design.rank == b.design.rank and a.design.condition == b.design.condition
    assert (a.search is None) == (b.search is None)
    if a.search is not None:
        import dataclasses

        for f in dataclasses.fields(a.search):
            assert np.array_equal(getattr(a.search, f.name), getattr(b.search, f.name)), f.name
    assert a.summary().equals(b.summary())
    da, db = a.diagnostics(), b.diagnostics()
    assert da.keys() == db.keys()
    assert all(da[k] == db[k] or (da[k] != da[k] and db[k] != db[k]) for k in da)  # NaN == NaN


@pytest.mark.parametrize("prior,options", [
    (Bounded(), ImageOptions(n_samples=100)),
    (Sparse(i_max=6.0), ImageOptions(n_samples=40)),
    (TwoLevel(i_max=5.0), ImageOptions(reference=(5.0, 2.0))),
    ("gaussian", None),
])
def test_image_result_saves_and_loads_back_equal(bright, tmp_path, prior, options):
    model, dirs, _, y = bright
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ob.ConvergenceWarning)  # short chains on purpose
        res = image(model, y, dirs, prior, options=options, rng=3)
    path = res.save(tmp_path / "image.nc", data=y, seed=3)
    back = ImageResult.load(path)
    _assert_same(res, back)
    import xarray as xr

    with xr.open_dataset(path, engine="h5netcdf") as ds:
        assert ds.attrs["seed"] == 3 and len(ds.attrs["data_sha256"]) == 64
        assert ds.attrs["olsbayes_version"] == ob.__version__


def test_image_result_repr_and_summary_are_short(bright):
    model, dirs, _, y = bright
    res = image(model, y, dirs, "gaussian")
    assert len(repr(res)) < 200 and "ImageResult(prior='gaussian'" in repr(res)
    table = res.summary()
    assert list(table.index) == [0, 1] and {"theta", "mean", "sd", "lower"} <= set(table)
