"""Feedback on long calls: a tqdm bar or status line on stderr, shown only when a call lasts.

Every call of the package that can run longer than a few seconds -- the posterior
sampler, nested sampling, importance sampling inside ``select_k``, the imaging
samplers, studies -- takes ``progress`` (True by default; the command line's
``--quiet`` turns it off) and reports through :func:`progress_bar`.  A bar appears
only after :data:`DELAY` seconds, so quick calls print nothing.
"""

from __future__ import annotations

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
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit=unit, disable=not enabled,
                delay=DELAY, leave=False, file=sys.stderr, dynamic_ncols=True)
