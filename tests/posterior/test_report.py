"""Posterior report folder, plots and ArviZ round trip."""

import base64
import json
import re
import warnings

import numpy as np
import pytest

from olsbayes import Model, Ring, Scene
from olsbayes.posterior import SamplerOptions, sample, write_report
from olsbayes.posterior._arviz import from_netcdf


@pytest.fixture(scope="module")
def small_result():
    model = Model(Ring(16), sigma=0.02)
    truth = np.array([np.pi - 0.02, 1.0])  # a source at the +-pi edge
    data = model.simulate(truth, rng=11)
    res = sample(model, data, 1, start=truth, rng=12, progress=False,
                 options=SamplerOptions(n_steps=400))
    return res, truth


def test_report_folder_has_every_file(small_result, tmp_path):
    res, truth = small_result
    files = write_report(res, tmp_path / "rep", truths=Scene(directions=[truth[0]],
                                                                intensities=[truth[1]]))
    names = {"corner.png", "trace.png", "summary.csv", "summary.json", "posterior.nc",
             "report.html"}
    assert names <= {p.name for p in (tmp_path / "rep").iterdir()}
    assert not [p for p in (tmp_path / "rep").iterdir() if p.name.startswith(".")]  # no temps
    page = files.html.read_text(encoding="utf-8")
    # embedded images are exactly the PNG files, and every link points at an existing file
    embedded = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    assert len(embedded) == 2
    pngs = {files.corner.read_bytes(), files.trace.read_bytes()}
    assert {base64.b64decode(e) for e in embedded} == pngs
    for target in re.findall(r'href="([^"]+)"', page):
        assert (files.folder / target).is_file(), target
    summary = json.loads(files.summary_json.read_text())
    assert set(summary["parameters"]) == {"theta[0]", "I[0]"}
    assert summary["parameters"]["theta[0]"]["sd"] < 0.1  # circular: not ~pi at the edge
    assert abs(abs(summary["truths"]["theta[0]"]) - (np.pi - 0.02)) < 1e-9 or abs(
        summary["truths"]["theta[0]"] - (np.pi - 0.02)) < 0.5
    csv_head = files.summary_csv.read_text().splitlines()[0]
    for col in ("mean", "sd", "ess_bulk", "ess_tail", "r_hat", "tau", "crlb", "sd_over_crlb"):
        assert col in csv_head


def test_netcdf_round_trip(small_result, tmp_path):
    res, _ = small_result
    path = res.to_netcdf(tmp_path / "p.nc")
    back = from_netcdf(path)
    for group in ("posterior", "sample_stats", "log_likelihood", "observed_data",
                  "constant_data", "prior"):
        assert group in back.groups()
    np.testing.assert_array_equal(back.posterior["theta"].values[..., 0], res.samples[..., 0])
    assert back.log_likelihood["obs"].shape[-1] == 16
    assert back.constant_data["normals"].shape == (16, 2)
    # pointwise log-likelihood sums to the total one at every draw
    total = back.sample_stats["lp"].values - back.sample_stats["log_prior"].values
    np.testing.assert_allclose(back.log_likelihood["obs"].values.sum(-1), total, rtol=1e-10)


def test_loo_over_sub_sensors(small_result):
    """Dark sub-sensors have constant log-likelihood: LOO adds them exactly, no k = inf."""
    from olsbayes.posterior._arviz import loo

    res, _ = small_result
    ll = res.idata.log_likelihood["obs"].values.reshape(-1, 16)
    dark = np.ptp(ll, axis=0) == 0
    assert dark.any()
    with warnings.catch_warnings():  # a genuine high-k warning may remain (near-horizon sensors)
        warnings.simplefilter("ignore", UserWarning)
        out = loo(res.idata, pointwise=True)
        total = float(loo(res.idata)["elpd_loo"])
    assert out["n_data_points"] == 16 and np.all(out["pareto_k"].values[dark] == 0.0)
    np.testing.assert_allclose(out["loo_i"].values[dark], ll[0, dark])
    assert abs(total - out["loo_i"].values.sum()) < 1e-9


def test_corner_plot_draws_crlb_ellipses(small_result):
    from matplotlib.patches import Ellipse

    from olsbayes.plotting import plot_corner, plot_trace

    res, truth = small_result
    fig = plot_corner(res, truths=truth)
    assert len(fig.axes) == 4
    assert sum(isinstance(p, Ellipse) for p in fig.axes[2].patches) == 2  # 1 and 2 sigma
    assert "rad" in fig.axes[2].get_xlabel()
    # a source at +-pi: the plotted angle axis is one continuous interval, not [-pi, pi]
    lo, hi = fig.axes[0].get_xlim()
    assert hi - lo < 1.0
    fig2 = plot_trace(res)
    assert len(fig2.axes) == 4
    import matplotlib.pyplot as plt

    plt.close(fig)
    plt.close(fig2)
