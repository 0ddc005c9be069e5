"""Estimators of ring studies as (name, options): labels, spellings and refusals."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
import xarray as xr

from olsbayes import InputError
from olsbayes.studies import ESTIMATORS, Estimator, as_estimator, run_study, vectorized
from olsbayes.studies import estimators as ring_module
from olsbayes.studies.estimators import ring_estimate

FIXED = {"n_sensors": 8, "sigma": 0.05, "n_sources": 1}


def _study(grid, **kw):
    kw.setdefault("fixed", FIXED)
    return run_study(ring_estimate, grid, 2, executor="serial", rng=3, progress=False, **kw)


def _numbers(ds):
    """Everything but the measured times."""
    return ds.drop_vars(["seconds", "cpu_seconds"])


def test_labels_are_canonical():
    assert Estimator("fast").label == "fast"
    assert Estimator("fast", batched=False) == Estimator("fast")  # defaults filled in
    assert Estimator("fast", batched=True).label == "fast(batched=True)"
    assert Estimator("multistart", n_starts=5).label == "multistart(n_starts=5)"
    assert Estimator("exact").label == "exact"
    assert Estimator("posterior", n_steps=300).label == "posterior(n_steps=300)"
    assert (Estimator("posterior", n_walkers=40, n_steps=300).label
            == "posterior(n_steps=300, n_walkers=40)")  # table order, not call order
    assert Estimator("nested", max_calls=20000).label == "nested"
    assert Estimator("nested", max_calls=5000).label == "nested(max_calls=5000)"
    assert repr(Estimator("multistart", n_starts=5)) == "Estimator('multistart', n_starts=5)"
    for name in ESTIMATORS:
        required = {k: 7 for k, o in ESTIMATORS[name].items() if o.required}
        e = Estimator(name, **required)
        assert pickle.loads(pickle.dumps(e)) == e and hash(e) == hash(Estimator(name, **required))
        assert as_estimator(e.to_json()) == e  # the JSON (and TOML) form reads back
        assert json.loads(json.dumps(e.to_json())) == e.to_json()


def test_every_spelling_gives_the_same_study_and_labelled_coordinates():
    spellings = [
        [Estimator("fast"), Estimator("multistart", n_starts=2), Estimator("exact")],
        [("fast", {}), ("multistart", {"n_starts": 2}), ("exact", {})],
        ["fast", {"name": "multistart", "n_starts": 2}, {"name": "exact"}],
    ]
    ref = _study({"estimator": spellings[0]}, fixed=FIXED)
    assert list(ref.estimator.values) == ["fast", "multistart(n_starts=2)", "exact"]
    assert ref.dir_z2.dims == ("estimator", "trial")
    assert ref.sel(estimator="multistart(n_starts=2)").converged.dtype == bool
    grid = json.loads(ref.attrs["grid"])
    assert grid == [["estimator", [{"name": "fast", "batched": False},
                                   {"name": "multistart", "n_starts": 2}, {"name": "exact"}]]]
    for other in spellings[1:]:
        assert _numbers(_study({"estimator": other})).identical(_numbers(ref))
    # one estimator as a fixed setting: a one-cell study draws the streams of cell 0
    alone = run_study(ring_estimate, {}, 2, fixed={**FIXED, "estimator": ("fast", {})},
                      executor="serial", rng=3, progress=False)
    assert json.loads(alone.attrs["fixed_settings"])["estimator"] == {"name": "fast",
                                                                      "batched": False}
    np.testing.assert_array_equal(alone.dir_err_rms, ref.dir_err_rms.sel(estimator="fast"))


REFUSALS = [
    ({"estimator": ["fast", "multistart_5"]},
     "grid['estimator'][1]: unknown estimator name 'multistart_5'; accepted: 'fast', "
     "'multistart', 'exact', 'posterior', 'nested'"),
    ({"estimator": [("multistart", {"nstarts": 5})]},
     "grid['estimator'][0]: multistart has no option 'nstarts'; accepted options: n_starts"),
    ({"estimator": [{"name": "multistart"}]},
     "multistart needs option n_starts, an integer in [1, 100000]"),
    ({"estimator": [("multistart", {"n_starts": 0})]},
     "multistart option n_starts must be in [1, 100000]; got 0"),
    ({"estimator": [("multistart", {"n_starts": 2.5})]},
     "multistart option n_starts must be an integer; got 2.5"),
    ({"estimator": [("posterior", {"n_steps": 0})]}, "n_steps must be in [1, 10000000]"),
    ({"estimator": [("posterior", {"n_steps": 9, "n_walkers": 1})]},
     "n_walkers must be in [2, 100000]"),
    ({"estimator": [("nested", {"max_calls": 10})]},
     "nested option max_calls must be in [1000, 1000000000]; got 10"),
    ({"estimator": [("fast", {"batched": "yes"})]}, "batched must be true or false"),
    ({"estimator": [("exact", {"n_starts": 5})]}, "exact has no option 'n_starts'; it takes none"),
    ({"estimator": [5]}, "grid['estimator'][0] must be an Estimator, a name"),
    ({"estimator": ["fast", ("fast", {"batched": False})]}, "repeated values ['fast', 'fast']"),
    ({"method": ["fast"]}, "setting 'method' is not read by trial "
                           "olsbayes.studies.estimators:ring_estimate; accepted settings: "),
]


@pytest.mark.parametrize("grid, message", REFUSALS)
def test_bad_estimators_are_refused_before_any_trial_runs(grid, message, monkeypatch, tmp_path):
    def no_trial(*args, **kw):
        raise AssertionError("a trial ran")

    monkeypatch.setattr(ring_module, "_timed_estimates", no_trial)
    ckpt = tmp_path / "c.ckpt"
    with pytest.raises(InputError) as info:
        _study(grid, checkpoint=ckpt)
    assert message in str(info.value)
    assert not ckpt.exists()


def test_bad_fixed_estimator_is_refused():
    with pytest.raises(InputError, match=r"fixed\['estimator'\]: exact has no option 'x'"):
        _study({}, fixed={**FIXED, "estimator": {"name": "exact", "x": 1}})


def test_batched_ml_trials_do_not_depend_on_chunking():
    grid = {"estimator": [Estimator("fast", batched=True)], "n_sources": [1, 2]}
    fixed = {"n_sensors": 12, "sigma": 0.02}
    a, b = (run_study(ring_estimate, grid, 12, fixed=fixed, executor="serial", rng=4,
                      chunk_size=c, progress=False) for c in (12, 5))
    for v in ("dir_err_rms", "dir_z2", "max_z", "k_hat", "resolvable"):
        np.testing.assert_allclose(a[v], b[v], rtol=1e-7, atol=1e-12)
    # an efficient estimator: mean (error / CRLB)^2 ~ 1, within 5 standard errors
    # (z2 of one direction is ~ chi2_1: sd sqrt(2) per trial, 12 trials per cell)
    z2 = a["dir_z2"].sel(n_sources=1).values
    assert abs(z2.mean() - 1) < 5 * np.sqrt(2 / z2.size)
    with pytest.raises(InputError, match="unknown estimator name 'multistart_5'"):
        ring_estimate({"estimator": "multistart_5", "n_sensors": 8, "sigma": 0.1},
                      rngs=[np.random.default_rng(0)])


def test_exact_estimator_in_ring_studies():
    with pytest.raises(InputError, match="exact has no option 'n_starts'; it takes none"):
        Estimator("exact", n_starts=3)
    settings = {"n_sensors": 30, "sigma": 1e-2, "n_sources": 2, "estimator": Estimator("exact")}
    out = ring_estimate(settings, rngs=[np.random.default_rng(s) for s in range(3)])
    assert np.all(np.asarray(out["converged"]))
    assert np.all(np.asarray(out["ll_gain"]) >= -1e-9)  # the global optimum beats the truth


def positional_trial(settings, r):
    return {"x": 1.0}


@vectorized
def batch_with_rng(settings, *, rng):
    return {"x": np.zeros(len(rng))}


def test_trials_take_rng_by_keyword():
    with pytest.raises(InputError, match=r"must accept \(settings, \*, rng\)"):
        run_study(positional_trial, {}, 1, executor="serial", rng=1, progress=False)
    with pytest.raises(InputError, match=r"must accept \(settings, \*, rngs\)"):
        run_study(batch_with_rng, {}, 1, executor="serial", rng=1, progress=False)


STUDY_TOML = """
[study]
trial = "ring_estimate"
n_trials = 2
seed = 3
out = "s.nc"
executor = "serial"

[grid]
estimator = ["fast", {name = "multistart", n_starts = 2}]

[fixed]
n_sensors = 8
sigma = 0.05
n_sources = 1
"""


def test_cli_study_reads_estimator_tables(tmp_path, capsys):
    from olsbayes.cli import main

    cfg = tmp_path / "s.toml"
    cfg.write_text(STUDY_TOML)
    assert main(["study", str(cfg), "--no-progress"]) == 0
    capsys.readouterr()
    ds = xr.load_dataset(tmp_path / "s.nc")
    ref = _study({"estimator": [Estimator("fast"), Estimator("multistart", n_starts=2)]})
    assert _numbers(ds).identical(_numbers(ref))
    for setting, message in [
        ('grid.estimator=[{name = "multistart"}]', "multistart needs option n_starts"),
        ('grid.estimator=["multistart_5"]', "unknown estimator name 'multistart_5'"),
        ('grid.method=["fast"]', "setting 'method' is not read by trial"),
    ]:
        assert main(["study", str(cfg), "--no-progress", "--set", setting]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err


def test_dataset_variables_carry_long_name_and_units_and_k_hat_is_nan_without_select():
    """Every ring_estimate output has long_name (and units where it has any); k_hat of a
    study that does not choose K is NaN, never a number that averages into the mean."""
    ds = _study({"estimator": ["fast"]})
    for name in ds.data_vars:
        assert ds[name].attrs["long_name"] and "units" in ds[name].attrs or name in (
            "resolvable", "on_kink", "converged", "n_evaluations", "k_hat")
    assert ds.dir_err_rms.attrs["units"] == "rad" and ds.ll_gain.attrs["units"] == "nats"
    assert np.isnan(ds.k_hat.values).all()
    chosen = _study({"estimator": ["fast"]}, fixed={**FIXED, "select": True})
    assert set(np.unique(chosen.k_hat.values)) <= {0.0, 1.0, 2.0}
