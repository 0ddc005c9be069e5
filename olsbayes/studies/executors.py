"""Where chunks of trials run: in process, a local pool, Dask, or any Executor.

Every backend offers the same three operations -- ``submit(fn, *args)``,
``wait_first(pending)`` and ``close()`` -- so the runner keeps a bounded window
of chunks in flight and checkpoints each one as soon as it finishes.  Dask
(``distributed``) is an optional extra, imported only when it is used.

The local process pool starts fast: its workers fork from a server process that
has imported the package once (:mod:`olsbayes._forkserver`), and until the first worker
has delivered a chunk the study's own process runs queued chunks itself, so a
small study never waits for the pool.  A fresh local Dask cluster forks its
workers from the same server (which then also imports ``distributed``, if it is
the first to start it) instead of spawning processes that import everything anew.
A chunk gives the same numbers wherever it runs (its trials' seeds are fixed).
"""

from __future__ import annotations

import concurrent.futures as cf
import importlib.util
import multiprocessing
import os
import select
import threading
import time
from collections.abc import Callable
from multiprocessing import forkserver
from typing import Any

from .._validation import _short, integer
from ..errors import InputError

__all__ = ["Backend", "make_backend", "EXECUTORS"]

#: Executor names accepted by :func:`make_backend`.
EXECUTORS = ("serial", "threads", "processes", "dask")


class _Deferred:
    """A future computed when its result is first asked for (serial backend)."""

    def __init__(self, fn: Callable, args: tuple):
        self._fn, self._args = fn, args

    def result(self) -> Any:
        return self._fn(*self._args)

    def cancel(self) -> bool:
        return True


class _PoolFuture:
    """A call for the local pool that the study's own process may run instead.

    ``inner`` is the pool's future once the call has been handed to the pool
    (None before: the pool is still starting).  :meth:`run_here` runs the call in
    this process, cancelling the pool's copy; calls are deterministic, so where a
    call ran never changes its result.
    """

    def __init__(self, fn: Callable, args: tuple):
        self.inner: cf.Future | None = None
        self._call = (fn, args)
        self._outcome: tuple[bool, Any] | None = None

    @property
    def settled(self) -> bool:
        """Whether the call ran here (or was cancelled before it reached the pool)."""
        return self._outcome is not None

    def hand_to(self, pool: cf.Executor) -> None:
        """Give the call to the pool unless it ran here already."""
        if self.inner is None and self._outcome is None:
            fn, args = self._call
            self.inner = pool.submit(fn, *args)

    def run_here(self) -> None:
        """Run the call in this process (its exception, if any, is kept for result())."""
        fn, args = self._call
        try:
            self._outcome = (True, fn(*args))
        except Exception as exc:  # noqa: BLE001 - re-raised by result(), as the pool would
            self._outcome = (False, exc)

    def result(self) -> Any:
        """The call's value, or its exception raised here (run here if still unsent)."""
        if self._outcome is None and self.inner is None:
            self.run_here()
        if self._outcome is not None:
            ok, value = self._outcome
            if ok:
                return value
            raise value
        try:
            return self.inner.result()
        except cf.process.BrokenProcessPool as exc:
            raise InputError(
                "the study's worker processes ended abruptly (killed, out of memory, or "
                "failing on start-up). Workers import the script that called run_study: a "
                "script must call it under `if __name__ == \"__main__\":`; or use "
                f"executor='serial' or 'threads' ({exc})") from None

    def cancel(self) -> bool:
        """Cancel the call if it has not started (here or in the pool)."""
        if self._outcome is not None:
            return False
        if self.inner is None:
            self._outcome = (False, cf.CancelledError())
            return True
        return self.inner.cancel()


def _forkserver(*extra: str) -> multiprocessing.context.BaseContext:
    """The ``forkserver`` context, its server told to import the package first.

    One server serves the process: the modules count only when this call comes
    before the server's start (the first pool or local Dask cluster of the
    process); ``extra`` names further modules to import there.  ``__main__`` is
    imported only when it is a file, as for any ``forkserver`` worker.
    """
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["__main__", "olsbayes._forkserver", *extra])
    return ctx


class _LocalPool:
    """A ``ProcessPoolExecutor`` started in the background while the caller works.

    Starting the pool (the fork server importing the package, then the first
    worker) takes seconds; a helper thread does it while :meth:`wait_first` runs
    queued calls in the calling process.  Once the pool runs, calls go to it, and
    until its first result the caller keeps running calls: one it can take back
    from the pool, else the oldest pending one (whose pool copy then runs twice).
    """

    def __init__(self, n_workers: int):
        ctx = _forkserver()
        self.pool = cf.ProcessPoolExecutor(max_workers=n_workers, mp_context=ctx,
                                           initializer=_end_with, initargs=(os.getpid(),))
        self.ready = threading.Event()
        self.delivered = False
        threading.Thread(target=self._start, name="olsbayes-study-pool-start",
                         daemon=True).start()

    def _start(self) -> None:
        try:
            self.pool.submit(os.getpid).result()
        except BaseException:  # noqa: BLE001 - a broken pool reports through the calls
            pass
        finally:
            self.ready.set()

    def submit(self, fn: Callable, *args: Any) -> _PoolFuture:
        """A call for the pool (handed over now if the pool runs)."""
        fut = _PoolFuture(fn, args)
        if self.ready.is_set():
            fut.hand_to(self.pool)
        return fut

    def wait_first(self, pending: list[_PoolFuture]) -> tuple[list, list]:
        """At least one of ``pending`` done, run here while the pool is not delivering."""
        pick = None
        if not self.ready.is_set():
            pick = next((f for f in pending if f.inner is None and not f.settled), None)
        if pick is None:
            self.ready.wait()
            for f in pending:
                f.hand_to(self.pool)
            pick = next((f for f in pending if f.settled), None)
        if pick is None and not self.delivered:
            done, _ = cf.wait([f.inner for f in pending], timeout=0,
                              return_when=cf.FIRST_COMPLETED)
            if not done:  # the latest call the pool has not started, else the oldest
                pick = next((f for f in reversed(pending) if f.inner.cancel()), pending[0])
        if pick is not None:
            if not pick.settled:
                pick.run_here()
            return [pick], [f for f in pending if f is not pick]
        done, _ = cf.wait([f.inner for f in pending], return_when=cf.FIRST_COMPLETED)
        self.delivered = True
        return ([f for f in pending if f.inner in done],
                [f for f in pending if f.inner not in done])

    def close(self) -> None:
        """Stop the pool without waiting for calls whose results are no longer needed."""
        self.pool.shutdown(wait=False, cancel_futures=True)


class Backend:
    """Uniform face of an executor.

    Attributes
    ----------
    name : str
        ``"serial"``, ``"threads"``, ``"processes"``, ``"dask"`` or ``"executor"``.
    n_workers : int
        Parallel slots (used to size chunks and the in-flight window).
    chunks_per_worker : int
        Default number of chunks per slot: fewer, larger chunks where a task costs
        more to dispatch (a Dask task costs more than a local pool's;
        ``benchmarks/study_throughput.py`` measures both).
    """

    def __init__(self, name: str, n_workers: int, submit: Callable, kind: str,
                 closer: Callable[[], None] | None = None, chunks_per_worker: int = 8):
        self.name, self.n_workers = name, max(1, int(n_workers))
        self.chunks_per_worker = int(chunks_per_worker)
        self._submit, self._kind, self._closer = submit, kind, closer
        self._local: _LocalPool | None = None

    def submit(self, fn: Callable, *args: Any) -> Any:
        """Schedule ``fn(*args)``; return a future-like object with ``result()``."""
        return self._submit(fn, *args)

    def wait_first(self, pending: list) -> tuple[list, list]:
        """Block until at least one of ``pending`` is done; return (done, still pending)."""
        if self._local is not None:
            return self._local.wait_first(pending)
        if self._kind == "cf" or (
            self._kind == "any" and all(isinstance(f, cf.Future) for f in pending)
        ):
            done, _ = cf.wait(pending, return_when=cf.FIRST_COMPLETED)
        elif self._kind == "dask":
            from distributed import wait

            with pending[0].client.as_current():  # the futures' client, default or not
                done = wait(pending, return_when="FIRST_COMPLETED").done
        else:  # serial or foreign futures: in submission order
            return [pending[0]], pending[1:]
        ids = {id(f) for f in done}
        return [f for f in pending if id(f) in ids], [f for f in pending if id(f) not in ids]

    def close(self) -> None:
        """Shut down what this backend started (never a user's executor or client)."""
        if self._closer is not None:
            self._closer()
            self._closer = None


def _wait_for_exit(pid: int) -> None:
    """Block until process ``pid`` has ended (pidfd on Linux, else polling each second)."""
    try:
        fd = os.pidfd_open(pid)
    except (AttributeError, OSError):  # no pidfd here, or the process is already gone
        fd = None
    if fd is not None:
        select.select([fd], [], [])  # the pidfd turns readable when the process exits
        return
    while True:
        try:
            os.kill(pid, 0)
        except (ProcessLookupError, PermissionError):  # gone (or its pid reused by another user)
            return
        time.sleep(1.0)


def _end_with(parent: int) -> None:
    """Pool-worker initializer: exit as soon as the study's process ``parent`` dies.

    Without it, a study killed with ``kill -9`` leaves its pool workers behind:
    they finish their chunk for nobody, then wait forever on the task queue.
    """
    def watch() -> None:
        _wait_for_exit(parent)
        os._exit(1)

    threading.Thread(target=watch, name="olsbayes-study-parent-watch", daemon=True).start()


def _local_workers(workers: int | None) -> int:
    if workers is None:
        return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
            os.cpu_count() or 1)
    return integer("workers", workers, low=1)


def _is_dask_client(obj: object) -> bool:
    return type(obj).__module__.split(".")[0] == "distributed" and hasattr(obj, "submit")


def _dask_backend(client: Any, closer: Callable[[], None] | None) -> Backend:
    nthreads = sum(client.nthreads().values()) or 1

    def submit(fn: Callable, *args: Any) -> Any:
        return client.submit(fn, *args, pure=False)

    return Backend("dask", nthreads, submit, "dask", closer, chunks_per_worker=4)


def _start_dask(scheduler: str | None, workers: int | None) -> Backend:
    if importlib.util.find_spec("distributed") is None:  # pragma: no cover - environment
        raise InputError(
            "executor='dask' needs the optional dependency dask.distributed: "
            "pip install 'olsbayes[dask]'"
        )
    if scheduler is None:
        return _local_dask(_local_workers(workers))
    if not isinstance(scheduler, str) or not scheduler:
        raise InputError(f"scheduler must be an address such as 'tcp://host:8786'; "
                         f"got {_short(scheduler)}")
    from distributed import Client

    try:  # not the process's default client: a failed start must leave no global behind
        client = Client(scheduler, timeout="20s", set_as_default=False)
    except (OSError, ValueError, TypeError) as exc:  # unreachable, or not an address
        raise InputError(f"cannot reach the Dask scheduler at {scheduler!r}: {exc}") from None
    return _dask_backend(client, client.close)


def _local_dask(n_workers: int) -> Backend:
    """A ``LocalCluster`` of ``n_workers`` processes forked from the fork server.

    The server starts first (told to import the package and ``distributed``,
    before ``distributed`` can set its own list), so its imports run while this
    process imports ``distributed``.

    The cluster's servers run with Dask's housekeeping timers slowed: no
    statistical profiler (by default it samples each running task's stack every
    10 ms), the event-loop health tick every 1 s instead of 20 ms, the system
    monitor every 2 s and the workers' memory monitor every 1 s.  Each wake-up
    takes the GIL from the trials that run beside it; a study's trials are
    Python-heavy, so these timers cost a local cluster a sizeable share of its
    throughput (``benchmarks/study_throughput.py``).  Only this cluster is
    affected (a user's client or scheduler keeps its own settings); its
    dashboard then shows no task profiles.
    """
    _forkserver("distributed")
    forkserver.ensure_running()
    import dask
    from distributed import Client, LocalCluster

    with dask.config.set({"distributed.worker.multiprocessing-method": "forkserver",
                          "distributed.worker.profile.enabled": False,
                          "distributed.admin.tick.interval": "1s",
                          "distributed.admin.system-monitor.interval": "2s",
                          "distributed.worker.memory.monitor-interval": "1s"}):
        cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1,
                               processes=True, dashboard_address=":0")
    client = Client(cluster, set_as_default=False)

    def closer() -> None:
        client.close()
        cluster.close()

    return _dask_backend(client, closer)


def make_backend(executor: object = "processes", *, workers: int | None = None,
                 scheduler: str | None = None) -> Backend:
    """Build the backend for ``executor``.

    Parameters
    ----------
    executor : str, distributed.Client or concurrent.futures.Executor-like
        ``"serial"`` (in this process, in order), ``"threads"``, ``"processes"``
        (a local ``ProcessPoolExecutor``, forkserver start; the fork server
        preloads the package -- this sets its preload list, which takes effect
        if it has not started yet), ``"dask"`` (a client
        to ``scheduler``, or, when no scheduler is given, a fresh ``LocalCluster``
        of ``workers`` processes forked from the same fork server), a
        ``distributed.Client`` (e.g. connected to a dask-jobqueue cluster), or any
        object with ``submit(fn, *args)`` returning futures with ``result()``.
        Objects passed in are never shut down here.
    workers : int, optional
        Pool size for ``"threads"``, ``"processes"`` and a local Dask cluster;
        default the number of usable cores.
    scheduler : str, optional
        Dask scheduler address (only with ``executor="dask"``).
    """
    if scheduler is not None and executor != "dask":
        raise InputError(f"scheduler is only used with executor='dask'; got executor={executor!r}")
    if isinstance(executor, str):
        if executor == "serial":
            return Backend("serial", 1, lambda fn, *args: _Deferred(fn, args), "serial")
        if executor == "threads":
            n = _local_workers(workers)
            pool = cf.ThreadPoolExecutor(max_workers=n)
            return Backend("threads", n, pool.submit, "cf", pool.shutdown)
        if executor == "processes":
            n = _local_workers(workers)
            local = _LocalPool(n)
            backend = Backend("processes", n, local.submit, "pool", local.close)
            backend._local = local
            return backend
        if executor == "dask":
            return _start_dask(scheduler, workers)
        raise InputError(f"executor must be one of {EXECUTORS}, a distributed.Client or an "
                         f"object with a submit() method; got {executor!r}")
    if _is_dask_client(executor):
        return _dask_backend(executor, None)
    if callable(getattr(executor, "submit", None)):
        n = getattr(executor, "_max_workers", None) or _local_workers(workers)
        return Backend("executor", n, executor.submit, "any")
    raise InputError(f"executor must be one of {EXECUTORS}, a distributed.Client or an object "
                     f"with a submit() method; got {_short(executor)}")
