"""Calibration-map statistics on a case with a known answer; its machinery on a tiny grid."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "analyses"))

from _calmap import METHODS, calmap_trial, u_from_draws  # noqa: E402
from _calmap_cost import estimate_text, plan  # noqa: E402
from calibration_map import (  # noqa: E402
    MODES,
    cell_state,
    groups,
    reference_table,
    sbc_p,
    summarise,
)

from olsbayes import run_study  # noqa: E402


def _linear_gaussian_u(n_rep: int, sd_scale: float, rng) -> np.ndarray:
    """PIT of the truth under the exact posterior of y = X b + e, b ~ N(0, I), e ~ N(0, 0.5^2 I)
    (its sd multiplied by ``sd_scale``), with 199 posterior draws per replicate."""
    x = np.array([[1.0, 0.2], [0.4, 1.0], [1.0, -1.0]])
    prec = np.eye(2) + x.T @ x / 0.25
    cov = np.linalg.inv(prec)
    root = np.linalg.cholesky(cov) * sd_scale
    out = np.empty((n_rep, 2))
    for i in range(n_rep):
        b = rng.standard_normal(2)
        y = x @ b + 0.5 * rng.standard_normal(3)
        mean = cov @ x.T @ y / 0.25
        draws = mean + rng.standard_normal((199, 2)) @ root.T
        out[i] = u_from_draws(b, draws, rng)
    return out


def _coverages(u: np.ndarray) -> tuple[float, float]:
    return float(np.mean(np.abs(u - 0.5) < 0.25)), float(np.mean(np.abs(u - 0.5) < 0.45))


def test_exact_gaussian_posterior_is_calibrated():
    u = _linear_gaussian_u(400, 1.0, np.random.default_rng(7))
    c50, c90 = _coverages(u)
    n = u.size
    assert abs(c50 - 0.5) < 3 * np.sqrt(0.25 / n)
    assert abs(c90 - 0.9) < 3 * np.sqrt(0.09 / n)
    assert sbc_p(u) > 0.01
    # 800 parameter-draws: se of 90 % coverage 0.011, so the band is resolved
    assert cell_state(sbc_p(u), (c50, c90), n) == "calibrated"


def test_overconfident_posterior_fails():
    u = _linear_gaussian_u(400, 0.5, np.random.default_rng(8))  # intervals half as wide
    c50, c90 = _coverages(u)
    # exact coverage of a 90 % interval of half the width: 2 Phi(0.822) - 1 = 0.589
    assert abs(c90 - 0.589) < 3 * np.sqrt(0.589 * 0.411 / u.size)
    assert sbc_p(u) < 0.01
    assert cell_state(sbc_p(u), (c50, c90), u.size) == "fails"


def test_weighted_draws_give_the_posterior_cdf():
    rng = np.random.default_rng(3)
    draws = np.sort(rng.normal(size=(5000, 1)), axis=0)
    w = np.full(5000, 1 / 5000)
    truth = np.array([0.0])
    assert abs(u_from_draws(truth, draws, rng, weights=w)[0] - 0.5) < 0.03


def test_cell_state_rules():
    assert cell_state(0.5, (0.5, 0.9), 400) == "calibrated"
    assert cell_state(0.001, (0.5, 0.9), 400) == "fails"
    assert cell_state(0.5, (0.5, 0.80), 1000) == "fails"  # 0.10 off, se 0.009
    assert cell_state(0.5, (0.5, 0.85), 20) == "undecided"  # 0.05 off, se 0.067
    assert cell_state(np.nan, (0.5, 0.9), 2) == "undecided"
    assert cell_state(0.5, (np.nan, np.nan), 0) == ""


def test_groups_of_the_quick_mode():
    tags = [t for t, _, _ in groups(MODES["quick"])]
    assert tags == ["ring-k1", "ring-k2", "ring-k4", "ring-k4-antipodal", "sphere-k2"]
    assert [t for t, _, _ in groups(MODES["quick"], (2,))] == ["ring-k2", "sphere-k2"]


def test_tiny_map_runs_and_methods_share_scenes(tmp_path):
    grid = {"separation": [3.0], "snr": [100.0]}
    fixed = {"geometry": "ring", "n_sources": 2, "antipodal": -1.0, "max_steps": 200}
    res = {("ring-k2", m): run_study(calmap_trial, grid, 3, fixed={**fixed, "method": m},
                                     executor="serial", rng=5, progress=False)
           for m in ("laplace", "image-gaussian")}
    a, b = (ds["gap"].values for ds in res.values())
    np.testing.assert_array_equal(a, b)  # the same scenes for every method
    rows = summarise(res)
    assert [r["method"] for r in rows] == ["laplace", "image-gaussian"]
    assert rows[0]["n"] == 3 and 0 <= rows[0]["cov90"] <= 1 and "ml_eff" in rows[0]
    assert rows[1]["rhat_max"] == 1.0  # closed form
    from _calmap_plot import plot_map

    plot_map(rows, tmp_path / "map.png", "test", 3)
    assert (tmp_path / "map.png").stat().st_size > 0


def test_method_list_is_one_record_per_method():
    assert {"emcee", "laplace", "exact", "image-bounded", "image-gaussian"} <= set(METHODS)
    assert METHODS["exact"].applies({"geometry": "ring", "n_sources": 2, "snr": 100.0})
    assert not METHODS["exact"].applies({"geometry": "ring", "n_sources": 4, "snr": 100.0})


@pytest.mark.parametrize("bad", [{"n_sources": 5}, {"snr": 0.5}, {"geometry": "plate"},
                                 {"method": "nope"}])
def test_bad_cell_refused_before_work(bad):
    from olsbayes.errors import InputError

    fixed = {"geometry": "ring", "n_sources": 1, "snr": 100.0, "method": "laplace", **bad}
    with pytest.raises(InputError):
        run_study(calmap_trial, {}, 1, fixed=fixed, executor="serial", progress=False)


def test_plan_counts_cells_scenes_and_methods_of_each_mode():
    rows = plan(groups(MODES["full"]), METHODS, list(METHODS), 100)
    cells = {m: sum(r["cells"] for r in rows if r["method"] == m) for m in METHODS}
    assert cells["emcee"] == cells["laplace"] == 81  # every cell
    assert cells["exact"] == 12  # rings, K <= 2, SNR <= 300: 1 x 2 + 5 x 2
    assert sum(r["runs"] for r in rows if r["method"] == "emcee") == 8100
    medium = plan(groups(MODES["medium"]), METHODS, ["emcee"], 16)
    assert sum(r["cells"] for r in medium) == 50


def test_estimate_scales_measured_cpu_per_run_and_flags_gaps():
    rows = plan(groups(MODES["quick"], (2,)), METHODS, ["emcee", "laplace"], 6)
    runs = {m: sum(r["runs"] for r in rows if r["method"] == m) for m in ("emcee", "laplace")}
    text = estimate_text(rows, {("emcee", 2, 3000): (3.6, 10)}, 3000, "quick", 6)
    assert f"{runs['emcee'] * 3.6 / 3600:.2f} CPU-h" in text
    assert "laplace" in text and "CPU unknown (not measured)" in text
    lower = estimate_text(rows, {("emcee", 2, 3000): (3.6, 10)}, 20000, "quick", 6)
    assert "a lower bound" in lower  # measured under a smaller step cap


def test_reference_table_counts_states_and_names_failing_cells():
    def row(x, snr, state, c50, c90):
        return dict(group="ring-k2", method="laplace", x=x, snr=snr, state=state,
                    cov50=c50, cov90=c90)
    rows = [row(1.0, 100.0, "fails", 0.04, 0.06), row(5.0, 100.0, "calibrated", 0.5, 0.9),
            row(2.0, 10.0, "undecided", 0.44, 0.81), row(3.0, 10.0, "", np.nan, np.nan)]
    line = reference_table(rows).splitlines()[2].split()
    assert line[:6] == ["ring-k2", "laplace", "3", "1", "1", "1"]  # the n/a cell not counted
    assert line[6:] == ["0.06", "(90", "%)", "1/100"]  # 0.84 below 0.9 is the worst


def test_report_summarises_finished_studies_and_runs_nothing(tmp_path, capsys):
    from calibration_map import main

    assert main(["--report", "--out", str(tmp_path)]) == 0  # nothing finished yet
    assert "no finished study" in capsys.readouterr().out
    grid = {"separation": [3.0], "snr": [100.0]}
    fixed = {"geometry": "ring", "n_sources": 2, "antipodal": -1.0, "max_steps": 200,
             "method": "laplace"}
    run_study(calmap_trial, grid, 3, fixed=fixed, executor="serial", rng=5, progress=False,
              out=tmp_path / "quick-ring-k2-laplace-quick.nc")
    assert main(["--report", "--out", str(tmp_path), "--methods", "laplace", "emcee"]) == 0
    text = (tmp_path / "calibration_map-quick.txt").read_text()
    assert text.startswith(f"1 of {2 * len(groups(MODES['quick']))} (group, method) studies")
    assert "ring-k2" in text and "emcee" not in text.split("\n", 1)[1]  # only what ran
    assert (tmp_path / "calibration_map-quick.png").stat().st_size > 0
    assert sorted(p.name for p in tmp_path.glob("*.ckpt")) == []  # nothing was run
