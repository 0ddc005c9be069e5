"""Imaging cost whatever the BLAS thread setting, on an idle and on a busy machine.

Goal: the time of ``image`` on Fig. 2 does not depend on the BLAS thread setting
(``image`` limits BLAS to one thread inside, with threadpoolctl): the default
thread setting -- one BLAS thread per core, which oversubscribes a busy machine
-- costs no more than the setting pinned to one thread.

Each measurement is a new process (BLAS reads its thread count as numpy loads),
either with ``OPENBLAS_NUM_THREADS`` / ``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS``
= 1 or with them unset, alternating over ``--rounds`` rounds; "busy" runs the
same beside one process per core that spins for the whole measurement.  In
each, the Fig. 2 problem (304 directions, the 15 x 20 sphere, linspace sensors,
sigma 0.01) is imaged ``--calls`` times after one untimed call: the bounded
mode (``ImageOptions(n_samples=0)``) and a short sampled run (4 chains of 20
draws).  Printed: median CPU and wall seconds per call, and the ratio default /
one thread of the medians over rounds; goal met where every ratio is at most
``--tolerance`` (1.25: the spread of repeated runs on a shared 2-core machine).

Run ``python benchmarks/imaging_threads.py`` (~3 min).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
CALLS = {"mode": {"n_samples": 0}, "sampled": {"n_samples": 20, "n_burn": 10}}


def child(n_calls: int) -> None:
    """Time the calls in this process; print {call: (median CPU, median wall)} as JSON."""
    import warnings

    import numpy as np

    import olsbayes as ob
    from olsbayes.imaging.olss import SIGMA, fig2_sphere, olss_bitmap, olss_directions

    # the Fig. 2 problem as benchmarks/imaging_mixing.py builds it (which is not imported
    # here: it pins BLAS to one thread as it loads)
    model = ob.Model(fig2_sphere("linspace"), SIGMA)
    dirs = olss_directions("endpoints")
    y = model.simulate(np.column_stack([dirs, olss_bitmap().ravel()]).ravel(), rng=1)
    import threadpoolctl

    blas = threadpoolctl.threadpool_info()
    out = {"blas_threads": max((d["num_threads"] for d in blas if d["user_api"] == "blas"),
                               default=0)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, kw in CALLS.items():
            opts = ob.ImageOptions(**kw)
            ob.image(model, y, dirs, options=opts, rng=0, progress=False)  # loads, untimed
            cpu, wall = [], []
            for i in range(n_calls):
                c0, w0 = time.process_time(), time.perf_counter()
                ob.image(model, y, dirs, options=opts, rng=i, progress=False)
                cpu.append(time.process_time() - c0)
                wall.append(time.perf_counter() - w0)
            out[name] = (float(np.median(cpu)), float(np.median(wall)))
    print(json.dumps(out))


def measure(pinned: bool, busy: bool, n_calls: int) -> dict:
    """One child process's timings, BLAS pinned to one thread or not, beside spinners."""
    env = {k: v for k, v in os.environ.items() if k not in _THREAD_VARS}
    if pinned:
        env.update(dict.fromkeys(_THREAD_VARS, "1"))
    spin = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
            for _ in range(os.cpu_count() or 1)] if busy else []
    try:
        here = Path(__file__).resolve()
        proc = subprocess.run([sys.executable, str(here), "--child", "--calls", str(n_calls)],
                              env=env, cwd=here.parent, capture_output=True, text=True,
                              check=True)
    finally:
        for p in spin:
            p.kill()
            p.wait()
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--calls", type=int, default=5, help="timed calls per process")
    p.add_argument("--tolerance", type=float, default=1.25)
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.child:
        child(a.calls)
        return 0
    import numpy as np

    ok = True
    for busy in (False, True):
        runs: dict[bool, list[dict]] = {True: [], False: []}
        for r in range(a.rounds):
            for pinned in ((True, False) if r % 2 == 0 else (False, True)):
                runs[pinned].append(measure(pinned, busy, a.calls))
        for name in CALLS:
            med = {pinned: np.median([[v[name][0], v[name][1]] for v in runs[pinned]], axis=0)
                   for pinned in runs}
            threads = {pinned: runs[pinned][0]["blas_threads"] for pinned in runs}
            ratio = med[False] / med[True]
            met = bool(np.all(ratio <= a.tolerance))
            ok &= met
            print(f"{'busy' if busy else 'idle':4s} {name:8s} one BLAS thread: CPU "
                  f"{med[True][0]:6.3f} s, wall {med[True][1]:6.3f} s | default "
                  f"({threads[False]} BLAS threads): CPU "
                  f"{med[False][0]:6.3f} s, wall {med[False][1]:6.3f} s | ratio CPU "
                  f"{ratio[0]:.2f}, wall {ratio[1]:.2f} (goal <= {a.tolerance:g}): "
                  f"{'met' if met else 'NOT met'}", flush=True)
    print(f"imaging independent of the BLAS thread setting: {'met' if ok else 'NOT met'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
