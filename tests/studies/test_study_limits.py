"""Study inputs that used to run away, hang or mislead: each is one clear error, up front.

Sizes are checked against stated limits before anything is allocated, settings
against what the trial reads (with its ranges), paths before the study runs.
The CLI cases run in a child process whose address space is capped at 1 GB.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import tracemalloc

import numpy as np
import pytest

from olsbayes import InputError
from olsbayes.studies import Setting, run_study, trial_settings
from olsbayes.studies.estimators import ring_estimate
from olsbayes.studies.trials import noise_check

CALLS: list[int] = []


def counted(settings, rng):
    CALLS.append(1)
    return {"x": rng.random()}


def int_then_float(settings, rng):
    """Returns an int in cell 0 and a float in cell 1 (the same output)."""
    return {"x": 1 if settings["c"] == 0 else 2.5}


def wide(settings, rng):
    CALLS.append(1)
    return {"v": rng.random(1000)}


@trial_settings(n=Setting("int", 1, 10), mode=Setting("str"), flag=Setting("bool"),
                scale=Setting("float", high=5.0, positive=True))
def declared(settings, rng):
    return {"x": 1.0}


def _refused(match, **kw):
    args = dict(trial=noise_check, grid={"sigma": [0.1]}, n_trials=2,
                fixed={"n_sensors": 8}, executor="serial", progress=False)
    args.update(kw)
    with pytest.raises(InputError, match=match):
        run_study(**args)


@pytest.mark.parametrize("kw, match", [
    (dict(fixed={"n_sensors": 10**9}), r"fixed\['n_sensors'\] must be an integer in \[3, 10000\]"),
    (dict(grid={"n_sensors": [8, 10**9]}, fixed={"sigma": 0.1}),
     r"grid\['n_sensors'\]\[1\] must be an integer in \[3, 10000\]; got 1000000000"),
    (dict(grid={"sigma": [-0.1]}), r"grid\['sigma'\]\[0\] must be a number in \(0, 1e\+06\]"),
    (dict(fixed={"n_sensors": 8.0}), "must be an integer"),
    (dict(fixed={"n_sensors": 8, "n_sources": 0}), r"n_sources'\] must be an integer in \[1,"),
    (dict(fixed={"n_sensors": 8, "intensity": 10**400}), "intensity"),
    (dict(fixed={"n_sensors": 8, "n_source": 2}), "did you mean 'n_sources'"),
    (dict(grid={"sigm": [0.1]}), "did you mean 'sigma'"),
    (dict(n_trials=10**9), r"n_trials=1e9 at 1 grid cell\(s\) needs at least ~9 GB .* the limit "
                           r"is .* GB; raise it with max_memory_gb="),
    (dict(grid={"sigma": [0.1, 0.2], "separation": list(range(500)),
                "intensity": list(range(1000))}, n_trials=10**4), "at 1e6 grid cell"),
    (dict(workers=0), r"workers must be in \[1, inf\]; got 0"),
    (dict(max_memory_gb=0), r"max_memory_gb must be a number in \(0, 1e6\]"),
    (dict(max_memory_gb=float("nan")), "max_memory_gb"),
    (dict(max_memory_gb=True), "max_memory_gb"),
    (dict(fixed={"n_sensors": 8, "separation": [[1.0]]}), r"separation'\] must be a number"),
])
def test_study_inputs_are_refused_before_any_allocation(kw, match, tmp_path):
    tracemalloc.start()
    try:
        _refused(match, checkpoint=tmp_path / "c.ckpt", **kw)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20e6  # nothing sized by the input was allocated
    assert not (tmp_path / "c.ckpt").exists()


def test_ring_estimate_settings_have_ranges_and_kinds():
    for fixed, match in [({"kink": "yes"}, r"kink'\] must be true or false"),
                         ({"select": 1}, r"select'\] must be true or false"),
                         ({"i_max": 0}, r"i_max'\] must be a number in \(0,"),
                         ({"n_sensors": 10**6}, "n_sensors"),
                         ({"methd": "fast"}, "setting 'methd' is not read")]:
        with pytest.raises(InputError, match=match):
            run_study(ring_estimate, {}, 1, fixed={"n_sensors": 8, "sigma": 0.1, **fixed},
                      executor="serial", progress=False)


def test_declared_settings_check_kind_and_range_and_keep_the_value():
    assert Setting("int", 1, 10)(3, "x") == 3
    assert isinstance(Setting("float", high=5.0)(2, "x"), int)  # values are not converted
    for value, setting, match in [(11, Setting("int", 1, 10), r"x must be an integer in \[1, 10\]"),
                                  (True, Setting("int"), "x must be an integer"),
                                  (1, Setting("bool"), "x must be true or false"),
                                  (3, Setting("str"), "x must be a string"),
                                  (float("inf"), Setting("float"), "x must be a number")]:
        with pytest.raises(InputError, match=match):
            setting(value, "x")
    with pytest.raises(ValueError, match="Setting kind"):
        Setting("complex")
    ds = run_study(declared, {"n": [1, 10]}, 1, fixed={"mode": "a", "flag": True, "scale": 5},
                   executor="serial", rng=1, progress=False)
    assert list(ds.n.values) == [1, 10]


def test_outputs_of_different_dtypes_are_promoted_not_truncated():
    ds = run_study(int_then_float, {"c": [0, 1]}, 3, executor="serial", rng=1, chunk_size=3,
                   progress=False)
    np.testing.assert_array_equal(ds.x.values, [[1, 1, 1], [2.5, 2.5, 2.5]])


def test_results_larger_than_the_budget_stop_after_the_first_chunk(tmp_path):
    ckpt = tmp_path / "c.ckpt"
    CALLS.clear()
    with pytest.raises(InputError, match=r"the results of this study need ~0.008 GB \(1 cell\(s\)"
                                         r" x 1000 trials x 8001 bytes per trial\); the limit "
                                         r"is 0.001 GB; raise it with max_memory_gb="):
        run_study(wide, {}, 1000, executor="serial", rng=1, chunk_size=10, checkpoint=ckpt,
                  max_memory_gb=0.001, progress=False)
    assert len(CALLS) == 10  # one chunk ran, and is kept
    CALLS.clear()
    ds = run_study(wide, {}, 1000, executor="serial", rng=1, chunk_size=10, checkpoint=ckpt,
                   max_memory_gb=0.1, progress=False)
    assert len(CALLS) == 990 and ds.v.shape == (1000, 1000)


def test_unusable_out_fails_before_the_study_runs(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for out, match in [(tmp_path, "is a folder; give a file name"),
                       (fifo, "not a regular file"), ("/dev/null", "not a regular file"),
                       (blocker / "sub" / "o.nc", "cannot be created"),
                       ("a\0b", "must be a file path")]:
        CALLS.clear()
        with pytest.raises(InputError, match=match):
            run_study(counted, {}, 3, executor="serial", out=out, progress=False)
        assert CALLS == []
        with pytest.raises(InputError, match=match.replace("out", "checkpoint")):
            run_study(counted, {}, 3, executor="serial", checkpoint=out, progress=False)
        assert CALLS == []


# -- the CLI, in a child process limited to 1 GB of address space ---------------------
STUDY = """
[study]
trial = "noise_check"
n_trials = 3
seed = 1
out = "s.nc"
executor = "serial"

[grid]
sigma = [0.01, 0.1]

[fixed]
n_sensors = 8
"""

CHILD = textwrap.dedent("""
    import contextlib, io, json, resource, sys
    resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))
    from olsbayes.cli import main
    out = []
    for argv in json.loads(sys.argv[1]):
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            try:
                code = main(argv)
            except BaseException as exc:  # a traceback would have reached the user
                code = f"{type(exc).__name__}: {exc}"
        out.append([argv, code, err.getvalue()])
    # peak resident memory of this process image (ru_maxrss would include the parent's,
    # which survives exec)
    status = open("/proc/self/status").read()
    peak = int(status.split("VmHWM:")[1].split()[0]) * 1024
    print(json.dumps({"cases": out, "peak": peak}))
""")


def _cli_cases(tmp_path) -> list[list[str]]:
    cfg = tmp_path / "s.toml"
    cfg.write_text(STUDY)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    (tmp_path / "folder").mkdir()
    deep = tmp_path / "deep.toml"
    deep.write_text(STUDY + "nested = " + "[" * 5000 + "]" * 5000 + "\n")
    study = ["study", str(cfg), "--no-progress"]
    return [
        ["study", "/dev/zero"],
        ["study", str(fifo)],
        ["study", str(tmp_path)],
        ["study", str(deep)],
        study + ["--workers", "0"],
        study + ["--workers", "-3"],
        study + ["--out", str(tmp_path / "folder")],
        study + ["--out", str(fifo)],
        study + ["--set", "study.trial='os:system'"],
        study + ["--set", "study.trial='math:pi'"],
        study + ["--set", "study.trial='..up:fn'"],
        study + ["--set", "study.trial='builtins:print'"],
        study + ["--set", "study.trial='olsbayes.studies.runner:run_study'"],
        study + ["--set", "fixed.n_sensors=1000000000"],
        study + ["--set", "grid.n_sensors=[8, 1000000000]"],
        study + ["--set", "fixed.n_sensor=8"],
        study + ["--set", "study.n_trials=1000000000"],
        study + ["--set", "study.max_memory_gb=0"],
        study + ["--set", "fixed.n_sources=[[[[1]]]]"],
        study + ["--set", "grid.sigma={a = 1}"],
        study + ["--scheduler", "garbage"],
    ]


def test_cli_study_catalogue_one_line_each_under_1_gb(tmp_path):
    cases = _cli_cases(tmp_path)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path), "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", CHILD, json.dumps(cases)], env=env,
                          capture_output=True, text=True, timeout=240, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    # nothing left behind to fail at exit (a half-started Dask client would wait 40 s,
    # then print "Exception ignored ... Traceback")
    assert "Traceback" not in proc.stderr and "Exception ignored" not in proc.stderr, \
        proc.stderr[-2000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    for argv, code, err in report["cases"]:
        lines = err.strip().splitlines()
        assert code == 2, (argv, code, err)
        assert len(lines) == 1 and "error:" in lines[0] and "Traceback" not in err, (argv, err)
    assert len(report["cases"]) == len(cases) >= 20
    assert report["peak"] < 1 << 30
    assert not (tmp_path / "s.nc").exists()  # no case ran a study
