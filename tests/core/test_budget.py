"""The memory budget: sizes that drive memory are refused before allocation, with the estimate.

And degenerate data (all-zero or constant readings) is fitted in bounded memory.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

import olsbayes as ob
from olsbayes._budget import DEFAULT_LIMIT, ENV_VAR, check_memory, memory_limit

MODEL = ob.Model(ob.Ring(30), 0.01)
DATA = MODEL.simulate(ob.Scene(directions=[0.37, -2.0], intensities=[1.0, 0.2]), rng=0)


def _peak(call) -> float:
    """Peak bytes traced (numpy allocations included) while ``call`` runs."""
    tracemalloc.start()
    try:
        call()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def _sample(**options):
    from olsbayes.posterior import SamplerOptions, sample

    return sample(MODEL, DATA, 2, options=SamplerOptions(**options), progress=False)


def _select(**laplace):
    from olsbayes.select import LaplaceOptions, NestedOptions, SelectOptions, select_k

    opts = SelectOptions(laplace=LaplaceOptions(**laplace.get("laplace", {})),
                         nested=NestedOptions(**laplace.get("nested", {})))
    return select_k(MODEL, DATA, 2, options=opts, method=laplace.get("method", "auto"))


CASES = [
    ("ring of 1e9 sub-sensors", lambda: ob.Ring(10**9), r"Ring\(n=1000000000\) needs ~96 GB"),
    ("sphere grid 1e5 x 1e5", lambda: ob.Sphere.grid(10**5, 10**5), "needs ~960 GB"),
    ("fibonacci sphere 1e9", lambda: ob.Sphere.fibonacci(10**9), "needs"),
    ("plate 1e5 x 1e5", lambda: ob.Plate.grid(10**5, 10**5), "needs"),
    ("walkers 1e8", lambda: _sample(n_walkers=10**8), r"n_walkers=100000000 .* needs ~"),
    ("steps 1e9", lambda: _sample(max_steps=10**9), r"x 1000000000 steps .* needs"),
    ("fixed steps 1e9", lambda: _sample(n_steps=10**9), "needs"),
    ("importance draws 1e9", lambda: _select(laplace={"importance_draws": 10**9}),
     "importance_draws=1000000000"),
    ("nested maxcall 1e12", lambda: _select(nested={"maxcall": 10**12}), "maxcall"),
    ("nested n_live 1e9", lambda: _select(nested={"n_live": 10**9}), "n_live=1000000000"),
    ("fast fit of 1e6 sensors", lambda: ob.fit_ml(ob.Model(ob.Ring(10**6), 0.01),
                                                 np.zeros(10**6), 1),
     "1024 candidate locations x 1000000 sub-sensors"),
    ("user grid of 3e7 points", lambda: ob.fit_ml(MODEL, DATA, 2, grid=np.broadcast_to(
        np.zeros((1, 1)), (3 * 10**7, 1))), "30000000 candidate locations"),
]


@pytest.mark.parametrize("label,call,match", CASES, ids=[c[0] for c in CASES])
def test_sizes_beyond_the_budget_are_refused_before_allocation(label, call, match):
    def run():
        with pytest.raises(ob.InputError, match=match) as info:
            call()
        assert "the limit is" in str(info.value) and ENV_VAR in str(info.value)

    assert _peak(run) < 100e6


def test_fit_rows_beyond_the_budget(monkeypatch):
    monkeypatch.setenv(ENV_VAR, "1MB")
    data = np.zeros((20_000, 30))
    with pytest.raises(ob.InputError, match=r"fit_ml of 20000 data vector\(s\) x 4 parameters"):
        ob.fit_ml(MODEL, data, 2)
    monkeypatch.setenv(ENV_VAR, "16GB")
    assert memory_limit() == 16 * 10**9


def test_npy_claiming_more_than_the_budget(tmp_path, monkeypatch):
    from olsbayes.config import read_readings

    np.save(tmp_path / "big.npy", np.zeros((200, 30), dtype=np.int8))
    monkeypatch.setenv(ENV_VAR, "10kB")
    with pytest.raises(ob.OlsBayesError, match=r"shape \(200, 30\) as float64 needs ~48 kB"):
        read_readings(tmp_path / "big.npy", 30)


@pytest.mark.parametrize("raw", ["lots", "-1GB", "1 parsec", "0"])
def test_bad_memory_limit_setting(monkeypatch, raw):
    monkeypatch.setenv(ENV_VAR, raw)
    with pytest.raises(ob.InputError, match=ENV_VAR):
        check_memory("anything", 1.0)


def test_default_limit_and_units(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert memory_limit() == DEFAULT_LIMIT
    for raw, value in (("512MiB", 512 * 2**20), ("2.5GB", 2.5e9), ("1e6", 10**6)):
        monkeypatch.setenv(ENV_VAR, raw)
        assert memory_limit() == value


@pytest.mark.parametrize("readings", ["zeros", "constant"])
def test_degenerate_readings_are_fitted_in_bounded_memory(readings):
    """16000 all-zero or constant rows: a few kB per row at most, and the trivial fit.

    With all-zero readings every configuration of the exact escalation ties, so an
    unbounded re-solve would keep 64 candidates per row.
    """
    data = np.zeros((16_000, 30)) if readings == "zeros" else np.full((16_000, 30), 0.3)
    ob.fit_ml(MODEL, data[:2], 2, warn=False)  # compiled kernels loaded outside the count
    out = {}

    def run():
        out["fit"] = ob.fit_ml(MODEL, data, 2, warn=False)

    peak = _peak(run)
    assert peak < 100e6, peak
    fit = out["fit"]
    assert fit.params.shape == (16_000, 4)
    if readings == "zeros":
        assert np.all(fit.params[:, 1::2] == 0)
        assert np.all(fit.log_likelihood == fit.log_likelihood[0])
    np.testing.assert_array_equal(fit.params[5000], ob.fit_ml(MODEL, data[5000], 2,
                                                               warn=False).params)


def test_fit_blocks_equal_one_batch():
    """Rows are fitted in blocks of BLOCK_ROWS: the rows of a block fit equal single fits."""
    from olsbayes.ml.plain import BLOCK_ROWS

    data = MODEL.simulate(ob.Scene(directions=[0.37, -2.0], intensities=[1.0, 0.2]), rng=3,
                          size=BLOCK_ROWS + 3)
    batch = ob.fit_ml(MODEL, data, 2, warn=False)
    for i in (0, BLOCK_ROWS - 1, BLOCK_ROWS, BLOCK_ROWS + 2):
        one = ob.fit_ml(MODEL, data[i], 2, warn=False)
        np.testing.assert_allclose(one.params, batch.params[i], rtol=0, atol=1e-10)
        np.testing.assert_allclose(one.cov, batch.cov[i], rtol=1e-8)


def test_a_fit_on_a_large_array_allocates_nothing_sensor_by_sensor():
    # after a model's one-off set-up (atoms, grid, sensor spacing) a fit's memory grows
    # with N, not N^2: one 4000 x 4000 matrix of doubles would be 128 MB
    model = ob.Model(ob.Ring(4000), 0.01)
    data = model.simulate(ob.Scene(directions=[0.4, 2.0], intensities=[1.0, 0.8]), rng=1)
    ob.fit_ml(model, data, 2)
    assert _peak(lambda: ob.fit_ml(model, data, 2)) < 16e6


def test_imaging_a_large_array_allocates_nothing_sensor_by_sensor():
    # the design's SVD keeps V (K x K) and no N x N factor (128 MB at N = 4000)
    model = ob.Model(ob.Ring(4000), 0.01)
    data = model.simulate(ob.Scene(directions=[0.4, 2.0], intensities=[1.0, 0.8]), rng=1)
    directions = np.array([0.4, 1.5, 2.9, 4.4])
    options = ob.ImageOptions(n_samples=0)
    assert _peak(lambda: ob.image(model, data, directions, rng=1, options=options)) < 16e6
