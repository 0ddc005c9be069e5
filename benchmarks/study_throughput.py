"""Throughput of ``run_study`` on one machine: serial vs a local pool vs Dask, in one run.

The workload is ML trials (:func:`olsbayes.studies.estimators.ring_estimate`,
estimator ``Estimator("fast")``: simulate a ring scene, fit it with ``fit_ml``,
score it against the CRLB).  Measured side by side:

* trials per second with ``executor="serial"``, a 2-worker local process pool
  and a 2-worker Dask ``LocalCluster`` (processes), each warm (executor started
  and workers imported before the clock starts) -- targets: pool / serial >= 1.6,
  Dask / pool >= 0.8.  Serial runs in a warmed process of its own, never beside a
  live executor (whose threads would slow it and inflate every ratio), and the pool
  never beside a live Dask cluster (whose idle scheduler, client and workers take
  about 12 % of one core): each round starts and warms a cluster for its Dask run;
* per round, the CPU time per trial of the study's own processes (main process
  plus workers, from /proc) and the fraction of the cores left idle: on a machine
  shared with other jobs the wall-clock ratios measure contention as much as the
  executors, while the CPU cost per trial shows what each executor adds and gives
  the best ratio 2 idle cores would allow;
* the same with the executor started inside ``run_study`` (cold), each cold run next
  to a serial run of its own round (the goal uses the median of those ratios); for
  Dask also as the first study of a new process (which starts the fork server the
  workers fork from), against the warm serial run and against serial as a new
  process's first study (both load the kernels and import xarray once), and, as the
  baseline, on a cluster of Dask's default spawned workers, each importing
  everything anew;
* the runner's own cost per trial (seeds, chunk bookkeeping, stacking, the
  Dataset) next to a batched ML fit: ``run_study`` of ``Estimator("fast",
  batched=True)`` trials vs calling the trial function on the same rngs
  directly, and a no-op trial;
* the start of ``executor="processes"``: seconds until its pool has started
  (first pool of the process, which starts the fork server, and a later one)
  and a small study (16 trials) on a new pool against serial, both run first in
  the process (serial before the pool runs, whose workers could slow it).

Goals (printed with "met"/"not met"): pool start <= 1 s; on the medium study
2 workers >= 1.7x serial and Dask (2 workers) >= 1.5x serial, as started by
``run_study`` ("cold") and on executors started beforehand ("warm").

Usage::

    python benchmarks/study_throughput.py            # quick
    python benchmarks/study_throughput.py --full     # more trials
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import contextlib
import multiprocessing
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from olsbayes.studies import Estimator, run_study, vectorized
from olsbayes.studies.estimators import ring_estimate
from olsbayes.studies.seeds import trial_rngs

__all__ = ["main"]

SETTINGS = {"n_sensors": 16, "sigma": 0.01, "n_sources": 2}
FAST, BATCHED = Estimator("fast"), Estimator("fast", batched=True)


@vectorized
def noop(settings, *, rngs):
    """A trial that does nothing: the runner's own cost."""
    return {"x": np.zeros(len(rngs))}


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def study(executor, n, estimator=FAST, trial=ring_estimate, chunk_size=None, **kw):
    return run_study(trial, {"estimator": [estimator]}, n, fixed=SETTINGS, executor=executor,
                     rng=1, chunk_size=chunk_size, progress=False, **kw)


def _cpu_ticks() -> tuple[int, int]:
    """(idle, total) jiffies of all CPUs from /proc/stat ((0, 0) elsewhere)."""
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:]]
    except OSError:
        return 0, 0
    return v[3] + v[4], sum(v[:8])


def _proc_cpu(pid: int) -> float:
    """CPU seconds (user + system) used so far by process ``pid`` (Linux /proc)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def measured(fn, worker_cpu) -> tuple[float, float, float]:
    """Run ``fn()``: wall seconds, CPU seconds (this process + ``worker_cpu()``, a
    callable summing the workers' CPU time) and the fraction of all cores idle."""
    i0, t0 = _cpu_ticks()
    c0, w0 = time.process_time(), worker_cpu()
    dt = timed(fn)
    cpu = time.process_time() - c0 + worker_cpu() - w0
    i1, t1 = _cpu_ticks()
    return dt, cpu, (i1 - i0) / (t1 - t0) if t1 > t0 else float("nan")


def _warm_one(_: int = 0) -> int:
    """Run one ML trial (imports the estimator stack); return the worker's pid."""
    ring_estimate({**SETTINGS, "estimator": FAST}, rngs=trial_rngs(9, 0, np.arange(1)))
    return os.getpid()


def _warm_pool(pool) -> set[int]:
    """Make every worker of the pool import the trial and run it once, so no timed
    round pays a worker's first import (seconds on a busy machine); the workers' pids."""
    pids: set[int] = set()
    for _ in range(20):
        pids |= set(pool.map(_warm_one, range(8)))
        if len(pids) >= 2:
            break
    study(pool, 8, chunk_size=4)
    return pids


@contextlib.contextmanager
def _warm_cluster():
    """A 2-worker Dask ``LocalCluster`` and its client, every worker warmed as the pool's.

    Started for each Dask round and closed after it: an idle cluster's scheduler,
    client and workers wake every few ms (about 12 % of one core together), which
    would slow the pool's rounds if it lived beside them."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=":0") as cluster, Client(cluster) as client:
        client.run(_warm_one)  # on every Dask worker
        study(client, 8, chunk_size=4)
        yield client


KINDS = ("serial", "processes(2) warm", "dask(2) warm")


def _per_task(executor) -> float:
    """Seconds per task of 64 one-trial chunks of a no-op trial (best of 3)."""
    return min(timed(lambda: study(executor, 64, trial=noop, chunk_size=1))
               for _ in range(3)) / 64


def throughput(n: int, repeats: int) -> tuple[dict, list, dict]:
    """Trials per second, best of ``repeats`` rounds; each round runs serial, pool and
    Dask back to back so that all three see the same background load.  Also returns
    per round and executor: (wall s, CPU s of the study's processes, idle fraction of
    all cores, 1-min load), and the seconds per task of a no-op chunk on each pool."""
    ctx = multiprocessing.get_context("forkserver")
    rounds = []
    with cf.ProcessPoolExecutor(2, mp_context=ctx) as pool:
        study("serial", 8)  # imports and caches outside the clock
        pids = _warm_pool(pool)
        for _ in range(repeats):
            row = {"serial": (*serial_apart(n), os.getloadavg()[0])}
            row["processes(2) warm"] = (*measured(lambda: study(pool, n),
                                                  lambda: sum(_proc_cpu(p) for p in pids)),
                                        os.getloadavg()[0])
            with _warm_cluster() as client:
                row["dask(2) warm"] = (*measured(
                    lambda: study(client, n),
                    lambda: sum(client.run(time.process_time).values())), os.getloadavg()[0])
            rounds.append(row)
        per_task = {"processes(2)": _per_task(pool)}
    with _warm_cluster() as client:
        per_task["dask(2)"] = _per_task(client)
    rates = {k: n / min(r[k][0] for r in rounds) for k in KINDS}
    cold = cold_rounds(n, repeats)
    for k in COLD[1:3]:
        rates[k] = n / min(r[k] for r in cold)
    return rates, rounds, per_task, cold


COLD = ("serial", "processes(2) cold", "dask(2) cold", "dask(2) cold, new process",
        "dask(2) cold, spawned", "serial, new process", "dask(2) cold, Dask's timers")


def dask_own_cluster(n: int, start_method: str) -> None:
    """The study on a fresh 2-worker Dask ``LocalCluster`` with Dask's default settings,
    started here rather than by ``run_study``; its start and close are part of the run.

    ``start_method`` "spawn" (Dask's default): each worker imports numpy, scipy,
    distributed and the package itself.  "forkserver": the workers fork from this
    process's fork server, as ``run_study``'s do, but keep Dask's default
    housekeeping timers -- a task profiler sampling every 10 ms, an event-loop tick
    every 20 ms -- where ``run_study`` slows them: what that gains.
    """
    import dask
    from distributed import Client, LocalCluster

    with dask.config.set({"distributed.worker.multiprocessing-method": start_method}):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                               dashboard_address=":0")
    client = Client(cluster, set_as_default=False)
    try:
        study(client, n)
    finally:
        client.close()
        cluster.close()


def serial_apart(n: int) -> tuple[float, float, float]:
    """A serial study of ``n`` trials in a warmed process of its own: wall seconds, CPU
    seconds and the fraction of all cores idle meanwhile.

    The serial baseline never shares its interpreter with a live executor: the warm
    pool's and Dask cluster's threads in this process (Dask's client and scheduler
    wake up every few ms) take the GIL from a study running beside them and would
    make every ratio to serial read high."""
    code = ("import sys, time; sys.path.insert(0, sys.argv[1]); import study_throughput as b; "
            "b.study('serial', 200); i0, t0 = b._cpu_ticks(); c = time.process_time(); "
            "w = time.perf_counter(); b.study('serial', int(sys.argv[2])); "
            "w, c = time.perf_counter() - w, time.process_time() - c; i1, t1 = b._cpu_ticks(); "
            "print(w, c, (i1 - i0) / (t1 - t0) if t1 > t0 else float('nan'))")
    out = subprocess.run([sys.executable, "-c", code, str(Path(__file__).parent), str(n)],
                         capture_output=True, text=True, check=True)
    wall, cpu, idle = (float(v) for v in out.stdout.split()[-3:])
    return wall, cpu, idle


def new_process(executor: str, n: int) -> float:
    """Wall seconds of ``run_study(executor=executor)`` as the first study of a new
    process: its first calls load the compiled kernels and the study imports xarray;
    a Dask study also starts the fork server (the interpreter's own start and its
    import of the package are not counted)."""
    code = ("import sys, time; sys.path.insert(0, sys.argv[1]); import study_throughput as b; "
            "ex = sys.argv[3]; t = time.perf_counter(); "
            "b.study(ex, int(sys.argv[2]), **({} if ex == 'serial' else {'workers': 2})); "
            "print(time.perf_counter() - t)")
    out = subprocess.run([sys.executable, "-c", code, str(Path(__file__).parent), str(n),
                          executor], capture_output=True, text=True, check=True)
    return float(out.stdout.split()[-1])


def cold_rounds(n: int, repeats: int) -> list[dict]:
    """Wall seconds per round of serial, then studies that start their own pool or Dask
    cluster (in this process; as the first study of a new process; with Dask's spawned
    workers): back to back, so each cold run has a serial run under the same background
    load to be divided by."""
    runs = {"serial": lambda: serial_apart(n)[0],
            "processes(2) cold": lambda: timed(lambda: study("processes", n, workers=2)),
            "dask(2) cold": lambda: timed(lambda: study("dask", n, workers=2)),
            "dask(2) cold, new process": lambda: new_process("dask", n),
            "dask(2) cold, spawned": lambda: timed(lambda: dask_own_cluster(n, "spawn")),
            "serial, new process": lambda: new_process("serial", n),
            "dask(2) cold, Dask's timers": lambda: timed(
                lambda: dask_own_cluster(n, "forkserver"))}
    return [{k: runs[k]() for k in COLD} for _ in range(repeats)]


def overhead(n: int, repeats: int) -> dict:
    settings = {**SETTINGS, "estimator": BATCHED}
    rngs = lambda: trial_rngs(1, 0, np.arange(n))  # noqa: E731
    direct = min(timed(lambda: ring_estimate(settings, rngs=rngs())) for _ in range(repeats))
    runner = min(timed(lambda: study("serial", n, BATCHED, chunk_size=n))
                 for _ in range(repeats))
    rng_only = min(timed(rngs) for _ in range(repeats))
    nothing = min(timed(lambda: study("serial", n, trial=noop, chunk_size=50))
                  for _ in range(repeats))
    return {"batched fit+score per trial (direct)": direct / n,
            "same through run_study, per trial": runner / n,
            "runner overhead per trial": (runner - direct) / n,
            "per-trial SeedSequence+Generator (in both above)": rng_only / n,
            "no-op trial through run_study (chunks of 50)": nothing / n}


def pool_start() -> dict:
    """Seconds until the processes backend's pool runs (first and second time in this
    process) and the wall ratio of a 16-trial study on it against serial."""
    from olsbayes.studies.executors import make_backend

    out = {}
    for name in ("first pool", "later pool"):
        t0 = time.perf_counter()
        backend = make_backend("processes", workers=2)
        backend._local.ready.wait()
        out[name] = time.perf_counter() - t0
        backend.close()
    study("serial", 4)  # this process loads the kernels outside the clock
    # serial first: a closed pool's workers may still be busy (loading kernels for a
    # trial they started) and would slow a serial study timed after them
    time.sleep(1.0)
    small_serial = min(timed(lambda: study("serial", 16)) for _ in range(3))
    small_proc = min(timed(lambda: study("processes", 16, workers=2)) for _ in range(3))
    out["small study processes/serial (wall)"] = small_proc / small_serial
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--full", action="store_true", help="paper-size run")
    ap.add_argument("--out", type=Path, default=Path("out/study_throughput"))
    args = ap.parse_args()
    n, reps = (20000, 5) if args.full else (4000, 3)
    load0 = os.getloadavg()[0]
    start = pool_start()  # first: it times the first pool of this process
    rates, rounds, per_task, cold = throughput(n, reps)
    ov = overhead(2000 if args.full else 500, 3)
    lines = [f"ML trials ({SETTINGS}, estimator fast), {n} trials, best of {reps}:"]
    lines += [f"  {k:<22s} {v:8.1f} trials/s" for k, v in rates.items()]
    lines += [
        f"  ratio processes(2)/serial (warm) = "
        f"{rates['processes(2) warm'] / rates['serial']:.2f}   (target >= 1.6)",
        f"  ratio dask(2)/processes(2) (warm) = "
        f"{rates['dask(2) warm'] / rates['processes(2) warm']:.2f}   (target >= 0.8)",
        f"  ratio dask(2)/processes(2) (cold) = "
        f"{rates['dask(2) cold'] / rates['processes(2) cold']:.2f}",
        f"  load average before/after: {load0:.1f} / {os.getloadavg()[0]:.1f} on "
        f"{os.cpu_count()} cores (other processes share them: ratios are only meaningful "
        "on an otherwise idle machine)",
        f"Rounds ({n} trials each): wall s, CPU ms per trial (the study's own processes), "
        "idle = fraction of all cores idle meanwhile",
        "  round  serial: wall  cpu/tr  idle | procs(2): wall  cpu/tr  idle | "
        "dask(2): wall  cpu/tr  idle | procs/serial  dask/procs  load1",
    ]
    for i, r in enumerate(rounds):
        cells = "  | ".join(f"{r[k][0]:6.2f}  {1e3 * r[k][1] / n:6.2f}  {r[k][2]:4.2f}"
                            for k in KINDS)
        lines.append(f"  {i:5d}  {cells}  | {r[KINDS[0]][0] / r[KINDS[1]][0]:12.2f}  "
                     f"{r[KINDS[1]][0] / r[KINDS[2]][0]:10.2f}  {r[KINDS[2]][3]:5.1f}")
    lines += ["Cold rounds (the study starts its executor), wall s, each next to a serial run; "
              "dask: in this process, as a new process's first study, with spawned workers; "
              "serial new: serial as a new process's first study; dask timers: as dask, with "
              "Dask's default housekeeping timers:",
              "  round  serial  procs(2)    dask  dask new  dask spawned  serial new  "
              "dask timers | procs/serial  dask/serial  new/serial  spawned/serial  "
              "new/serial new  timers/serial"]
    lines += [f"  {i:5d}  " + "  ".join(f"{r[k]:{w}.2f}"
                                        for k, w in zip(COLD, (6, 8, 6, 8, 12, 10, 11)))
              + " | " + "  ".join(f"{r['serial'] / r[k]:{w}.2f}" for k, w in
                                  zip(COLD[1:5], (12, 11, 10, 14)))
              + f"  {r[COLD[5]] / r[COLD[3]]:14.2f}  {r['serial'] / r[COLD[6]]:13.2f}"
              for i, r in enumerate(cold)]
    cold_ratio = {k: float(np.median([r["serial"] / r[k] for r in cold])) for k in COLD[1:]}
    like_for_like = float(np.median([r[COLD[5]] / r[COLD[3]] for r in cold]))
    cpu = {k: float(np.median([r[k][1] for r in rounds])) / n for k in KINDS}
    lines += [
        "CPU per trial (median over rounds; independent of other programs' load): "
        + ", ".join(f"{k.split()[0]} {1e3 * v:.2f} ms" for k, v in cpu.items()),
        f"  => on 2 otherwise idle cores, CPU-bound: processes(2)/serial <= "
        f"{2 * cpu['serial'] / cpu['processes(2) warm']:.2f}, dask(2)/processes(2) ~ "
        f"{cpu['processes(2) warm'] / cpu['dask(2) warm']:.2f} (a bound from CPU cost, "
        "not a measured rate)",
        "Cost per task (64 one-trial chunks of a no-op trial, best of 3): "
        + ", ".join(f"{k} {1e3 * v:.2f} ms" for k, v in per_task.items()),
        "Runner overhead (serial, seconds per trial):",
    ]
    lines += [f"  {k:<46s} {v * 1e6:9.1f} us" for k, v in ov.items()]
    lines += ["Pool start (executor='processes', 2 workers; the study's process runs chunks "
              "while its pool starts):"]
    lines += [f"  {k:<40s} {v:8.2f}{' s' if 'pool' in k.split()[-1] else ''}"
              for k, v in start.items()]
    if sys.dont_write_bytecode:  # PYTHONDONTWRITEBYTECODE: each new process compiles
        lines += ["  (bytecode caching is off here: the fork server compiles the package's "
                  "sources as it starts, which a normal install does not; unset "
                  "PYTHONDONTWRITEBYTECODE to time what users see)"]
    goals = [
        ("pool start, first pool of a process <= 1 s", start["first pool"], 1.0, "<="),
        ("pool start, later pool <= 1 s", start["later pool"], 1.0, "<="),
        ("small study processes/serial wall <= 1.2", start["small study processes/serial (wall)"],
         1.2, "<="),
        ("2 workers / serial (cold, run_study starts the pool) >= 1.7",
         cold_ratio["processes(2) cold"], 1.7, ">="),
        ("2 workers / serial (warm) >= 1.7", rates["processes(2) warm"] / rates["serial"], 1.7,
         ">="),
        ("Dask(2) / serial (cold) >= 1.5", cold_ratio["dask(2) cold"], 1.5, ">="),
        ("Dask(2) / serial (cold, a new process's first study) >= 1.5",
         cold_ratio["dask(2) cold, new process"], 1.5, ">="),
        ("Dask(2) / serial (each a new process's first study) >= 1.5", like_for_like, 1.5,
         ">="),
        ("Dask(2) / serial (warm) >= 1.5", rates["dask(2) warm"] / rates["serial"], 1.5, ">="),
    ]
    lines += [f"Dask(2) / serial (cold) with Dask's default timers: "
              f"{cold_ratio[COLD[6]]:.2f} (median), against {cold_ratio['dask(2) cold']:.2f} "
              f"with run_study's; faster in "
              f"{sum(r['dask(2) cold'] < r[COLD[6]] for r in cold)} of {len(cold)} rounds"]
    lines += ["Goals:"] + [
        f"  {name:<62s} {value:6.2f}  "
        f"{'met' if (value <= bound if op == '<=' else value >= bound) else 'not met'}"
        for name, value, bound, op in goals]
    text = "\n".join(lines)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "study_throughput.txt").write_text(text + "\n")


if __name__ == "__main__":
    main()
