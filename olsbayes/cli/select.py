"""Choose the number of sources K: evidence for K = 0..K_max and p(K | data).

Readings come from --data FILE, else from the config's [data] section (a file or
a simulation of [scene]).  Options come from the command line, else from an
optional [select] section (k_max, method, i_max, maxcall, tie).  The sections
[noise], [calibration] and [background] give the model its noise and nuisance
terms as for ``olsbayes fit`` (with ``[noise] frames = true`` the rows are frames
of one scene, selected jointly); [prior] sets the intensity prior (intensity,
i_max), an unknown sigma's prior and the prior on K (k_prior, k_mean).  Prints, per
reading row, a table of K, log Z, its error, the estimator and p(K | data), the
K sent to quadrature or nested sampling and why.  Long steps (importance and nested sampling)
show a status line on stderr (--quiet: none).  The ML points in the JSON (``params``) give
angles in the [scene] angle_unit.

Example:
  olsbayes select                              # the built-in Fig. 3 scene
  olsbayes select scene.toml --json --seed 1
  olsbayes select --data readings.txt --k-max 3 --method laplace --i-max 2
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from ..build import model_from_config, scene_from_config
from ..build_measurement import count_prior_from_config, prior_from_config
from ..config import Field, Section, register_section
from ..errors import InputError
from ..select import METHODS, DecisionOptions, NestedOptions, SelectOptions, select_k
from ._common import (
    add_command,
    add_config_args,
    add_json_arg,
    add_quiet_arg,
    add_seed_arg,
    emit,
    load_cli_config,
)
from ._measurement import FIT_SECTIONS, as_frames, read_data

__all__ = ["register", "run"]

register_section(Section(
    name="select",
    doc="choice of the number of sources (olsbayes select)",
    fields={
        "k_max": Field("int", default=4, low=0, high=8, doc="largest K considered"),
        "method": Field("str", default="auto", choices=METHODS, doc="evidence estimator"),
        "i_max": Field("float", positive=True, doc="upper end of the intensity prior"),
        "maxcall": Field("int", low=1000, high=100_000_000,
                         doc="likelihood-call cap per nested-sampling run (default: scaled "
                             "with the parameters and live points)"),
        "tie": Field("float", default=math.log(3.0), low=0.0, high=100.0,
                     doc="nats within which the smaller K is preferred"),
    },
))


def register(subparsers: Any) -> None:
    """Add the ``select`` subcommand and its options to ``subparsers``."""
    p = add_command(subparsers, "select", help="choose the number of sources K (evidence)",
                    description=__doc__)
    add_config_args(p)
    p.add_argument("--data", type=Path, default=None, metavar="FILE",
                   help="readings (text/CSV/.npy, one row of N readings per measurement)")
    p.add_argument("--k-max", type=int, default=None, metavar="K",
                   help="largest number of sources considered (default 4)")
    p.add_argument("--method", choices=METHODS, default=None,
                   help="evidence estimator (default auto: Laplace, then quadrature (K <= 2 "
                        "ring sources) or nested sampling where Laplace is not to be trusted)")
    p.add_argument("--i-max", type=float, default=None, metavar="I",
                   help="upper end of the uniform intensity prior (default: from the data)")
    p.add_argument("--maxcall", type=int, default=None, metavar="M",
                   help="likelihood-call cap per nested-sampling run (default: scaled with "
                        "the parameters and live points, within the memory budget)")
    add_seed_arg(p, help="seed of the ML restarts, nested sampling and a [data] simulation")
    add_quiet_arg(p)
    add_json_arg(p)
    p.set_defaults(run=run)


def _options(args: argparse.Namespace, cfg: Any) -> dict[str, Any]:
    sec = dict(cfg.get("select") or {})
    opts = {
        "k_max": args.k_max if args.k_max is not None else sec.get("k_max", 4),
        "method": args.method or sec.get("method", "auto"),
        "i_max": args.i_max if args.i_max is not None else sec.get("i_max"),
        "maxcall": args.maxcall if args.maxcall is not None else sec.get("maxcall"),
        "tie": sec.get("tie", math.log(3.0)),
    }
    if opts["i_max"] is not None and not (math.isfinite(opts["i_max"]) and opts["i_max"] > 0):
        raise InputError(f"--i-max must be a finite number > 0; got {opts['i_max']!r}")
    return opts


def _prior_args(cfg: Any, model: Any, row: Any, i_max: float | None, frames: bool
                ) -> dict[str, Any]:
    """``i_max=`` (no [prior] intensity settings) or ``priors=`` (K -> [prior]'s prior)."""
    sec = cfg.get("prior") or {}
    if not ({"i_max", "sigma_min", "sigma_max"} & set(sec)
            or sec.get("intensity", "uniform") != "uniform"):
        return {"i_max": i_max}
    prior_from_config(cfg, model, 1, row, frames, i_max=i_max)  # bad [prior]: before work
    return {"priors": lambda k: prior_from_config(cfg, model, k, row, frames, i_max=i_max)}


def _in_unit(model: Any, result: dict[str, Any], unit: str) -> dict[str, Any]:
    """A selection's JSON with the angles of every candidate's ML point in ``unit``."""
    from .fit import in_unit

    for cand in result["candidates"]:
        if cand["params"] and cand.get("names"):
            cand["params"] = in_unit(model, cand["names"], cand["params"], unit).tolist()
    return result


def run(args: argparse.Namespace) -> int:
    """Print the evidence per K and p(K | data) for every row of readings.

    Prints text, or JSON with --json; returns the exit status 0.
    """
    cfg = load_cli_config(args, sections=(*FIT_SECTIONS, "select"), required=("sensor",))
    model = model_from_config(cfg)
    truth = scene_from_config(cfg, model) if "scene" in cfg else None
    opts = _options(args, cfg)
    k_prior = count_prior_from_config(cfg, opts["k_max"])
    data, truth = read_data(args, cfg, model, truth, "select")
    data, frames = as_frames(cfg, model, data)
    rows = [data] if frames else data.reshape(-1, model.n_sensors)
    settings = SelectOptions(nested=NestedOptions(maxcall=opts["maxcall"]),
                             decision=DecisionOptions(tie=opts["tie"]))
    results = [select_k(model, row, opts["k_max"], k_prior=k_prior, method=opts["method"],
                        options=settings, rng=args.seed, progress=not args.quiet,
                        frames=frames, **_prior_args(cfg, model, row, opts["i_max"], frames))
               for row in rows]
    unit = (cfg.get("scene") or {}).get("angle_unit", "rad")
    payload: dict[str, Any] = {"model": repr(model), "options": opts, "angle_unit": unit,
                               "results": [_in_unit(model, r.to_dict(), unit) for r in results]}
    if truth is not None:
        payload["true_k"] = truth.n_sources
    lines = [repr(model)]
    if truth is not None:
        lines.append(f"true K = {truth.n_sources}")
    for i, r in enumerate(results):
        if len(results) > 1:
            lines.append(f"-- row {i}")
        lines.append(r.table())
    emit(args, payload, "\n".join(lines))
    return 0
