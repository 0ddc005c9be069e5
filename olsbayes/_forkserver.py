"""What the process pool's fork server imports once, before it forks any worker.

Workers of ``executor="processes"`` (and of a local Dask cluster) fork from one
server process per study process; whatever the server has imported they start
with, instead of each importing numpy, scipy and the package anew.  The compiled
kernels' modules are imported too, but their machine code loads from numba's
cache on each kernel's first call, a cost each worker's first trial pays (the
measurements are in ``docs/performance.md``).  So once the workers the server
has forked are all gone (the study's pool or local Dask cluster has closed), it
runs a few small fits (:func:`load_cached`) in a thread at the lowest CPU
priority, and every worker it forks afterwards -- the next pool or cluster of the
study's process -- starts with those kernels loaded.
A fork that comes meanwhile waits for that thread: a fork while another thread
holds a lock (the import lock, numba's compiler lock) could leave the child
waiting forever.  It only loads: a kernel missing from numba's cache stops the
load rather than being compiled there.  Where the server's children or a
thread's priority cannot be seen or set (outside Linux) it loads nothing; nor
does this module do anything in a process that is not the fork server.
"""

from __future__ import annotations

import os
import sys
import threading

# what the fast trials load on use: scipy.linalg (numba's LAPACK calls in the kernels)
# and the special functions of the fits' checks; forked workers start with them
# instead of each importing them anew.  scipy.optimize (about 0.3 s, a quarter of the
# server's start, hence of a process's first pool) is left to the trials that use it:
# the multistart estimator imports it in each worker on its first trial.
import scipy.linalg  # noqa: F401
import scipy.special  # noqa: F401

import olsbayes  # noqa: F401  (the package, with numpy; scipy loads on use)
import olsbayes.ml._numba.escalate  # noqa: F401
import olsbayes.ml._numba.exact  # noqa: F401
import olsbayes.ml._numba.fit  # noqa: F401
import olsbayes.ml._numba.lm  # noqa: F401
import olsbayes.ml._numba.refine  # noqa: F401
import olsbayes.ml._numba.rivals  # noqa: F401
import olsbayes.ml._numba.search  # noqa: F401
import olsbayes.ml._numba.tuples  # noqa: F401
import olsbayes.ml.fast  # noqa: F401
import olsbayes.studies._work  # noqa: F401
import olsbayes.studies.estimators  # noqa: F401
import olsbayes.studies.trials  # noqa: F401

__all__ = ["IDLE", "load_cached"]

#: Seconds between the fork server's looks for children left (then it loads the kernels).
IDLE = 0.5


class _IdleLoad:
    """The server's fork hooks: load the kernels once, when it has no child left.

    A timer looks every :data:`IDLE` seconds whether the server still has children
    (a pool's or a Dask cluster's workers); once none is left it loads the kernels
    at the lowest CPU priority, so as not to compete with a study's own work.
    """

    def __init__(self) -> None:
        self.pid = os.getpid()
        self.timer: threading.Timer | None = None
        self.hold = False  # a fork is under way: schedule nothing
        self.done = False

    def before_fork(self) -> None:
        """Stop the timer, or wait for a running load: no other thread at a fork."""
        if os.getpid() != self.pid:
            return
        self.hold = True
        while self.timer is not None and self.timer.is_alive():
            timer = self.timer
            timer.cancel()
            timer.join()

    def after_fork(self) -> None:
        """In the server after each fork: look again for idleness from now on."""
        if os.getpid() == self.pid and not self.done:
            self.hold = False
            self._schedule()

    def _schedule(self) -> None:
        self.timer = threading.Timer(IDLE, self._tick)
        self.timer.daemon = True
        self.timer.start()

    def _tick(self) -> None:
        if self.hold or self.done:
            return
        busy = _has_children()
        if busy:
            self._schedule()
            return
        self.done = True
        if busy is None:  # children cannot be seen here: never compete with them
            return
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)
        except (AttributeError, OSError):
            return
        load_cached()


class _WouldCompile(Exception):
    """A kernel is not in numba's cache: loading it would mean compiling it."""


def load_cached() -> bool:
    """Run the small fast fits of :func:`olsbayes.ml.warmup.fast_fits` if their kernels are cached.

    A kernel missing from the cache is not compiled here (tens of seconds, during
    which a fork would have to wait): the first compile aborts the load, and the
    workers compile what they use, as without it.  Returns whether it loaded all.
    """
    from numba.core import event

    from olsbayes._notice import silenced
    from olsbayes.ml.warmup import fast_fits

    class Refuse(event.Listener):
        def on_start(self, ev) -> None:
            if getattr(ev.data["dispatcher"].py_func, "__module__", "").startswith("olsbayes."):
                raise _WouldCompile

        def on_end(self, ev) -> None:
            pass

    listener = Refuse()
    event.register("numba:compile", listener)
    try:
        with silenced():
            fast_fits()
        return True
    except Exception:  # noqa: BLE001 - an optimisation only: workers load on first use
        return False
    finally:
        event.unregister("numba:compile", listener)


def _has_children() -> bool | None:
    """Whether the server has child processes (None where Linux's /proc cannot say)."""
    try:
        with open(f"/proc/self/task/{os.getpid()}/children") as f:
            return bool(f.read().split())
    except OSError:
        return None


def _in_fork_server() -> bool:
    """Whether this module is being imported by the fork server's preload."""
    from multiprocessing import forkserver

    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_code is forkserver.main.__code__:
            return True
        frame = frame.f_back
    return False


_IDLE_LOAD = _IdleLoad() if _in_fork_server() else None
if _IDLE_LOAD is not None:
    os.register_at_fork(before=_IDLE_LOAD.before_fork, after_in_parent=_IDLE_LOAD.after_fork)
