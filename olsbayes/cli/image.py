"""Imaging mode: intensities of sources at known directions, with their posterior.

Readings come from --data FILE, else from the config's [data] section (a file
or a simulation of [scene]).  The known directions come from [image] directions,
else from [scene] directions (imaging at the scene's own source directions).
Options come from the command line, else from an optional [image] section
(directions, prior, i_max, level, n_samples, n_chains, sampler, neighbours, window,
prior_bright, restarts); a setting the prior does not use is an error.

Prints the design's rank and null space size and, per direction, the posterior
mean, sd, credible interval and how much of it the array cannot see
(null fraction); the samplers show a progress bar on stderr (--quiet: none);
--figure PATH draws true sources / raw readings / estimate /
posterior sd on sky maps (sphere arrays), or intensity against angle (rings).

The bounded prior takes its upper bound i_max from the readings
unless --i-max (or [image] i_max) is given; the two-level prior needs it.  A
posterior that piles up at i_max is flagged (at_bound) and warned about.
Without --seed a seed is drawn, printed and recorded in the JSON with the
package version, the SHA-256 of the readings and the command line.

Example:
  olsbayes image scene.toml --json --seed 1
  olsbayes image scene.toml --prior two-level --i-max 1 --seed 1
  olsbayes image scene.toml --data readings.txt --prior gaussian
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from .._provenance import draw_seed, file_sha256, provenance
from .._validation import positive_float
from ..build import data_from_config, model_from_config, scene_from_config
from ..config import Field, Section, read_readings, register_section
from ..errors import InputError
from ..imaging import (
    PRIORS,
    SAMPLERS,
    Bounded,
    Gaussian,
    ImageOptions,
    ImagingPrior,
    NonNegative,
    TwoLevel,
    image,
)
from ._common import (
    add_command,
    add_config_args,
    add_json_arg,
    add_quiet_arg,
    add_seed_arg,
    emit,
    format_table,
    load_cli_config,
    output_file,
)

__all__ = ["register", "run"]

register_section(Section(
    name="image",
    doc="imaging at known directions (olsbayes image)",
    fields={
        "directions": Field("array", ndim=(1, 2),
                            doc="known source directions: ring angles or [[lon, lat], ...] (rad)"),
        "prior": Field("str", default="bounded", choices=PRIORS, doc="intensity prior"),
        "i_max": Field("float", positive=True,
                       doc="intensity scale: upper bound (bounded; default from the "
                           "readings), bright level (two-level; required), N(i_max/2, "
                           "(i_max/2)^2) (gaussian; default 1)"),
        "level": Field("float", default=0.9, low=0.01, high=0.999, doc="interval credibility"),
        # the keys below have no default here: each one given must apply to the prior
        "n_samples": Field("int", low=0, high=1_000_000,
                           doc="draws per chain (default: nonnegative and bounded sample "
                               "until converged, others 200; 0 = posterior mode only)"),
        "n_chains": Field("int", low=1, high=256, doc="sampler chains (default 4)"),
        "sampler": Field("str", choices=SAMPLERS, doc="box-prior sampler (default gibbs)"),
        "neighbours": Field("int", low=0, high=64, doc="pair moves per source (default 4)"),
        "window": Field("int", low=0, high=64,
                        doc="box-prior Gibbs: window moves over each source + this many "
                            "nearest (default 15)"),
        "prior_bright": Field("float", low=1e-9, high=1 - 1e-9,
                              doc="two-level prior: probability that a source is bright "
                                  "(default 0.5)"),
        "restarts": Field("int", low=0, high=10_000,
                          doc="two-level prior: extra randomly rounded search starts (default 0)"),
    },
))


def register(subparsers: Any) -> None:
    """Add the ``image`` subcommand and its options to ``subparsers``."""
    p = add_command(subparsers, "image", help="intensities at known directions (imaging)",
                    description=__doc__)
    add_config_args(p)
    p.add_argument("--data", type=Path, default=None, metavar="FILE",
                   help="readings (text/CSV/.npy, one row of N readings)")
    p.add_argument("--prior", choices=PRIORS, default=None, help="intensity prior")
    p.add_argument("--i-max", type=float, default=None, metavar="I",
                   help="intensity scale: upper bound of the bounded prior "
                        "(default: derived from the readings), bright level of the two-level "
                        "prior (required), N(I/2, (I/2)^2) for the gaussian prior (default 1)")
    p.add_argument("--n-samples", type=int, default=None, metavar="S",
                   help="draws per chain (default 200; 0 = posterior mode only, no sampling; "
                        "the two-level prior is MAP only)")
    p.add_argument("--figure", type=Path, default=None, metavar="PNG",
                   help="write the figure (sky maps for a sphere, intensity against angle "
                        "for a ring) to this PNG file")
    add_seed_arg(p, help="seed of the sampler and of a [data] simulation")
    add_quiet_arg(p)
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
    if args.prior is not None:
        sec["prior"] = args.prior
    sec["_angle_unit"] = (cfg.get("scene") or {}).get("angle_unit", "rad") \
        if "directions" not in sec else "rad"
    for key in ("i_max", "n_samples"):
        if getattr(args, key) is not None:
            sec[key] = getattr(args, key)
    return model, data, np.asarray(dirs, dtype=float), truth, sec


def _prior(sec: dict[str, Any]) -> ImagingPrior:
    """The prior object of the [image] settings (prior name, i_max, prior_bright)."""
    name = sec.get("prior", "bounded")
    given = sec.get("i_max")
    if given is None and name == "two-level":
        raise InputError("prior 'two-level' needs --i-max (or [image] i_max): the intensity "
                         "of a bright source")
    i_max = positive_float("i_max", 1.0 if given is None else given)
    bound = None if given is None else i_max  # bounded: None = from the readings
    p_bright = sec.get("prior_bright")
    if p_bright is not None and name != "two-level":
        raise InputError(f"prior_bright = {p_bright!r} does not apply to prior {name!r}: it is "
                         "used by the two-level prior; leave it unset")
    build = {
        "gaussian": lambda: Gaussian(mean=0.5 * i_max, sd=0.5 * i_max, scale=i_max),
        "nonnegative": lambda: NonNegative(scale=i_max),
        "bounded": lambda: Bounded(i_max=bound),
        "two-level": lambda: TwoLevel(i_max=i_max,
                                      p_bright=0.5 if p_bright is None else p_bright),
    }
    return build[name]()


def _options(sec: dict[str, Any], prior: ImagingPrior, truth: np.ndarray | None,
             k: int) -> ImageOptions:
    """The sampler settings of the [image] section; the [scene]'s truth as the reference."""
    keys = ("n_samples", "n_chains", "sampler", "neighbours", "window", "restarts")
    reference = None
    if isinstance(prior, TwoLevel) and truth is not None and truth.shape == (k,):
        reference = truth  # the search reports the [scene]'s log posterior too
    return ImageOptions(level=sec.get("level", 0.9), reference=reference,
                        **{key: sec[key] for key in keys if sec.get(key) is not None})


def _payload(res: Any, truth: np.ndarray | None, unit: str) -> dict[str, Any]:
    """JSON-ready result: diagnostics, per-direction table (directions in ``unit``)."""
    dirs = np.asarray(res.directions, dtype=float)
    if unit == "deg" and dirs.ndim and res.design.directions.shape[-1] in (1, 2):
        dirs = np.rad2deg(dirs)
    payload: dict[str, Any] = {
        **res.diagnostics(),
        "names": [f"I[{k}]" for k in range(res.n_sources)],
        "angle_unit": unit,
        "directions": dirs,
        "mean": res.mean,
        "mode": res.mode,
        "sd": res.sd,
        "lower": res.lower,
        "upper": res.upper,
        "null_fraction": res.null_fraction,
    }
    if res.p_bright is not None:
        payload["p_bright"] = res.p_bright
    if res.at_bound is not None:
        payload["at_bound"] = res.at_bound
    if truth is not None and truth.shape == res.mean.shape:
        payload["truth"] = truth
        payload["error_sd"] = float(np.std(res.mean - truth))
        payload["coverage"] = float(np.mean(res.covers(truth)))
    return payload


def run(args: argparse.Namespace) -> int:
    """Image the known directions: print the intensity posterior per direction.

    Prints text, or JSON with --json, and with --figure writes the sky-map panels;
    returns the exit status 0.
    """
    model, data, dirs, truth, sec = _inputs(args)
    prior = _prior(sec)
    options = _options(sec, prior, truth, dirs.shape[0])
    if args.figure is not None:
        if model.kind == "position":
            raise InputError("--figure draws sky maps (sphere) or angles (ring); a plate's "
                             "near sources have none")
        output_file(args.figure, "--figure")
    seed = args.seed if args.seed is not None else draw_seed()
    res = image(model, data, dirs, prior, options=options, rng=seed, progress=not args.quiet)
    unit = sec.get("_angle_unit", "rad")
    payload = _payload(res, truth, unit)
    record = provenance(seed=seed, data=data)
    if args.data is not None:
        record.update(data_file=str(args.data), data_file_sha256=file_sha256(args.data))
    payload["provenance"] = record
    s = res.diagnostics()
    bound = "" if res.i_max is None else f", i_max {res.i_max:.4g}"
    lines = [
        f"Imaging {res.n_sources} directions with {s['n_sensors']} sub-sensors, prior "
        f"{res.prior!r}{bound} ({s['sampler']}): rank {s['rank']}, null space {s['nullity']}, "
        f"condition {s['condition']:.3g}, R-hat {s['rhat']:.3g}",
        f"seed {seed}" + (" (drawn; recorded in the JSON)" if args.seed is None else ""),
    ]
    header = ["k", "mean", "sd", f"lo{res.level:.0%}", f"hi{res.level:.0%}", "null frac"]
    rows = [[k, res.mean[k], res.sd[k], res.lower[k], res.upper[k], res.null_fraction[k]]
            for k in range(res.n_sources)]
    if res.at_bound is not None:
        header.append("at i_max")
        rows = [r + ["yes" if res.at_bound[k] else ""] for k, r in enumerate(rows)]
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
