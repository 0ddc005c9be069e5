"""Where chunks of trials run: in process, a local pool, Dask, or any Executor.

Every backend offers the same three operations -- ``submit(fn, *args)``,
``wait_first(pending)`` and ``close()`` -- so the runner keeps a bounded window
of chunks in flight and checkpoints each one as soon as it finishes.  Dask
(``distributed``) is an optional extra, imported only when it is used.

The local process pool (:mod:`._pool`) starts fast: its workers fork from a server process that
has imported the package once (:mod:`olsbayes._forkserver`), and until the first worker
has delivered a chunk the study's own process runs queued chunks itself, so a
small study never waits for the pool; a study starts its pool only after
:data:`POOL_START_DELAY` seconds of that, so one done sooner never starts it.
A fresh local Dask cluster forks its workers from the same server (which then
also imports ``distributed``, if it is the first to start it) instead of
spawning processes that import everything anew.
A chunk gives the same numbers wherever it runs (its trials' seeds are fixed).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import functools
import importlib.util
import os
import threading
from collections.abc import Callable
from multiprocessing import forkserver
from typing import Any

from .._notice import notice
from .._validation import _short, integer
from ..errors import InputError
from ._pool import LocalPool, forkserver_context, submit_safely
from ._script import unguarded_call

__all__ = ["Backend", "make_backend", "check_script_guard", "EXECUTORS", "POOL_START_DELAY"]

#: Executor names accepted by :func:`make_backend`.
EXECUTORS = ("serial", "threads", "processes", "dask")

#: Seconds a study runs chunks in its own process before its local pool starts
#: (``run_study``): a study done sooner -- a few dozen trials of a few ms --
#: never pays for starting workers (tens of ms), a longer one forgoes their help
#: for at most this long.
POOL_START_DELAY = 0.05


class _Deferred:
    """A future computed when its result is first asked for (serial backend)."""

    def __init__(self, fn: Callable, args: tuple):
        self._fn, self._args = fn, args

    def result(self) -> Any:
        return self._fn(*self._args)

    def cancel(self) -> bool:
        return True


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
        self._local: LocalPool | None = None

    @property
    def alone(self) -> bool:
        """Whether this process runs every call for now (its local pool has not started)."""
        return self._local is not None and not self._local.ready.is_set()

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


def check_script_guard(executor: object, scheduler: str | None = None) -> None:
    """Refuse a local pool or Dask cluster started by unguarded top-level code of a script.

    Their workers fork from a server that imports the running script, which would
    start the study again there (:mod:`._script`).  Other executors, and a Dask
    scheduler elsewhere, never import it.

    Raises
    ------
    InputError
        ``executor`` is ``"processes"``, or ``"dask"`` with no ``scheduler``, and
        the call comes from a top-level statement of the running script outside
        ``if __name__ == "__main__":``.
    """
    local = isinstance(executor, str) and (
        executor == "processes" or (executor == "dask" and scheduler is None))
    where = unguarded_call() if local else None
    if where is not None:
        path, line = where
        raise InputError(
            f"executor={executor!r} starts worker processes that import the script "
            f"{path!r}, whose line {line} starts this study at the top level: put the "
            "study under `if __name__ == \"__main__\":`, or use executor='serial' or 'threads'")


def _start_dask(scheduler: str | None, workers: int | None) -> Backend:
    if importlib.util.find_spec("distributed") is None:  # pragma: no cover - environment
        raise InputError(
            "executor='dask' needs the optional dependency dask.distributed: "
            "pip install 'olsbayes[dask]'"
        )
    if scheduler is None:
        n = _local_workers(workers)
        check_script_guard("dask")
        return _local_dask(n)
    if not isinstance(scheduler, str) or not scheduler:
        raise InputError(f"scheduler must be an address such as 'tcp://host:8786'; "
                         f"got {_short(scheduler)}")
    client = _connect(scheduler)
    return _dask_backend(client, client.close)


def _connect(scheduler: str, *, timeout: int = 20, notice_after: float = 2.0) -> Any:
    """A ``distributed.Client`` of the scheduler at ``scheduler`` (not the default client).

    Connecting gives up after ``timeout`` seconds; a connection still pending
    after ``notice_after`` seconds says so in one line on stderr.  A client whose
    start fails (unreachable, or not an address: ``'host'`` without a port, an
    unknown scheme) is closed here at once.  Left to the garbage collector, it
    would wait twice its timeout when the process exits -- 40 s after the error
    was reported, by default -- and then print a traceback.
    """
    from distributed import Client

    waiting = threading.Timer(notice_after, notice, (
        f"connecting to the Dask scheduler at {scheduler!r} (gives up after {timeout} s) ...",))
    waiting.daemon = True
    waiting.start()
    client = Client.__new__(Client)  # held before __init__ runs, so a failed start is closed
    try:  # not the process's default client: a failed start must leave no global behind
        client.__init__(scheduler, timeout=f"{timeout}s", set_as_default=False)
    except BaseException as exc:
        with contextlib.suppress(Exception):  # failed before it had a loop: nothing to close
            client.close(timeout=1)
        if isinstance(exc, (OSError, ValueError, TypeError, ImportError)):
            raise InputError(f"cannot reach the Dask scheduler at {scheduler!r}: {exc}") from None
        raise
    finally:
        waiting.cancel()
    return client


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
    forkserver_context("distributed")
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
                 scheduler: str | None = None, start_delay: float = 0.0) -> Backend:
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
    start_delay : float
        Seconds before ``"processes"`` starts its pool; until then, and until the
        pool delivers, ``wait_first`` runs the calls in this process.

    Raises
    ------
    InputError
        An unknown executor, a scheduler without ``"dask"``, or a local pool or
        Dask cluster asked for by a top-level statement of the running script
        outside ``if __name__ == "__main__":`` (:func:`check_script_guard`).
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
            check_script_guard("processes")
            local = LocalPool(n, start_delay)
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
        submit = (functools.partial(submit_safely, executor)
                  if isinstance(executor, cf.ProcessPoolExecutor) else executor.submit)
        return Backend("executor", n, submit, "any")
    raise InputError(f"executor must be one of {EXECUTORS}, a distributed.Client or an object "
                     f"with a submit() method; got {_short(executor)}")
