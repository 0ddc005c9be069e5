"""Simulate noisy readings of a scene (Eq. 1 plus N(0, sigma^2) noise, or the [noise] model).

Writes one row of N readings per measurement, as text a `fit` run (or a
`[data] file = ...` entry) reads back, or as a .npy array for an --out name that
ends in .npy.  The sections [noise], [calibration] and
[background] apply as for ``olsbayes fit``: ``[noise] model = "poisson"`` writes
counts (non-negative integers) of the given exposure, with the calibration's
gains and offsets and the background's value; with ``[noise] frames = true`` the
rows are F frames of the scene (F = --repeats, [data] repeats or one per
exposure).  The seed comes from --seed, else from [data] seed in CONFIG, else the
built-in default seed.

Example:
  olsbayes simulate --seed 1 --repeats 5 --out readings.txt
  olsbayes simulate scene.toml --json
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..build import MAX_READINGS, model_from_config, scene_from_config
from ..errors import InputError
from ._common import (
    add_command,
    add_config_args,
    add_json_arg,
    add_seed_arg,
    emit,
    load_cli_config,
    output_file,
    readings_text,
    write_readings,
)
from ._measurement import FIT_SECTIONS, frame_count

__all__ = ["register", "run", "DEFAULT_SEED"]

#: Seed used when neither --seed nor [data] seed is given.
DEFAULT_SEED = 20260123


def register(subparsers: Any) -> None:
    """Add the ``simulate`` subcommand and its options to ``subparsers``."""
    p = add_command(subparsers, "simulate", help="simulate noisy readings of a scene",
                    description=__doc__)
    add_config_args(p)
    add_seed_arg(p)
    p.add_argument("--repeats", type=int, default=None, metavar="T",
                   help="number of independent measurements (rows); default [data] repeats or 1")
    p.add_argument("--out", type=Path, default=None, metavar="FILE",
                   help="write the readings to FILE (one row per measurement: a .npy "
                        "array for a .npy name, else text)")
    add_json_arg(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Simulate noisy readings of the configured scene; print them or write them to --out.

    Prints text, or JSON with --json; returns the exit status 0.
    """
    cfg = load_cli_config(args, FIT_SECTIONS, required=("sensor", "scene"))
    model = model_from_config(cfg)
    scene = scene_from_config(cfg, model)
    data_sec = cfg.get("data") or {}
    if "file" in data_sec:
        raise InputError("simulate makes readings; remove [data] file from the config")
    seed = args.seed if args.seed is not None else data_sec.get("seed", DEFAULT_SEED)
    n_frames = frame_count(cfg, args.repeats)
    reps = n_frames or (args.repeats if args.repeats is not None else data_sec.get("repeats", 1))
    if not 1 <= reps <= 1_000_000:
        raise InputError(f"--repeats must be in [1, 1000000]; got {reps}")
    if reps * model.n_sensors > MAX_READINGS:
        raise InputError(
            f"--repeats {reps} x {model.n_sensors} sub-sensors exceeds {MAX_READINGS} readings"
        )
    if args.out is not None:
        output_file(args.out, "--out")
    readings = (model.simulate(scene, rng=seed, n_frames=n_frames) if n_frames
                else model.simulate(scene, rng=seed, size=reps))
    header = (
        f"olsbayes simulate: {model!r}; {scene!r}; seed={seed}; "
        f"{reps} row(s) of {model.n_sensors} readings" + (" (frames)" if n_frames else "")
    )
    if args.out is not None:
        write_readings(args.out, readings, header)
    payload = {"seed": seed, "n_sensors": model.n_sensors, "sigma": model.sigma,
               "readings": readings, "out": args.out}
    text = (f"wrote {reps} row(s) of {model.n_sensors} readings to {args.out}"
            if args.out is not None else readings_text(readings, header))
    emit(args, payload, text)
    return 0
