"""Imaging mode: intensities of sources at known directions, with their posterior.

Readings come from --data FILE, else from the config's [data] section (a file
or a simulation of [scene]).  The known directions come from [image] directions,
else from [scene] directions (imaging at the scene's own source directions).
Options come from the command line, else from an optional [image] section
(directions, prior, i_max, level, n_samples, n_chains, sampler, neighbours, window).

Prints the design's rank and null space size and, per direction, the posterior
mean, sd, credible interval and how much of it the array cannot see
(null fraction); --figure PATH draws true sources / raw readings / estimate /
posterior sd on a sky map (sphere arrays).

Example:
  olsbayes image scene.toml --json --seed 1
  olsbayes image scene.toml --prior sparse --figure olss.png
  olsbayes image scene.toml --data readings.txt --prior gaussian
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from ..build import data_from_config, model_from_config, scene_from_config
from ..config import Field, Section, read_readings, register_section
from ..errors import InputError
from ..imaging import PRIORS, SAMPLERS, image
from ._common import (
    add_command,
    add_config_args,
    add_json_arg,
    add_seed_arg,
    emit,
    format_table,
    load_cli_config,
    output_dir,
)

__all__ = ["register", "run"]

register_section(Section(
    name="image",
    doc="imaging at known directions (olsbayes image)",
    fields={
        "directions": Field("array", ndim=(1, 2),
                            doc="known source directions: ring angles or [[lon, lat], ...] (rad)"),
        "prior": Field("str", default="bounded", choices=PRIORS, doc="intensity prior"),
        "i_max": Field("float", default=1.0, positive=True, doc="upper intensity bound"),
        "level": Field("float", default=0.9, low=0.01, high=0.999, doc="interval credibility"),
        "n_samples": Field("int", low=0, high=1_000_000,
                           doc="draws per chain (default 200; 0 = posterior mode only)"),
        "n_chains": Field("int", default=4, low=1, high=256, doc="sampler chains"),
        "sampler": Field("str", default="gibbs", choices=SAMPLERS, doc="box-prior sampler"),
        "neighbours": Field("int", default=4, low=0, high=64, doc="pair moves per source"),
        "window": Field("int", default=15, low=0, high=64,
                        doc="box-prior Gibbs: window moves over each source + this many nearest"),
        "prior_bright": Field("float", default=0.5, low=1e-9, high=1 - 1e-9,
                              doc="two-level prior: probability that a source is bright"),
        "restarts": Field("int", default=0, low=0, high=10_000,
                          doc="two-level prior: extra randomly rounded search starts"),
    },
))


def register(subparsers: Any) -> None:
    p = add_command(subparsers, "image", help="intensities at known directions (imaging)",
                    description=__doc__)
    add_config_args(p)
    p.add_argument("--data", type=Path, default=None, metavar="FILE",
                   help="readings (text/CSV/.npy, one row of N readings)")
    p.add_argument("--prior", choices=PRIORS, default=None, help="intensity prior")
    p.add_argument("--i-max", type=float, default=None, metavar="I",
                   help="upper bound of the intensities (default 1)")
    p.add_argument("--n-samples", type=int, default=None, metavar="S",
                   help="draws per chain (default 200; 0 = posterior mode only, no sampling; "
                        "the two-level prior is MAP only)")
    p.add_argument("--figure", type=Path, default=None, metavar="PNG",
                   help="write the sky-map panels (sphere arrays) to this PNG file")
    add_seed_arg(p, help="seed of the sampler and of a [data] simulation")
    add_json_arg(p)
    p.set_defaults(run=run)


def _inputs(args: argparse.Namespace) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray | None,
                                                 dict[str, Any]]:
    cfg = load_cli_config(args, sections=("sensor", "scene", "data", "image"))
    model = model_from_config(cfg)
    sec = dict(cfg.get("image") or {})
    scene = scene_from_config(cfg, model) if "scene" in cfg else None
    if args.data is not None:
        data = read_readings(args.data, model.n_sensors, name="--data")
    else:
        data = data_from_config(cfg, model, scene, rng=args.seed)
        if data is None:
            raise InputError("image needs readings: give --data FILE or a [data] section")
    if np.ndim(data) != 1:
        raise InputError(f"image takes one row of readings; got {np.shape(data)[0]} rows")
    if "directions" in sec:
        dirs, truth = sec["directions"], None
    elif scene is not None and scene.n_sources:
        dirs = scene.locations
        truth = scene.intensities if args.data is None else None
    else:
        raise InputError("image needs known directions: [image] directions or a [scene]")
    opts = {
        "prior": args.prior or sec.get("prior", "bounded"),
        "i_max": args.i_max if args.i_max is not None else sec.get("i_max", 1.0),
        "n_samples": args.n_samples if args.n_samples is not None else sec.get("n_samples"),
        "level": sec.get("level", 0.9),
        "n_chains": sec.get("n_chains", 4),
        "sampler": sec.get("sampler", "gibbs"),
        "neighbours": sec.get("neighbours", 4),
        "window": sec.get("window", 15),
        "prior_bright": sec.get("prior_bright", 0.5),
        "restarts": sec.get("restarts", 0),
    }
    return model, data, np.asarray(dirs, dtype=float), truth, opts


def run(args: argparse.Namespace) -> int:
    model, data, dirs, truth, opts = _inputs(args)
    if args.figure is not None:
        if model.kind != "lonlat":
            raise InputError("--figure draws sky maps and needs a sphere array")
        output_dir(args.figure.parent if str(args.figure.parent) else Path("."), "--figure")
    if opts["prior"] == "two-level" and truth is not None and truth.shape == (dirs.shape[0],):
        opts["reference"] = truth  # the search reports the [scene]'s log posterior too
    res = image(model, data, dirs, rng=args.seed, **opts)
    payload: dict[str, Any] = {
        **res.summary(),
        "directions": res.directions,
        "mean": res.mean,
        "mode": res.mode,
        "sd": res.sd,
        "lower": res.lower,
        "upper": res.upper,
        "null_fraction": res.null_fraction,
    }
    if res.p_bright is not None:
        payload["p_bright"] = res.p_bright
    if truth is not None and truth.shape == res.mean.shape:
        payload["truth"] = truth
        payload["error_sd"] = float(np.std(res.mean - truth))
        payload["coverage"] = float(np.mean(res.covers(truth)))
    s = res.summary()
    lines = [
        f"Imaging {res.n_sources} directions with {s['n_sensors']} sub-sensors, prior "
        f"{res.prior!r} ({s['sampler']}): rank {s['rank']}, null space {s['nullity']}, "
        f"condition {s['condition']:.3g}, R-hat {s['rhat']:.3g}",
    ]
    header = ["k", "mean", "sd", f"lo{res.level:.0%}", f"hi{res.level:.0%}", "null frac"]
    rows = [[k, res.mean[k], res.sd[k], res.lower[k], res.upper[k], res.null_fraction[k]]
            for k in range(res.n_sources)]
    lines.append(format_table(header, rows, 4))
    if res.search is not None:
        lines.append(f"MAP search: log posterior {s['log_posterior']:.6g} after {s['moves']} "
                     f"moves, local optimum {s['local_optimum']}; [scene] log posterior "
                     f"{s['reference_log_posterior']}, better than the scene found: "
                     f"{s['reference_better']}")
    if "error_sd" in payload:
        lines.append(f"error sd vs [scene] intensities: {payload['error_sd']:.4g}; "
                     f"interval coverage {payload['coverage']:.3f}")
    if args.figure is not None:
        payload["figure"] = str(_figure(res, truth, model, data, args.figure))
        lines.append(f"Figure: {payload['figure']}")
    emit(args, payload, "\n".join(lines))
    return 0


def _figure(res: Any, truth: np.ndarray | None, model: Any, data: np.ndarray, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import atomic_path
    from ..plotting.skymap import plot_image_result

    fmt = path.suffix.lstrip(".").lower() or "png"
    fig = plot_image_result(res, truth=truth, model=model, data=data)
    if fmt not in fig.canvas.get_supported_filetypes():
        plt.close(fig)
        raise InputError(
            f"--figure {str(path)!r}: unknown image format {fmt!r}; use one of "
            f"{', '.join(sorted(fig.canvas.get_supported_filetypes()))}"
        )
    with atomic_path(path) as tmp:  # an interrupted run leaves no half-written figure
        fig.savefig(tmp, dpi=110, format=fmt)
    plt.close(fig)
    return path
