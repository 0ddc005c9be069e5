"""Feedback on long calls: a tqdm bar or status line on stderr, shown only when a call lasts.

Every call of the package that can run longer than a few seconds -- the posterior
sampler, nested sampling, importance sampling inside ``select_k``, the imaging
samplers, studies -- takes ``progress`` (True by default; the command line's
``--quiet`` turns it off) and reports through :func:`progress_bar`.  A bar appears
only after :data:`DELAY` seconds, so quick calls print nothing.
"""

from __future__ import annotations

import functools
import sys
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
    it shows the latest status).
    """
    from tqdm import tqdm

    class _DelayedBar(tqdm):
        def refresh(self, nolock: bool = False, lock_args: Any = None) -> Any:
            start = getattr(self, "start_t", None)  # None: disabled, or still in __init__
            if start is not None and self._time() < start + self.delay:
                return False
            return super().refresh(nolock=nolock, lock_args=lock_args)

    return _DelayedBar
