"""Exact Cramér-Rao lower bound of a scene (and the paper's Eq. 3 / Eq. 4 on a ring).

Angles (directions and their bounds) are printed in the [scene] angle_unit.

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
from ..model import Model
from ..scene import Scene
from ._common import add_command, add_config_args, add_json_arg, emit, format_table, load_cli_config

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


def _paper_bounds(model: Model, scene: Scene, unit: str = "rad") -> dict[str, Any] | None:
    """Eq. 3 per source and, for two sources, Eq. 4 -- ring geometry only; angles in unit."""
    if model.kind != "angle" or scene.n_sources == 0 or not hasattr(model.array, "n"):
        return None
    inten = np.where(scene.intensities > 0, scene.intensities, np.nan)
    th3 = 2.0 * model.sigma / (np.sqrt(model.n_sensors) * inten)
    out: dict[str, Any] = {
        "eq3_direction_std": _deg(th3, unit),
        "eq3_intensity_std": crlb_eq3(model.n_sensors, model.sigma, 1.0)[1],
    }
    if scene.n_sources == 2:
        sep = float(abs(scene.directions[1] - scene.directions[0]))
        th4, i4 = crlb_eq4(model.n_sensors, model.sigma, scene.intensities, sep)
        out.update(eq4_direction_std=_deg(th4, unit), eq4_intensity_std=float(i4),
                   separation=_deg(sep, unit))
    return out


def _truth(scene: Scene, unit: str) -> dict[str, Any]:
    if scene.kind == "position":
        return {"positions": scene.positions, "intensities": scene.intensities}
    return {"directions": _deg(scene.directions, unit), "intensities": scene.intensities}


def crlb_payload(model: Model, scene: Scene, res: CRLBResult, unit: str = "rad"
                 ) -> dict[str, Any]:
    """JSON-ready dictionary of a CRLB result; directions and their bounds in ``unit``."""
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
    }
    paper = _paper_bounds(model, scene, unit)
    if paper is not None:
        payload["paper"] = paper
    return payload


def crlb_text(model: Model, scene: Scene, res: CRLBResult, unit: str = "rad") -> str:
    """A readable table: truth and CRLB per source (plus Eq. 3 / 4 on a ring); angles in unit."""
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
    paper = _paper_bounds(model, scene, unit)
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
        f"Exact CRLB (standard deviations; locations in {where}); "
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
    cfg = load_cli_config(args, required=("sensor", "scene"))
    model = model_from_config(cfg)
    scene = scene_from_config(cfg, model)
    res = crlb(model, scene)
    unit = (cfg.get("scene") or {}).get("angle_unit", "rad")
    emit(args, crlb_payload(model, scene, res, unit), crlb_text(model, scene, res, unit))
    return 0
