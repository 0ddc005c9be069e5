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


def test_report_folder_has_every_file(small_result, tmp_path, capsys):
    res, truth = small_result
    files = write_report(res, tmp_path / "rep", truths=Scene(directions=[truth[0]],
                                                                intensities=[truth[1]]))
    # the figures take seconds: one status line says so as the call starts
    assert capsys.readouterr().err == (f"olsbayes: writing the posterior report to "
                                       f"{tmp_path / 'rep'} (figures, tables, NetCDF, HTML) ...\n")
    names = {"corner.png", "trace.png", "ppc.png", "summary.csv", "summary.json",
             "posterior.nc", "report.html"}
    assert names <= {p.name for p in (tmp_path / "rep").iterdir()}
    assert not [p for p in (tmp_path / "rep").iterdir() if p.name.startswith(".")]  # no temps
    page = files.html.read_text(encoding="utf-8")
    # embedded images are exactly the PNG files, and every link points at an existing file
    embedded = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    assert len(embedded) == 3
    pngs = {files.corner.read_bytes(), files.trace.read_bytes(), files.ppc.read_bytes()}
    assert {base64.b64decode(e) for e in embedded} == pngs
    for target in re.findall(r'href="([^"]+)"', page):
        assert (files.folder / target).is_file(), target
    summary = json.loads(files.summary_json.read_text())
    assert summary["names"] == list(summary["parameters"]) == ["theta[0]", "I[0]"]
    assert summary["run"]["olsbayes_version"] and summary["run"]["seed"] == 12
    assert 0 <= summary["model_check"]["ppp"] <= 1
    for fact in ("olsbayes_version", "seed", "data_sha256", "command", "chi2_dof", "ppp"):
        assert f"<th>{fact}</th>" in page
    assert "Uniform(0, " in page and "1e-16" not in page  # the prior in 4 digits, not a repr
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
    for group in ("posterior", "posterior_predictive", "sample_stats", "log_likelihood",
                  "observed_data", "constant_data", "prior"):
        assert group in back.groups()
    # angles stored unwrapped around their circular mean, and marked as such
    np.testing.assert_array_equal(back.posterior["theta"].values[..., 0],
                                  res.unwrapped_samples()[..., 0])
    attrs = back.posterior["theta"].attrs
    assert attrs["circular"] == 1 and attrs["units"] == "rad"
    assert back.posterior["I"].attrs["units"] == "reading units"
    for group in back.groups():
        assert getattr(back, group).attrs["inference_library"] == "emcee"
        assert "inference_library_version" in getattr(back, group).attrs
    assert back.constant_data["crlb_cov"].dims == ("parameter", "parameter_bis")
    assert list(back.constant_data["estimate"].coords["parameter"].values) == list(res.names)
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


def test_report_with_ml_truth_and_the_number_of_sources(small_result, tmp_path):
    """The report lists ML, posterior and truth side by side (same order) and, given a
    selection, the per-K evidence table and the p(K | data) plot."""
    from olsbayes import fit_ml, select_k

    res, truth = small_result
    data = res.idata.observed_data["obs"].values
    ml = fit_ml(res.model, data, 1)
    sel = select_k(res.model, data, 2, rng=1)
    files = write_report(res, tmp_path / "rep", truths=truth, ml=ml, selection=sel,
                         metadata={"data_file": "readings.txt"})
    page = files.html.read_text(encoding="utf-8")
    assert files.k_posterior.stat().st_size > 1000
    assert "ml_estimate" in page and "truth" in page and "log_evidence" in page
    assert "<th>data_file</th>" in page and 'class="wide"' in page
    summary = json.loads(files.summary_json.read_text())
    assert summary["selection"]["best"] == 1 and summary["ml"]["method"] == ml.method
