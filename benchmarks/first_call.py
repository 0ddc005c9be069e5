"""First use of a fresh install: ``olsbayes compile``, then ``olsbayes demo`` twice.

Goals: a fresh install's first ``olsbayes demo`` costs at most 1.5x the CPU of its
second run, and no call blocks for more than ~5 s without saying what it is doing.

Every command runs in a new process with an empty numba cache folder of its own
(``NUMBA_CACHE_DIR``, a new temporary folder: what a new machine, container or CI
job starts with) and a new working folder.  CPU is the child's user + system time
(``resource.getrusage(RUSAGE_CHILDREN)``), wall time as a user waits.  Rows:

1. **The README's route**: ``olsbayes compile`` (once per machine), then the first
   and the second ``olsbayes demo``; the goal's ratio is first / second demo CPU, and
   the first demo's longest unannounced silence (below) is judged too.
2. **Without** ``olsbayes compile`` (a new cache again): the first demo compiles
   what it needs; printed its CPU, when its first line on stderr came (the
   compile notice) and its longest *unannounced* silence -- a stretch of more
   than 5 s wall with no output whose last output was not on stderr (a status
   line, a progress bar or a notice says what is running; a table on stdout
   does not).  Goal met if no such silence exceeds 5 s.

Run ``python benchmarks/first_call.py`` (~3 min CPU; ``--rounds 2`` runs the
README's route twice, each on a new cache; ``--parts 2`` the second row alone).
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

#: Longest stretch (wall s) a call may run without saying what it is doing.
SILENCE = 5.0


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _olsbayes() -> list[str]:
    """The command line of this interpreter's installed package."""
    return [sys.executable, "-m", "olsbayes"]


def run(args: list[str], cache: Path, cwd: Path) -> dict:
    """Run ``olsbayes <args>``: CPU, wall, return code and timed output chunks."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), MPLBACKEND="Agg")
    events: list[tuple[float, str, bytes]] = []  # (wall s since start, stream, bytes)
    lock = threading.Lock()
    c0, t0 = _children_cpu(), time.monotonic()
    proc = subprocess.Popen(_olsbayes() + args, cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)

    def read(stream, name):
        for chunk in iter(lambda: os.read(stream.fileno(), 4096), b""):
            with lock:
                events.append((time.monotonic() - t0, name, chunk))

    readers = [threading.Thread(target=read, args=(s, n), daemon=True)
               for s, n in ((proc.stdout, "out"), (proc.stderr, "err"))]
    for r in readers:
        r.start()
    rc = proc.wait()
    for r in readers:
        r.join()
    wall = time.monotonic() - t0
    return {"cpu": _children_cpu() - c0, "wall": wall, "rc": rc,
            "events": sorted(events, key=lambda e: e[0])}


def silences(res: dict) -> tuple[float | None, float, float, str]:
    """The first stderr line's time and the longest unannounced silence.

    Returns (wall s to the first stderr output or None, the silence's length in s, its
    start in s, the last line printed before it).  A silence is the wall time between
    two outputs (or from the start, or to the end); it is announced when the output
    before it was on stderr.
    """
    ev = res["events"]
    first_err = next((t for t, name, _ in ev if name == "err"), None)
    worst, at, before = 0.0, 0.0, ""
    last_t, last_name, last_text = 0.0, None, b""
    for t, name, chunk in ev + [(res["wall"], "end", b"")]:
        if last_name != "err" and t - last_t > worst:
            worst, at = t - last_t, last_t
            before = last_text.decode(errors="replace").strip().splitlines()[-1:] or [""]
            before = before[0]
        last_t, last_name, last_text = t, name, chunk
    return first_err, worst, at, before


def said(res: dict, n: int = 6) -> list[str]:
    """The first ``n`` status lines (``olsbayes: ...``) the command printed on stderr."""
    text = b"".join(c for _, name, c in res["events"] if name == "err").decode(errors="replace")
    return [ln for ln in text.splitlines() if ln.startswith("olsbayes:")][:n]


def _silence_line(res: dict) -> tuple[bool, str]:
    """Whether the longest unannounced silence is within :data:`SILENCE`, and a report."""
    first_err, worst, at, before = silences(res)
    met = res["rc"] == 0 and worst <= SILENCE
    first = "none" if first_err is None else f"{first_err:.1f} s"
    return met, (f"first line on stderr after {first}; longest unannounced silence "
                 f"{worst:.1f} s (goal <= {SILENCE:g}): {'met' if met else 'NOT met'}, "
                 f"from {at:.1f} s, after {before[:70]!r}")


def readme_route(root: Path, i: int) -> bool:
    """Row 1: olsbayes compile, then the first and the second demo (new cache)."""
    cache, work = root / f"cache{i}", root / f"work{i}"
    cache.mkdir()
    work.mkdir()
    comp, first = run(["compile"], cache, work), run(["demo"], cache, work)
    second = run(["demo"], cache, work)
    ratio = first["cpu"] / second["cpu"]
    met = ratio <= 1.5 and comp["rc"] == first["rc"] == second["rc"] == 0
    quiet, text = _silence_line(first)
    print(f"1. README route, round {i + 1}: olsbayes compile {comp['cpu']:6.1f} s CPU "
          f"({comp['wall']:.1f} s wall, rc {comp['rc']}); demo first {first['cpu']:5.2f} s, "
          f"second {second['cpu']:5.2f} s CPU; first / second {ratio:.2f} (goal <= 1.5): "
          f"{'met' if met else 'NOT met'}\n   first demo: {text}")
    for line in said(comp, 1):
        print(f"   compile said: {line}")
    return met and quiet


def cold_demo(root: Path) -> bool:
    """Row 2: the first demo of a new cache without olsbayes compile."""
    cache, work = root / "cold", root / "cold-work"
    cache.mkdir()
    work.mkdir()
    cold = run(["demo"], cache, work)
    met, text = _silence_line(cold)
    print(f"2. demo without olsbayes compile: {cold['cpu']:6.1f} s CPU ({cold['wall']:.1f} s "
          f"wall, rc {cold['rc']}); {text}")
    for line in said(cold):
        print(f"   it said: {line}")
    return met


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=1, help="README routes to run")
    p.add_argument("--parts", default="12", help="which rows to run, e.g. 2")
    a = p.parse_args(argv)
    root = Path(tempfile.mkdtemp(prefix="olsbayes-first-call-"))
    ok = True
    try:
        for i in range(a.rounds if "1" in a.parts else 0):
            ok &= readme_route(root, i)
        if "2" in a.parts:
            ok &= cold_demo(root)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    print(f"first call: {'met' if ok else 'NOT met'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
