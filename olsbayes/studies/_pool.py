"""The local process pool of a study: started in the background, helped by the caller.

Its workers fork from a server process that has imported the package once
(:mod:`olsbayes._forkserver`); until the first worker has delivered a call the
caller runs queued calls itself, so a small study never waits for the pool, and the
pool gets the calls still queued the moment it runs.  Calls are deterministic, so
where one ran never changes its result.  Workers exit when the study's process dies.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import select
import threading
import time
from collections.abc import Callable
from typing import Any

from ..errors import InputError

__all__ = ["LocalPool", "PoolFuture", "forkserver_context", "submit_safely"]


class _CancelSafeFuture(cf.Future):
    """A process-pool future that may be cancelled while its pool breaks.

    When a worker dies, Python 3.11's pool fails every pending future from its
    manager thread; on one the caller cancelled meanwhile, ``set_exception``
    raises ``InvalidStateError``, which ends that thread before the remaining
    futures are failed: they then never finish, and a wait on them never
    returns.  Python 3.12 ignores the error there (CPython gh-107219); this
    class does the same for the futures of the study's pool, on any version.
    """

    def set_exception(self, exception: BaseException | None) -> None:
        try:
            super().set_exception(exception)
        except cf.InvalidStateError:
            if not self.cancelled():
                raise


def submit_safely(pool: cf.ProcessPoolExecutor, fn: Callable, *args: Any) -> cf.Future:
    """``pool.submit(fn, *args)``, its future safe to cancel while the pool breaks."""
    fut = pool.submit(fn, *args)
    if type(fut) is cf.Future:  # another pool's own future class is left as it is
        fut.__class__ = _CancelSafeFuture  # a subclass adding no state: the object is unchanged
    return fut


class PoolFuture:
    """A call for the local pool that the study's own process may run instead.

    ``inner`` is the pool's future once the call has been handed to the pool
    (None before: the pool is still starting).  A call is either handed over or
    claimed by this process (:meth:`claim`, then :meth:`run_here`), never both:
    the two happen under one lock shared by the calls of a pool.
    """

    def __init__(self, fn: Callable, args: tuple, lock: threading.Lock | None = None):
        self.inner: cf.Future | None = None
        self._call = (fn, args)
        self._outcome: tuple[bool, Any] | None = None
        self._claimed = False
        self._lock = lock if lock is not None else threading.Lock()

    @property
    def settled(self) -> bool:
        """Whether the call ran here (or was cancelled before it reached the pool)."""
        return self._outcome is not None

    def claim(self) -> bool:
        """Reserve the call for this process; False if handed over or claimed already."""
        with self._lock:
            if self.inner is None and not self._claimed and self._outcome is None:
                self._claimed = True
                return True
            return False

    def hand_to(self, pool: cf.Executor) -> None:
        """Give the call to the pool unless it is claimed here, ran here or was cancelled."""
        with self._lock:
            if self.inner is None and not self._claimed and self._outcome is None:
                fn, args = self._call
                try:
                    self.inner = submit_safely(pool, fn, *args)
                except cf.process.BrokenProcessPool as exc:  # settled: result() says why
                    self._outcome = (False, _broken(exc))

    def run_here(self) -> None:
        """Run the call in this process (its exception, if any, is kept for result())."""
        fn, args = self._call
        try:
            self._outcome = (True, fn(*args))
        except Exception as exc:  # noqa: BLE001 - re-raised by result(), as the pool would
            self._outcome = (False, exc)

    def result(self) -> Any:
        """The call's value, or its exception raised here (run here if still unsent)."""
        if self._outcome is None and self.claim():
            self.run_here()
        if self._outcome is not None:
            ok, value = self._outcome
            if ok:
                return value
            raise value
        try:
            return self.inner.result()
        except cf.process.BrokenProcessPool as exc:
            raise _broken(exc) from None

    def cancel(self) -> bool:
        """Cancel the call if it has not started (here or in the pool)."""
        with self._lock:
            if self._outcome is not None or self._claimed:
                return False
            if self.inner is None:
                self._outcome = (False, cf.CancelledError())
                return True
        return self.inner.cancel()


def _broken(exc: BaseException) -> InputError:
    """The error a call of a broken pool raises, in one line."""
    return InputError(
        "the study's worker processes ended abruptly (killed, out of memory, or failing "
        "on start-up). Workers import the script that called run_study: a script must "
        "call it under `if __name__ == \"__main__\":`; or use executor='serial' or "
        f"'threads' ({exc})")


def forkserver_context(*extra: str) -> multiprocessing.context.BaseContext:
    """The ``forkserver`` context, its server told to import the package first.

    One server serves the process: the modules count only when this call comes
    before the server's start (the first pool or local Dask cluster of the
    process); ``extra`` names further modules to import there.  ``__main__`` is
    imported only when it is a file, as for any ``forkserver`` worker.
    """
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["__main__", "olsbayes._forkserver", *extra])
    return ctx


class LocalPool:
    """A ``ProcessPoolExecutor`` started in the background while the caller works.

    Starting the pool (the fork server importing the package, then the first
    worker) takes from tens of ms to seconds; a helper thread does it while
    :meth:`wait_first` runs queued calls in the calling process, and hands the pool
    every call still queued the moment it runs, so its workers never wait for the
    caller to finish a call.  Until the pool's first result the caller keeps
    running calls: one it can take back from the pool, else the oldest pending one
    (whose pool copy then runs twice).  The start waits ``delay`` seconds first,
    and does not happen if the pool is closed by then: until it starts, the caller
    runs every call.
    """

    def __init__(self, n_workers: int, delay: float = 0.0):
        self.pool = cf.ProcessPoolExecutor(max_workers=n_workers, mp_context=forkserver_context(),
                                           initializer=_end_with, initargs=(os.getpid(),))
        self.ready = threading.Event()
        self.delivered = False
        self._closed = threading.Event()
        self._lock = threading.Lock()  # shared by the calls: handed over or run here, not both
        self._queued: list[PoolFuture] = []
        threading.Thread(target=self._start, args=(delay,), name="olsbayes-study-pool-start",
                         daemon=True).start()

    def _start(self, delay: float) -> None:
        """Start the pool after ``delay`` seconds unless closed; hand it the queued calls."""
        if delay > 0 and self._closed.wait(delay):
            return  # nothing was handed over: no one waits for ready
        try:
            submit_safely(self.pool, os.getpid).result()
        except BaseException:  # noqa: BLE001 - a broken pool reports through the calls
            pass
        with self._lock:
            queued, self._queued = self._queued, []
            self.ready.set()
        try:
            for f in queued:
                if self._closed.is_set():
                    break
                f.hand_to(self.pool)
        except RuntimeError:  # closed meanwhile: the pool takes no more calls
            pass

    def submit(self, fn: Callable, *args: Any) -> PoolFuture:
        """A call for the pool (handed over now if the pool runs)."""
        fut = PoolFuture(fn, args, self._lock)
        with self._lock:
            queued = not self.ready.is_set()
            if queued:
                self._queued.append(fut)
        if not queued:
            fut.hand_to(self.pool)
        return fut

    def wait_first(self, pending: list[PoolFuture]) -> tuple[list, list]:
        """At least one of ``pending`` done, run here while the pool is not delivering."""
        pick = None
        if not self.ready.is_set():
            pick = next((f for f in pending if f.claim()), None)
            with self._lock:  # the queue holds only calls the pool may still get
                self._queued = [f for f in self._queued if f is not pick]
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
        self._closed.set()
        self.pool.shutdown(wait=False, cancel_futures=True)


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
