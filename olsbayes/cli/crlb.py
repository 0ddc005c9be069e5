"""Exact Cramér-Rao lower bound of a scene (and the paper's Eq. 3 / Eq. 4 on a ring).

Angles (directions and their bounds) are printed in the [scene] angle_unit.
The sections [noise], [calibration] and [background] give the noise and the
nuisance terms as for ``olsbayes fit``: the bound is that of Poisson counts of
the given exposure, say, with inferred terms marginalised; with ``[noise] frames
= true`` it is that of F frames ([data] repeats, or one per exposure).

Example:
  olsbayes crlb                               # the built-in Fig. 3 scene
  olsbayes crlb scene.toml --json
  olsbayes crlb --set sensor.n=60 --set sensor.sigma=0.001
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from ..bounds import CRLBResult, crlb, crlb_eq3, crlb_eq4
from ..build import model_from_config, scene_from_config
from ..measurement import is_plain
from ..model import Model
from ..scene import Scene
from ._common import add_command, add_config_args, add_json_arg, emit, format_table, load_cli_config
from ._measurement import FIT_SECTIONS, frame_count

__all__ = ["register", "run", "crlb_payload", "crlb_text"]


def register(subparsers: Any) -> None:
    """Add the ``crlb`` subcommand and its options to ``subparsers``."""
    p = add_command(subparsers, "crlb", help="exact CRLB of a scene", description=__doc__)
    add_config_args(p)
    add_json_arg(p)
    p.set_defaults(run=run)


def _deg(values: Any, unit: str) -> Any:
    """Angles (rad) in ``unit``; None stays None."""
    if values is None or unit != "deg":
        return values
    return np.rad2deg(np.asarray(values, dtype=float))


def _paper_bounds(model: Model, scene: Scene, unit: str = "rad", n_frames: int | None = None
                  ) -> dict[str, Any] | None:
    """Eq. 3 per source and, for two sources, Eq. 4 -- ring geometry only; angles in unit.

    With ``n_frames`` F the bounds of F frames: those of one frame / sqrt(F).
    """
    if (model.kind != "angle" or scene.n_sources == 0 or not hasattr(model.array, "n")
            or not is_plain(model)):
        return None
    inten = np.where(scene.intensities > 0, scene.intensities, np.nan)
    sigma = model.sigma / np.sqrt(1 if n_frames is None else n_frames)
    th3 = 2.0 * sigma / (np.sqrt(model.n_sensors) * inten)
    out: dict[str, Any] = {
        "eq3_direction_std": _deg(th3, unit),
        "eq3_intensity_std": crlb_eq3(model.n_sensors, sigma, 1.0)[1],
    }
    if scene.n_sources == 2:
        sep = float(abs(scene.directions[1] - scene.directions[0]))
        th4, i4 = crlb_eq4(model.n_sensors, sigma, scene.intensities, sep)
        out.update(eq4_direction_std=_deg(th4, unit), eq4_intensity_std=float(i4),
                   separation=_deg(sep, unit))
    return out


def _truth(scene: Scene, unit: str) -> dict[str, Any]:
    if scene.kind == "position":
        return {"positions": scene.positions, "intensities": scene.intensities}
    return {"directions": _deg(scene.directions, unit), "intensities": scene.intensities}


def crlb_payload(model: Model, scene: Scene, res: CRLBResult, unit: str = "rad",
                 n_frames: int | None = None) -> dict[str, Any]:
    """JSON-ready dictionary of a CRLB result; directions and their bounds in ``unit``.

    ``n_frames``: the frames the bound is for (None: one measurement).  With
    inferred extra parameters, their bounds and the cost of not knowing them
    (``nuisance_cost``, std / std with them known) are included.
    """
    unit = unit if model.kind != "position" else "rad"
    payload: dict[str, Any] = {
        "model": repr(model),
        "n_sensors": model.n_sensors,
        "sigma": model.sigma,
        "kind": model.kind,
        "angle_unit": unit,
        "truth": _truth(scene, unit),
        "crlb": {
            "direction_std": _deg(res.direction_std, unit),
            "position_std": res.position_std,
            "intensity_std": res.intensity_std,
            "condition": res.condition,
            "resolvable": res.resolvable,
        },
        "param_names": model.param_names(scene.n_sources),
        "n_frames": n_frames,
    }
    if res.extra_names:
        payload["crlb"].update(extra_names=list(res.extra_names), extra_std=res.extra_std,
                               nuisance_cost=res.nuisance_cost)
    paper = _paper_bounds(model, scene, unit, n_frames)
    if paper is not None:
        payload["paper"] = paper
    return payload


def crlb_text(model: Model, scene: Scene, res: CRLBResult, unit: str = "rad",
              n_frames: int | None = None) -> str:
    """A readable table: truth and CRLB per source (plus Eq. 3 / 4 on a ring); angles in unit.

    ``n_frames``: the frames the bound is for (None: one measurement).
    """
    unit = unit if model.kind != "position" else "rad"
    loc_names = {"angle": ["theta"], "lonlat": ["lon", "lat"], "position": ["x", "y", "z"]}[
        model.kind
    ]
    loc_std = res.position_std if model.kind == "position" else _deg(res.direction_std, unit)
    loc_std = np.asarray(loc_std).reshape(scene.n_sources, -1)
    locations = np.asarray(_deg(scene.locations, unit))
    header = ["k", *loc_names, "I", *(f"sd({n})" for n in loc_names), "sd(I)"]
    rows = [
        [k, *locations[k], scene.intensities[k], *loc_std[k], res.intensity_std[k]]
        for k in range(scene.n_sources)
    ]
    paper = _paper_bounds(model, scene, unit, n_frames)
    if paper is not None:
        header += ["Eq3 sd(theta)", "Eq3 sd(I)"]
        for k, row in enumerate(rows):
            row += [paper["eq3_direction_std"][k], paper["eq3_intensity_std"]]
        if "eq4_direction_std" in paper:
            header += ["Eq4 sd(theta)", "Eq4 sd(I)"]
            for k, row in enumerate(rows):
                row += [paper["eq4_direction_std"][k], paper["eq4_intensity_std"]]
    where = unit if model.kind != "position" else "length units"
    lines = [
        f"{model!r}",
        f"Exact CRLB (standard deviations; locations in {where}"
        + ("" if n_frames is None else f"; {n_frames} frame(s)") + "); "
        f"Fisher condition number {res.condition:.3g}",
        format_table(header, rows),
    ]
    if not res.resolvable:
        lines.append("Some parameters are not identifiable (inf): sources too close to resolve.")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Print the exact CRLB of the configured scene (text, or JSON with --json).

    Returns the exit status 0.
    """
    cfg = load_cli_config(args, FIT_SECTIONS, required=("sensor", "scene"))
    model = model_from_config(cfg)
    scene = scene_from_config(cfg, model)
    n_frames = frame_count(cfg)
    res = crlb(model, scene, n_frames=n_frames)
    unit = (cfg.get("scene") or {}).get("angle_unit", "rad")
    emit(args, crlb_payload(model, scene, res, unit, n_frames),
         crlb_text(model, scene, res, unit, n_frames))
    return 0
