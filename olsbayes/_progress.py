"""Feedback on long calls: a tqdm bar or status line on stderr, shown only when a call lasts.

Every call of the package that can run longer than a few seconds -- the posterior
sampler, nested sampling, importance sampling inside ``select_k``, the imaging
samplers, studies -- takes ``progress`` (True by default; the command line's
``--quiet`` turns it off) and reports through :func:`progress_bar`.  A bar appears
only after :data:`DELAY` seconds, so quick calls print nothing; it appears then
even if nothing was counted yet, so a call's set-up and its last assembly, inside
the bar's ``with`` block, are not silent either.
"""

from __future__ import annotations

import functools
import sys
import threading
from typing import Any

__all__ = ["progress_bar", "DELAY"]

#: Seconds a call runs before its bar is drawn.
DELAY = 2.0


def progress_bar(*, enabled: bool, desc: str, unit: str, total: int | None = None,
                 initial: int = 0) -> Any:
    """A tqdm bar on stderr (a no-op object when ``enabled`` is False).

    Parameters
    ----------
    enabled : bool
        Show it (after :data:`DELAY` seconds).
    desc : str
        What runs, e.g. ``"posterior"``.
    unit : str
        What is counted, e.g. ``"step"``.
    total : int, optional
        The count at the end, when it is known; None shows a counter and rate, with
        the progress towards the stopping rule in the status (``set_postfix_str``).
    initial : int
        Count already done (a resumed run).
    """
    return _bar_class()(total=total, initial=initial, desc=desc, unit=unit,
                        disable=not enabled, delay=DELAY, leave=False, file=sys.stderr,
                        dynamic_ncols=True)


@functools.cache
def _bar_class() -> type:
    """tqdm whose status changes wait for ``delay`` like its counts do.

    tqdm's ``set_postfix_str`` and ``set_description`` redraw the bar at once, so a
    call that finished in a fraction of a second but set a status printed a bar all
    the same; here a redraw before ``start_t + delay`` is skipped (the next one after
    it shows the latest status).  tqdm draws a delayed bar only on an update after
    the delay, so a bar whose counts have not moved (a call still setting up, or
    assembling its result after the last count) would stay hidden however long it
    lasts; here a timer thread draws it once the delay has passed, unless the bar
    was closed first.
    """
    from tqdm import tqdm

    class _DelayedBar(tqdm):
        def __init__(self, *args: Any, **kwargs: Any):
            self._woken = threading.Lock()  # held while the timer draws, and by close()
            self._wake = None
            super().__init__(*args, **kwargs)
            if not self.disable and self.delay > 0:
                # a little after the delay, so that refresh() below does not skip it
                self._wake = threading.Timer(self.delay + 0.05, self._draw)
                self._wake.daemon = True
                self._wake.start()

        def _draw(self) -> None:
            with self._woken:
                if not self.disable:
                    self.refresh()

        def refresh(self, nolock: bool = False, lock_args: Any = None) -> Any:
            start = getattr(self, "start_t", None)  # None: disabled, or still in __init__
            if start is not None and self._time() < start + self.delay:
                return False
            return super().refresh(nolock=nolock, lock_args=lock_args)

        def close(self) -> None:
            if self._wake is not None:
                self._wake.cancel()
            with self._woken:  # a draw under way ends before the bar is cleared
                super().close()

    return _DelayedBar
