"""Monte Carlo studies: reproducibility across executors, checkpoint/resume, bad input."""

from __future__ import annotations

import concurrent.futures as cf
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from olsbayes import InputError
from olsbayes.studies import dataset_seed, run_study, trial_seed, vectorized
from olsbayes.studies._frames import scan
from olsbayes.studies.checkpoint import read_chunks
from olsbayes.studies.trials import noise_check, noise_check_batch

GRID = {"sigma": [0.01, 0.1], "n_sensors": [8, 16]}


def _serial(**kw):
    kw.setdefault("rng", 7)
    return run_study(noise_check, GRID, 24, executor="serial", progress=False, **kw)


# -- module-level trials for the bad-input tests (run serially) ------------------
def returns_list(settings, rng):
    return [1.0]


def returns_text(settings, rng):
    return {"x": "abc"}


def ragged(settings, rng):
    return {"x": np.zeros(int(rng.integers(1, 3)))}


def fails_on_cell(settings, rng):
    if settings["sigma"] == 0.1:
        raise ZeroDivisionError("boom")
    return {"x": rng.normal()}


def const_one(settings, rng):
    return {"x": 1.0}


def const_two(settings, rng):
    return {"x": 2.0}


@vectorized
def short_batch(settings, rngs):
    return {"x": np.zeros(len(rngs) - 1)}


def reenters(settings, rng):
    """A trial that starts a second study on the checkpoint its own study holds."""
    ds = run_study(const_one, {}, 1, executor="serial", rng=1, checkpoint=settings["ckpt"],
                   progress=False)
    return {"x": float(ds.x.sum())}


@pytest.mark.slow
def test_same_numbers_on_every_executor_worker_count_and_chunking(monkeypatch):
    from distributed import Client, LocalCluster

    from olsbayes.studies import executors

    monkeypatch.setattr(executors, "POOL_START_DELAY", 0.0)  # the pool runs chunks too
    ref = _serial()
    procs = run_study(noise_check, GRID, 24, executor="processes", workers=2, rng=7,
                      chunk_size=5, progress=False)
    assert procs.identical(ref)
    with cf.ThreadPoolExecutor(3) as pool:
        threads = run_study(noise_check, GRID, 24, executor=pool, rng=7, chunk_size=24,
                            progress=False)
        assert pool.submit(int, 1).result() == 1  # a user's executor is left running
    assert threads.identical(ref)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=":0") as cluster:
        with Client(cluster) as client:
            dask = run_study(noise_check, GRID, 24, executor=client, rng=7, chunk_size=7,
                             progress=False)
            assert client.submit(int, 2).result() == 2  # the user's client is left open
        # no client of the user's around: the runner's own client is not the default one
        by_address = run_study(noise_check, GRID, 24, executor="dask", rng=7,
                               scheduler=cluster.scheduler_address, progress=False)
    assert dask.identical(ref) and by_address.identical(ref)
    # the vectorised form draws the same streams: same scenes and noise
    batch = run_study(noise_check_batch, GRID, 24, executor="serial", rng=7, chunk_size=9,
                      progress=False)
    np.testing.assert_array_equal(batch.theta0, ref.theta0)
    np.testing.assert_allclose(batch.chi2, ref.chi2, rtol=1e-12)


def test_trial_streams_are_the_spawned_children():
    child = np.random.SeedSequence(7).spawn(4)[3].spawn(24)[5]
    np.testing.assert_array_equal(trial_seed(7, 3, 5).generate_state(4), child.generate_state(4))
    ds = _serial()
    # cell 3 = (sigma 0.1, n_sensors 16): its trial 5 starts with the scene's direction draw
    first = np.random.default_rng(child).uniform(-np.pi, np.pi)
    assert ds.theta0.isel(sigma=1, n_sensors=1, trial=5).item() == first


def test_dataset_layout_statistics_and_netcdf_roundtrip(tmp_path):
    out = tmp_path / "study.nc"
    ds = run_study(noise_check, GRID, 400, fixed={"n_sources": 2, "intensity": 0.5},
                   executor="serial", rng=11, out=out, progress=False)
    assert ds.chi2.dims == ("sigma", "n_sensors", "trial")
    assert ds.moments.dims == ("sigma", "n_sensors", "trial", "moments_dim0")
    assert ds.attrs["seed"] == 11 and ds.attrs["seed"].dtype == np.int64
    assert ds.attrs["seed_decimal"] == "11" and ds.attrs["n_trials"] == 400
    assert ds.chi2.attrs == {"long_name": "residual sum of squares / sigma^2 at the true scene",
                             "units": "1"}
    assert ds.theta0.attrs["units"] == "rad" and "long_name" in ds.trial.attrs
    assert "noise_check" in ds.attrs["trial_function"]
    assert '"n_sources": 2' in ds.attrs["fixed_settings"]
    # chi2 of the truth ~ chi2_N: mean N within 4 Monte Carlo standard errors sqrt(2N/T)
    for n in GRID["n_sensors"]:
        mean = ds.chi2.sel(n_sensors=n).mean("trial").values
        assert np.all(np.abs(mean - n) < 4 * np.sqrt(2 * n / 400))
    back = xr.load_dataset(out, engine="h5netcdf")
    assert back.identical(ds)
    assert dataset_seed(back) == 11
    assert dataset_seed(back.assign_attrs(seed="11")) == 11  # a seed stored as decimal text


def test_seed_without_a_value_given_is_numeric_and_repeats_the_study(tmp_path):
    """rng=None draws 128 bits: stored as uint64 words that dataset_seed reassembles."""
    out = tmp_path / "study.nc"
    ds = run_study(noise_check, {"sigma": [0.1]}, 3, fixed={"n_sensors": 8},
                   executor="serial", out=out, progress=False)
    back = xr.load_dataset(out, engine="h5netcdf")
    seed = dataset_seed(back)
    assert str(seed) == back.attrs["seed_decimal"]
    assert np.asarray(back.attrs["seed"]).dtype.kind in "iu"
    again = run_study(noise_check, {"sigma": [0.1]}, 3, fixed={"n_sensors": 8},
                      executor="serial", rng=seed, progress=False)
    np.testing.assert_array_equal(again.chi2.values, ds.chi2.values)


def test_bad_inputs_are_refused_with_the_argument_named(tmp_path):
    cases = [
        (dict(grid=[1, 2]), "grid must be a dict"),
        (dict(grid={"sigma": []}), "at least one value"),
        (dict(grid={"sigma": [0.1, "a"]}), r"grid\['sigma'\]\[1\] must be a number in"),
        (dict(trial=const_one, grid={"a": [0.1, "a"]}), "mixes value types"),
        (dict(grid={"sigma": [0.1, 0.1]}), "repeated values"),
        (dict(grid={"trial": [1]}), "identifiers other than"),
        (dict(trial=const_one, grid={"a": [float("nan")]}), "finite"),
        (dict(grid={"sigma": [float("nan")]}), r"must be a number in \(0, 1e\+06\]; got nan"),
        (dict(n_trials=0), "n_trials must be in"),
        (dict(chunk_size=0), "chunk_size must be in"),
        (dict(executor="gpu"), "executor must be one of"),
        (dict(executor="processes", scheduler="tcp://x:1"), "scheduler is only used"),
        (dict(rng=-1), "seed must be >= 0"),
        (dict(rng=np.random.SeedSequence(1).spawn(1)[0]), "root SeedSequence"),
        (dict(fixed={"sigma": 1.0}), "both a grid axis and fixed"),
        (dict(progress="yes"), "progress must be"),
    ]
    for extra, message in cases:
        kw = dict(trial=noise_check, grid={"sigma": [0.1], "n_sensors": [8]}, n_trials=2,
                  executor="serial", progress=False)
        kw.update(extra)
        with pytest.raises(InputError, match=message):
            run_study(**kw)
    with pytest.raises(InputError, match="cannot be sent to processes workers"):
        run_study(lambda settings, rng: {"x": 1.0}, {}, 2, executor="processes", workers=1,
                  progress=False)
    for fn, message in [(returns_list, "non-empty dict"), (returns_text, "numbers or bools"),
                        (ragged, "fixed shape"), (short_batch, "leading axis 4")]:
        with pytest.raises(InputError, match=message):
            run_study(fn, {}, 4, executor="serial", chunk_size=4, rng=1, progress=False)


def test_trial_error_propagates_and_finished_chunks_stay_checkpointed(tmp_path):
    ckpt = tmp_path / "c.ckpt"
    with pytest.raises(ZeroDivisionError) as info:
        run_study(fails_on_cell, {"sigma": [0.01, 0.1]}, 6, executor="serial", chunk_size=3,
                  checkpoint=ckpt, rng=2, progress=False)
    assert "cell 1" in "".join(getattr(info.value, "__notes__", []))
    assert sorted(rec.cell for rec in read_chunks(ckpt)) == [0, 0]
    with pytest.raises(ZeroDivisionError):  # lock released on error: the rerun resumes
        run_study(fails_on_cell, {"sigma": [0.01, 0.1]}, 6, executor="serial", chunk_size=3,
                  checkpoint=ckpt, rng=2, progress=False)


def test_checkpoint_held_by_a_running_study_is_refused(tmp_path):
    ckpt = tmp_path / "c.ckpt"
    with pytest.raises(InputError, match="in use by another running study"):
        run_study(reenters, {}, 1, fixed={"ckpt": str(ckpt)}, executor="serial", rng=1,
                  checkpoint=ckpt, progress=False)
    assert read_chunks(ckpt) == []  # header only: the second study wrote nothing


def test_checkpoint_from_other_settings_is_refused(tmp_path):
    ckpt = tmp_path / "c.ckpt"
    ref = _serial(checkpoint=ckpt)
    again = _serial(checkpoint=ckpt)  # a complete checkpoint: nothing runs, same result
    assert again.identical(ref)
    assert _serial(checkpoint=ckpt, rng=None).identical(ref)  # recorded seed adopted
    for kw, diff in [(dict(rng=8), "seed"), (dict(fixed={"intensity": 2.0}), "fixed")]:
        with pytest.raises(InputError, match=f"other settings .*{diff}"):
            _serial(checkpoint=ckpt, **kw)
    with pytest.raises(InputError, match="n_trials"):
        run_study(noise_check, GRID, 25, executor="serial", rng=7, checkpoint=ckpt,
                  progress=False)
    with pytest.raises(InputError, match="trial"):
        run_study(noise_check_batch, GRID, 24, executor="serial", rng=7, checkpoint=ckpt,
                  progress=False)
    with pytest.raises(InputError, match="grid"):
        run_study(noise_check, {**GRID, "sigma": [0.01, 0.2]}, 24, executor="serial", rng=7,
                  checkpoint=ckpt, progress=False)
    # same name, edited body: the checkpoint's results came from other code
    edited = tmp_path / "e.ckpt"
    run_study(const_one, {}, 2, executor="serial", rng=1, checkpoint=edited, progress=False)
    const_two.__qualname__ = const_one.__qualname__
    with pytest.raises(InputError, match="trial_code"):
        run_study(const_two, {}, 2, executor="serial", rng=1, checkpoint=edited,
                  progress=False)
    junk = tmp_path / "junk.ckpt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="not an olsbayes study checkpoint"):
        _serial(checkpoint=junk)


def test_torn_last_chunk_is_dropped_and_rerun(tmp_path):
    ckpt = tmp_path / "c.ckpt"
    ref = _serial(checkpoint=ckpt, chunk_size=8)
    data = ckpt.read_bytes()
    last = scan(data).frames[-1]
    ckpt.write_bytes(data[: last[0] + len(last[2]) // 2])  # half of the last frame survives
    with pytest.warns(RuntimeWarning, match="torn last chunk"):
        assert _serial(checkpoint=ckpt, chunk_size=5).identical(ref)


SCRIPT = textwrap.dedent(
    """
    import sys, time
    from olsbayes.studies import run_study
    from olsbayes.studies.trials import noise_check

    def slow_trial(settings, rng):
        time.sleep(0.03)
        return noise_check(settings, rng=rng)

    if __name__ == "__main__":
        ckpt = None if sys.argv[1] == "-" else sys.argv[1]
        run_study(slow_trial, {"sigma": [0.01, 0.1], "n_sensors": [8, 16]}, 30,
                  executor=sys.argv[3], workers=2, chunk_size=3, rng=5, checkpoint=ckpt,
                  out=sys.argv[2], progress=False)
    """
)


def _count_trials(ckpt: Path) -> np.ndarray:
    counts = np.zeros((4, 30), int)
    for rec in read_chunks(ckpt):
        np.add.at(counts[rec.cell], rec.trials, 1)
    return counts


def _session_members(sid: int) -> list[int]:
    """Pids of live processes in session ``sid`` (Linux /proc; empty elsewhere)."""
    pids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # the process ended meanwhile
            continue
        if int(fields[3]) == sid and fields[0] != "Z":
            pids.append(int(stat.parent.name))
    return pids


@pytest.mark.slow
def test_study_killed_with_sigkill_resumes_without_loss_or_duplicates(tmp_path):
    script = tmp_path / "study_script.py"
    script.write_text(SCRIPT)
    ckpt, out = tmp_path / "s.ckpt", tmp_path / "s.nc"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([sys.executable, str(script), str(ckpt), str(out), "processes"],
                            env=env, start_new_session=True)
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and proc.poll() is None:
            if ckpt.exists() and _count_trials(ckpt).sum() >= 15:
                break
            time.sleep(0.02)
        os.kill(proc.pid, signal.SIGKILL)  # the study's process only, not its workers
        proc.wait()
        # its pool workers notice and exit (none left computing or waiting for nobody)
        deadline = time.monotonic() + 20
        while _session_members(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _session_members(proc.pid) == []
    finally:
        if _session_members(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    partial = _count_trials(ckpt)
    assert proc.returncode == -signal.SIGKILL and not out.exists()
    assert 0 < partial.sum() < 120 and partial.max() == 1
    # the same command resumes (here in-process: the executor does not change the numbers)
    subprocess.run([sys.executable, str(script), str(ckpt), str(out), "serial"], env=env,
                   check=True)
    counts = _count_trials(ckpt)
    assert np.all(counts == 1)  # every trial exactly once: none lost, none duplicated
    resumed = xr.load_dataset(out)
    assert resumed.attrs["trial_function"] == "__main__:slow_trial"
    # slow_trial returns noise_check's numbers: compare with an uninterrupted run
    fresh = run_study(noise_check, {"sigma": [0.01, 0.1], "n_sensors": [8, 16]}, 30,
                      executor="serial", rng=5, progress=False)
    assert resumed.equals(fresh)  # values and coordinates (attrs name the other function)


STUDY_TOML = """
[study]
trial = "noise_check"
n_trials = 5
seed = 3
out = "s.nc"
checkpoint = "s.ckpt"
executor = "serial"

[grid]
sigma = [0.01, 0.1]

[fixed]
n_sensors = 8
"""


def test_cli_study_runs_resumes_and_refuses(tmp_path, capsys):
    from olsbayes.cli import main

    cfg = tmp_path / "s.toml"
    cfg.write_text(STUDY_TOML)
    assert main(["study", str(cfg), "--no-progress"]) == 0
    assert "written:" in capsys.readouterr().out
    ds = xr.load_dataset(tmp_path / "s.nc")
    ref = run_study(noise_check, {"sigma": [0.01, 0.1]}, 5, fixed={"n_sensors": 8},
                    executor="serial", rng=3, progress=False)
    assert ds.identical(ref)
    for argv, message in [
        ([], "pass --resume"),
        (["--resume", "--set", "study.seed=4"], "other settings (differing: seed)"),
        (["--set", "study.bogus=1"], "unknown key 'bogus' in [study]"),
        (["--set", "study.trial='nomodule:fn'"], "cannot be imported"),
        (["--resume", "--set", "grid.sigma=[]"], "at least one value"),
    ]:
        assert main(["study", str(cfg), "--no-progress", *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
    assert main(["study", str(cfg), "--resume", "--json", "--no-progress"]) == 0
    assert '"seed": 3,' in capsys.readouterr().out  # a number, as in the NetCDF


def test_scores_match_exchangeable_sources_and_the_crlb():
    import warnings

    from olsbayes import Model, Ring, Scene, crlb
    from olsbayes.studies.scoring import score

    model = Model(Ring(16), 0.01)
    truth = np.array([[3.1, 1.0, -2.0, 0.5]])
    std = crlb(model, Scene(directions=[3.1, -2.0], intensities=[1.0, 0.5])).std
    d = np.array([2e-3, -1e-3, 4e-3, 2e-3])
    # estimate: sources swapped, the first one wrapped across +-pi
    est = np.array([[-2.0 + d[2], 0.5 + d[3], 3.1 + d[0] - 2 * np.pi, 1.0 + d[1]]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = score(model, est, truth)
    z = d / std
    np.testing.assert_allclose(s["dir_z2"], np.mean(z[[0, 2]] ** 2), rtol=1e-9)
    np.testing.assert_allclose(s["int_z2"], np.mean(z[[1, 3]] ** 2), rtol=1e-9)
    np.testing.assert_allclose(s["max_z"], np.abs(z).max(), rtol=1e-9)
    np.testing.assert_allclose(s["dir_err_rms"], np.sqrt(np.mean(d[[0, 2]] ** 2)), rtol=1e-9)
    assert s["resolvable"].all() and not s["on_kink"].any()


def test_rank_statistics_are_uniform_for_an_exact_posterior():
    from olsbayes.studies.sbc import N_DRAWS, rank_test, ranks_of

    rng = np.random.default_rng(3)
    mu = rng.normal(size=400)  # prior N(0, 1), data y ~ N(mu, 1), posterior N(y/2, 1/2)
    y = mu + rng.normal(size=400)
    ranks = np.array([ranks_of(np.array([m]), (yy / 2 + np.sqrt(0.5) * rng.normal(
        size=(N_DRAWS, 1)))) for m, yy in zip(mu, y)])[:, 0]
    good = rank_test(ranks, N_DRAWS, 10, rng=rng)
    assert good.counts.sum() == 400 and good.p_value > 1e-3 and good.ks_p_value > 1e-3
    # an overconfident posterior (sd halved) gives a U-shaped, rejected histogram
    bad = np.array([ranks_of(np.array([m]), (yy / 2 + 0.35 * rng.normal(size=(N_DRAWS, 1))))
                    for m, yy in zip(mu, y)])[:, 0]
    assert rank_test(bad, N_DRAWS, 10, rng=rng).p_value < 1e-3
