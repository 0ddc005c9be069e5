"""Maximum-likelihood fit of K sources to readings, with the CRLB at the estimate.

Readings come from --data FILE, else from the config's [data] section (a file
or a simulation of [scene]).  K comes from --n-sources, else from [scene].

Example:
  olsbayes simulate --out readings.txt
  olsbayes fit --data readings.txt --n-sources 2
  olsbayes fit scene.toml --json
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..build import data_from_config, model_from_config, scene_from_config
from ..config import read_readings
from ..errors import InputError
from ._common import add_command, add_config_args, add_json_arg, add_seed_arg, load_cli_config

__all__ = ["register", "run"]


def register(subparsers: Any) -> None:
    p = add_command(subparsers, "fit", help="maximum-likelihood fit of K sources",
                    description=__doc__)
    add_config_args(p)
    p.add_argument("--data", type=Path, default=None, metavar="FILE",
                   help="readings (text/CSV/.npy, one row of N readings per measurement)")
    p.add_argument("--n-sources", type=int, default=None, metavar="K",
                   help="number of sources to fit (default: as many as in [scene])")
    add_seed_arg(p, help="seed of the multi-start optimiser (and of a simulation)")
    add_json_arg(p)
    p.set_defaults(run=run)


def load_fit_inputs(args: argparse.Namespace) -> tuple[Any, Any, Any, int]:
    """(model, truth scene or None, readings, K) from CONFIG, --data, --n-sources."""
    cfg = load_cli_config(args, required=("sensor",))
    model = model_from_config(cfg)
    truth = scene_from_config(cfg, model) if "scene" in cfg else None
    if args.data is not None:
        data = read_readings(args.data, model.n_sensors, name="--data")
    else:
        data = data_from_config(cfg, model, truth, rng=args.seed)
        if data is None:
            raise InputError("fit needs readings: give --data FILE or a [data] section")
    if args.n_sources is not None:
        k = args.n_sources
    elif truth is not None:
        k = truth.n_sources
    else:
        raise InputError("fit needs the number of sources: give --n-sources K or a [scene]")
    if not 1 <= k <= model.n_sensors // 2:
        raise InputError(
            f"--n-sources must be in [1, {model.n_sensors // 2}] (N/2 for N = "
            f"{model.n_sensors} sub-sensors); got {k}"
        )
    return model, truth, data, k


def run(args: argparse.Namespace) -> int:
    load_fit_inputs(args)
    try:
        from ..ml import fit_ml  # noqa: F401
    except ImportError:
        raise InputError("fit: the ML engine olsbayes.ml is not available") from None
    raise InputError("fit: not wired to olsbayes.ml.fit_ml yet")
