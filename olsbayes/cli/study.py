"""Run a Monte Carlo study described by a TOML file, locally or on a Dask cluster.

The file holds a [study] table (what to run and where), a [grid] table (setting
axes: lists of numbers, strings, bools or tables) and an optional [fixed] table
(settings shared by every cell).  The default trial, ring_estimate, simulates a
ring scene, estimates it with the setting `estimator` and scores it against the
CRLB.  An estimator is a table {name = ..., option = value} (listed at the end of
`olsbayes study --help`); a name alone ("fast", "exact", "nested") stands for its
table with the default options.  The result's `estimator` coordinate holds
canonical labels such as "multistart(n_starts=5)".  Unknown estimators, options
and settings (with a did-you-mean), values out of range and results that would
not fit in max_memory_gb are refused before any trial runs.

A study file is code: trial = "package.module:function" imports that module and
runs the function, as `python script.py` would.  Relative out and checkpoint
paths are relative to this file's folder; --out is relative to the current one.

  [study]
  trial = "ring_estimate"        # or noise_check, or "package.module:function"
  n_trials = 200
  seed = 1
  out = "study.nc"               # NetCDF result (relative to this file)
  checkpoint = "study.ckpt"      # optional; resume with --resume after a crash
  executor = "processes"         # serial | threads | processes | dask
  workers = 2
  max_memory_gb = 4              # optional budget of the result arrays

  [grid]
  estimator = [{name = "fast"}, {name = "multistart", n_starts = 5}]
  sigma = [0.001, 0.01, 0.1]
  n_sources = [1, 2]

  [fixed]
  n_sensors = 16

Example:
  olsbayes study sweep.toml
  olsbayes study sweep.toml --resume
  olsbayes study sweep.toml --executor dask --scheduler tcp://10.0.0.5:8786
"""

from __future__ import annotations

import argparse
import importlib
import inspect
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..config import Field, Section, load_config, register_section
from ..errors import ConfigError, InputError
from ..studies import ESTIMATORS, EXECUTORS, dataset_seed, run_study
from ._common import _parse_override, add_command, add_json_arg, emit, format_table

__all__ = ["register", "run", "load_study_config", "estimator_help", "BUILTIN_TRIALS"]

#: Trial functions accepted by name in [study] trial.
BUILTIN_TRIALS = {
    "ring_estimate": "olsbayes.studies.estimators:ring_estimate",
    "noise_check": "olsbayes.studies.trials:noise_check",
    "noise_check_batch": "olsbayes.studies.trials:noise_check_batch",
}

STUDY_SECTION = register_section(Section(
    name="study",
    doc="a Monte Carlo study: trial function, trials per cell, seed, executor, files",
    fields={
        "trial": Field("str", default="ring_estimate",
                       doc="built-in trial name or 'package.module:function'"),
        "n_trials": Field("int", required=True, low=1, high=10**9, doc="trials per grid cell"),
        "seed": Field("int", low=0, high=2**63 - 1, doc="root seed (default: fresh)"),
        "out": Field("path", doc="NetCDF file of the result"),
        "checkpoint": Field("path", doc="append-only checkpoint file (enables --resume)"),
        "executor": Field("str", default="processes", choices=EXECUTORS,
                          doc="serial, threads, processes or dask"),
        "workers": Field("int", low=1, high=100_000, doc="local workers (default: cores)"),
        "scheduler": Field("str", doc="Dask scheduler address, e.g. tcp://host:8786"),
        "chunk_size": Field("int", low=1, high=10**6, doc="trials per task"),
        "max_memory_gb": Field("float", positive=True, high=1e6,
                               doc="memory budget of the results, GB (default: half the "
                                   "memory, at most 4)"),
    },
))
for _free in ("grid", "fixed"):
    register_section(Section(name=_free, fields={}, free=True,
                             doc=f"a study's [{_free}] settings, checked against its trial"))
_TABLES = ("study", "grid", "fixed")


def estimator_help() -> str:
    """The estimators of ring_estimate and their options, one line per option."""
    lines = ["Estimators of ring_estimate ({name = ..., option = value}):"]
    for name, options in ESTIMATORS.items():
        if not options:
            lines.append(f"  {name:<11s} no options")
        for i, (key, opt) in enumerate(options.items()):
            lines.append(f"  {name if i == 0 else '':<11s} {key} ({opt.describe()}): {opt.doc}")
    return "\n".join(lines)


def register(subparsers: Any) -> None:
    """Add the ``study`` subcommand and its options to ``subparsers``."""
    p = add_command(subparsers, "study", help="run a Monte Carlo study (local pool or Dask)",
                    description=f"{__doc__}\n{estimator_help()}")
    p.add_argument("config", metavar="CONFIG", help="TOML file with [study], [grid], [fixed]")
    p.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="SECTION.KEY=VALUE", help="override one value (TOML syntax)")
    p.add_argument("--executor", choices=EXECUTORS, default=None, help="override [study]")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler address (implies --executor dask)")
    p.add_argument("--workers", type=_positive, default=None, help="local workers (>= 1)")
    p.add_argument("--out", type=Path, default=None, help="NetCDF result file")
    p.add_argument("--resume", action="store_true",
                   help="continue the study in the [study] checkpoint file")
    p.add_argument("--quiet", "--no-progress", dest="quiet", action="store_true",
                   help="no progress bar or status lines on stderr (warnings and errors "
                        "are still printed)")
    add_json_arg(p)
    p.set_defaults(run=run)


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1; got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1; got {value}")
    return value


def _load_trial(spec: str, source: str) -> Callable:
    """The function named by [study] trial: importing its module runs that module's code."""
    target = BUILTIN_TRIALS.get(spec, spec)
    module, sep, name = target.partition(":")
    if not (sep and name.isidentifier()
            and module and all(part.isidentifier() for part in module.split("."))):
        raise ConfigError(f"{source}: [study] trial must be one of {sorted(BUILTIN_TRIALS)} or "
                          f"'package.module:function'; got {spec!r}")
    try:
        fn = getattr(importlib.import_module(module), name)
    except Exception as exc:  # noqa: BLE001 - any failure of the user's module is reported
        raise ConfigError(f"{source}: [study] trial {spec!r} cannot be imported: "
                          f"{type(exc).__name__}: {exc}") from None
    if not inspect.isfunction(fn):
        raise ConfigError(f"{source}: [study] trial {spec!r} is not a Python function "
                          f"(def ...(settings, *, rng)); got {type(fn).__name__}")
    return fn


def load_study_config(path: str | Path, overrides: dict | None = None) -> dict[str, Any]:
    """Validated study settings: ``{"study": {...}, "grid": {...}, "fixed": {...}, "trial": fn}``.

    The file is read like every configuration file (:func:`olsbayes.config.load_config`:
    regular files of bounded size only); [study] is validated by its schema,
    relative paths resolved against the file's folder; [grid] and [fixed] are
    free tables checked by :func:`olsbayes.studies.run_study` against what the
    trial accepts.
    """
    cfg = load_config(path, _TABLES, required=("study",), overrides=overrides or {})
    study = dict(cfg.section("study"))
    return {"study": study, "grid": dict(cfg.get("grid") or {}),
            "fixed": dict(cfg.get("fixed") or {}), "trial": _load_trial(study["trial"], cfg.source)}


def _summary(ds) -> tuple[list[str], list[list[Any]]]:
    dims = [d for d in ds.dims if d in ds.coords and d != "trial"]
    scalars = [v for v in ds.data_vars if set(ds[v].dims) <= set(dims) | {"trial"}]
    mean = ds[scalars].astype(float).mean("trial")
    flat = mean.to_dataframe().reset_index() if dims else None
    header = dims + [f"mean {v}" for v in scalars]
    if flat is None:
        return header, [[float(mean[v]) for v in scalars]]
    return header, [list(r) for r in flat[dims + scalars].itertuples(index=False)][:200]


def run(args: argparse.Namespace) -> int:
    """Run the study of the TOML file, write its result and print the mean per cell.

    A study error is reported as a :class:`~olsbayes.errors.ConfigError` naming the
    file.  Prints text, or JSON with --json; returns the exit status 0.
    """
    overrides = dict(_parse_override(s) for s in args.overrides)
    cfg = load_study_config(args.config, overrides)
    s = cfg["study"]
    executor = "dask" if args.scheduler else (args.executor or s["executor"])
    scheduler = args.scheduler or s.get("scheduler")
    if executor != "dask":
        scheduler = None
    out = args.out if args.out is not None else s.get("out")
    if out is None:
        raise InputError("study needs an output file: [study] out = \"...\" or --out FILE")
    ckpt = s.get("checkpoint")
    if args.resume and ckpt is None:
        raise InputError("--resume needs [study] checkpoint = \"...\" in the config")
    if ckpt is not None and Path(ckpt).exists() and not args.resume:
        raise InputError(f"checkpoint {str(ckpt)!r} exists: pass --resume to continue that "
                         "study, or delete the file to start afresh")
    workers = args.workers if args.workers is not None else s.get("workers")
    try:
        ds = run_study(cfg["trial"], cfg["grid"], s["n_trials"], fixed=cfg["fixed"],
                       executor=executor, workers=workers, scheduler=scheduler,
                       checkpoint=ckpt, out=out, rng=s.get("seed"),
                       chunk_size=s.get("chunk_size"), progress=not args.quiet,
                       max_memory_gb=s.get("max_memory_gb"))
    except InputError as exc:
        raise ConfigError(f"{args.config}: {exc}") from None
    header, rows = _summary(ds)
    seed = dataset_seed(ds)
    payload = {"out": str(out), "seed": seed, "n_trials": int(ds.attrs["n_trials"]),
               "dims": {k: int(v) for k, v in ds.sizes.items()}, "header": header,
               "rows": rows}
    text = (f"study {ds.attrs['trial_function']}: {dict(ds.sizes)}, seed {seed}\n"
            f"{format_table(header, rows)}\nwritten: {out}")
    emit(args, payload, text)
    return 0


