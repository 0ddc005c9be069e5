"""Where a study's chunks run (``olsbayes.studies.executors``): the local pool's calls,
a local Dask cluster forked from the package's fork server, and its settings."""

from __future__ import annotations

import concurrent.futures as cf
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from olsbayes.studies import executors, run_study
from olsbayes.studies.trials import noise_check

GRID = {"sigma": [0.01, 0.1], "n_sensors": [8, 16]}


def _fail(msg):
    raise ValueError(msg)


def test_pool_calls_run_here_while_unsent_and_keep_their_errors():
    from olsbayes.studies._pool import PoolFuture

    here = PoolFuture(os.getpid, ())
    assert here.result() == os.getpid() and here.settled  # not yet sent: runs here
    bad = PoolFuture(_fail, ("boom",))
    bad.run_here()
    with pytest.raises(ValueError, match="boom"):
        bad.result()
    dropped = PoolFuture(os.getpid, ())
    assert dropped.cancel() and not dropped.cancel()
    with pytest.raises(cf.CancelledError):
        dropped.result()


def test_the_pool_takes_the_queued_calls_as_soon_as_it_runs():
    # calls queued while the pool starts go to it from the starting thread, not when
    # the caller next waits (a caller busy with a long call would leave it idle); a
    # call claimed by the caller is never handed over
    from olsbayes.studies._pool import LocalPool

    gate = threading.Event()

    class Gated(LocalPool):  # starts only once the calls are queued and one is claimed
        def _start(self, delay):
            gate.wait(120)
            super()._start(0.0)

    pool = Gated(1)
    try:
        calls = [pool.submit(os.getpid) for _ in range(3)]
        assert calls[0].claim() and not calls[0].claim()
        assert not pool.ready.is_set() and [c.inner for c in calls] == [None] * 3
        gate.set()
        assert pool.ready.wait(120)
        deadline = time.monotonic() + 10
        while calls[2].inner is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert calls[0].inner is None and None not in (calls[1].inner, calls[2].inner)
        calls[0].run_here()
        assert calls[0].result() == os.getpid() != calls[1].result() == calls[2].result()
    finally:
        pool.close()
        gate.set()


def test_a_pool_that_breaks_fails_every_call_not_cancelled():
    # a worker killed while calls wait, some of them cancelled: each other call fails
    # with BrokenProcessPool.  (Python 3.11's own futures would end the pool's manager
    # thread at the first cancelled one, leaving those after it pending for ever.)
    from olsbayes.studies._pool import forkserver_context, submit_safely

    pool = cf.ProcessPoolExecutor(max_workers=1, mp_context=forkserver_context())
    try:
        pid = submit_safely(pool, os.getpid).result(timeout=60)
        calls = [submit_safely(pool, time.sleep, 60) for _ in range(12)]
        # every other call; those the pool has sent on (at most calls[0..2]: one running,
        # two in its call queue) cannot be cancelled, the rest stay in its pending table
        cancelled = [f for f in calls[::2] if f.cancel()]
        assert len(cancelled) >= 4
        os.kill(pid, signal.SIGKILL)
        rest = [f for f in calls if not f.cancelled()]
        done, left = cf.wait(rest, timeout=30)
        assert not left and all(isinstance(f.exception(), cf.process.BrokenProcessPool)
                                for f in done)
    finally:
        pool.shutdown(wait=False, cancel_futures=True)


def test_a_users_process_pool_runs_the_study_and_is_left_open():
    from olsbayes.studies._pool import forkserver_context

    with cf.ProcessPoolExecutor(max_workers=2, mp_context=forkserver_context()) as pool:
        theirs = run_study(noise_check, GRID, 6, executor=pool, rng=3, progress=False)
        assert pool.submit(os.getpid).result(timeout=60) != os.getpid()  # still usable
    assert theirs.identical(run_study(noise_check, GRID, 6, executor="serial", rng=3,
                                      progress=False))


def _pools(monkeypatch, delay: float) -> list:
    """Set the study's pool start delay; per process pool made from now on, the calls
    handed to it (the first: the start's ``os.getpid``)."""
    made = []

    class Recording(cf.ProcessPoolExecutor):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.calls = []
            made.append(self.calls)

        def submit(self, fn, /, *args, **kwargs):
            self.calls.append(fn)
            return super().submit(fn, *args, **kwargs)

    monkeypatch.setattr(executors, "POOL_START_DELAY", delay)
    monkeypatch.setattr(cf, "ProcessPoolExecutor", Recording)
    return made


def _small_study(monkeypatch, delay: float) -> list:
    """A 24-trial study on the local pool with start delay ``delay``, checked against
    serial; the calls handed to its process pool (:func:`_pools`)."""
    made = _pools(monkeypatch, delay)
    ref = run_study(noise_check, GRID, 6, executor="serial", rng=3, progress=False)
    procs = run_study(noise_check, GRID, 6, executor="processes", workers=2, rng=3,
                      chunk_size=1, progress=False)
    assert procs.identical(ref)
    return made


def test_process_pool_study_on_many_small_chunks_equals_serial(monkeypatch):
    made = _small_study(monkeypatch, 0.0)
    deadline = time.monotonic() + 10
    while not made[0] and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(made) == 1 and made[0][0] is os.getpid  # the pool was started


def test_a_study_done_within_the_start_delay_never_starts_its_pool(monkeypatch):
    made = _small_study(monkeypatch, 60.0)
    time.sleep(0.1)
    assert made == [[]]  # a pool object, never started (closed within the delay)


def test_local_dask_workers_fork_from_the_package_fork_server():
    # a fresh local cluster's workers are forked by the fork server (which has imported
    # the package) rather than spawned by this process, whose children they would be
    import psutil

    from olsbayes.studies.executors import make_backend

    backend = make_backend("dask", workers=1)
    try:
        parent = backend.submit(os.getppid).result()
        command = " ".join(psutil.Process(parent).cmdline())  # psutil: a distributed dependency
        assert parent != os.getpid() and "multiprocessing.forkserver" in command
    finally:
        backend.close()
    # and the study gives the same numbers as serial
    local = run_study(noise_check, GRID, 24, executor="dask", workers=2, rng=7, chunk_size=3,
                      progress=False)
    assert local.identical(run_study(noise_check, GRID, 24, executor="serial", rng=7,
                                     progress=False))


_IDLE_SCRIPT = textwrap.dedent("""
    import concurrent.futures as cf, time
    from olsbayes.studies._pool import forkserver_context

    def loaded(_=0):
        import olsbayes.ml._numba.lm as lm
        return bool(lm._lm_all.signatures)  # machine code in memory, no call made here

    if __name__ == "__main__":
        ctx = forkserver_context()
        with cf.ProcessPoolExecutor(1, mp_context=ctx) as pool:
            first = pool.submit(loaded).result()
        for _ in range(120):  # seconds; ~2 when the kernels are in numba's cache
            time.sleep(1.0)
            with cf.ProcessPoolExecutor(1, mp_context=ctx) as pool:
                later = pool.submit(loaded).result()
            if later:
                break
        print(first, later)
""")


def test_the_fork_server_loads_the_kernels_while_idle(tmp_path):
    """In a new process: the first worker starts without the compiled kernels in memory;
    once the fork server has been idle it loads them, and later workers start with
    them.  Importing the server's module anywhere else installs nothing."""
    from olsbayes.ml.warmup import fast_fits

    fast_fits()  # into numba's cache (compiled here if need be): the server only loads
    script = tmp_path / "idle_load.py"
    script.write_text(_IDLE_SCRIPT)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         timeout=300, check=True)
    assert out.stdout.split() == ["False", "True"], out.stdout + out.stderr
    import olsbayes._forkserver as server

    assert server._IDLE_LOAD is None


def test_the_fork_server_loads_kernels_but_never_compiles_them(tmp_path):
    """With an empty numba cache the server's load stops at the first kernel it would have
    to compile (tens of seconds a waiting fork would pay): nothing compiled, nothing said."""
    code = ("import olsbayes._forkserver as s, olsbayes.ml._numba.lm as lm; "
            "print(s.load_cached(), len(lm._lm_all.signatures))")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300, check=True, env=env)
    assert out.stdout.split() == ["False", "0"] and "compiling" not in out.stderr, out.stderr


def test_local_dask_cluster_runs_with_quiet_housekeeping_timers_only_there():
    # the cluster run_study starts has no task profiler and slow ticks in its workers
    # and scheduler; the calling process's own Dask settings are left as they were
    import dask

    pytest.importorskip("distributed")  # its settings join dask.config when imported

    from olsbayes.studies.executors import make_backend

    before = dask.config.get("distributed.worker.profile.enabled")
    backend = make_backend("dask", workers=1)
    try:
        worker = backend.submit(dask.config.get, "distributed.worker.profile.enabled").result()
        ticks = backend.submit(dask.config.get, "distributed.admin.tick.interval").result()
        assert worker is False and ticks == "1s"
    finally:
        backend.close()
    assert dask.config.get("distributed.worker.profile.enabled") == before


def test_a_study_alone_in_its_process_takes_the_chunks_of_every_worker(monkeypatch, tmp_path):
    from olsbayes.studies.checkpoint import read_chunks

    _pools(monkeypatch, 60.0)
    grid = {"sigma": [0.01], "n_sensors": [8]}
    ref = run_study(noise_check, grid, 16, executor="serial", rng=4, progress=False)
    ckpt = tmp_path / "s.ckpt"
    procs = run_study(noise_check, grid, 16, executor="processes", workers=2, rng=4,
                      checkpoint=ckpt, progress=False)
    assert procs.identical(ref)
    # 16 trials for 2 workers are 16 chunks of 1; alone, the process runs them in pairs
    assert [len(rec.trials) for rec in read_chunks(ckpt)] == [2] * 8


def test_a_slow_scheduler_connection_says_so_once_and_a_failed_one_is_closed(monkeypatch, capsys):
    distributed = pytest.importorskip("distributed")
    from olsbayes.errors import InputError

    closed = []

    class Unreachable:  # connects for 0.3 s, then times out
        def __init__(self, address, **kwargs):
            time.sleep(0.3)
            raise OSError(f"Timed out trying to connect to {address}")

        def close(self, timeout=None):
            closed.append(timeout)

    monkeypatch.setattr(distributed, "Client", Unreachable)
    with pytest.raises(InputError, match="cannot reach the Dask scheduler at 'tcp://h:1': Timed"):
        executors._connect("tcp://h:1", notice_after=0.05)
    err = capsys.readouterr().err
    assert err == ("olsbayes: connecting to the Dask scheduler at 'tcp://h:1' "
                   "(gives up after 20 s) ...\n")
    assert closed == [1]  # the half-started client, closed before the error is raised
    monkeypatch.undo()
    # one that fails at once (no port) says nothing but the error
    with pytest.raises(InputError, match="missing port number"):
        executors._connect("h", notice_after=0.2)
    time.sleep(0.3)
    assert capsys.readouterr().err == ""
