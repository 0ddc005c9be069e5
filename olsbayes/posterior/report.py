"""A posterior report folder: figures, tables, NetCDF and a self-contained HTML page."""

from __future__ import annotations

import base64
import html
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._io import atomic_path, ensure_dir, write_text_atomic
from .result import PosteriorResult

__all__ = ["write_report", "ReportFiles"]


@dataclass(frozen=True)
class ReportFiles:
    """Paths written by :func:`write_report`."""

    folder: Path
    corner: Path
    trace: Path
    summary_csv: Path
    summary_json: Path
    netcdf: Path
    html: Path


def _save_fig(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    return path


def _table(result: PosteriorResult):
    frame = result.summary()
    check = result.crlb_check().to_frame()
    for col in ("ratio", "mc_error", "flagged", "reason"):
        frame["crlb_" + col if col != "ratio" else "sd_over_crlb"] = check[col].to_numpy()
    return frame


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_jsonable(v) for v in np.asarray(value, dtype=object).tolist()]
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    return value


def _run_info(result: PosteriorResult) -> dict:
    w, d, _ = result.samples.shape
    return {
        "n_sources": result.n_sources, "kind": result.model.kind,
        "n_sensors": result.model.n_sensors, "sigma": result.model.sigma,
        "sigma_inferred": result.prior.noise is not None, "n_walkers": w,
        "draws_per_walker": d, "n_steps": result.n_steps, "n_burn": result.n_burn,
        "thin": result.thin, "converged": result.converged,
        "tau_max": float(np.max(result.tau)), "elapsed_s": result.elapsed,
        "mean_acceptance": float(np.mean(result.acceptance_fraction)),
        "label_switch_fraction": result.switch_fraction,
        "prior": repr(result.prior),
    }


def _img(path: Path, alt: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (f'<figure><img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'
            f'<figcaption>{html.escape(alt)} (<a href="{path.name}">{path.name}</a>)'
            "</figcaption></figure>")


def _show(value) -> str:
    if isinstance(value, (float, np.floating)):
        return f"{value:.4g}"
    return str(value)


def _html(title: str, info: dict, table, files: dict[str, Path]) -> str:
    rows = "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(_show(v))}</td></tr>"
                   for k, v in info.items())
    flagged = table.index[table["crlb_flagged"].astype(bool)].tolist()
    verdict = ("Every posterior sd agrees with its CRLB." if not flagged else
               "Posterior sd differs from the CRLB for: " + ", ".join(flagged) +
               " (see the reason column).")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em}"
             "table{border-collapse:collapse;font-size:0.85em}td,th{border:1px solid #ccc;"
             "padding:2px 6px;text-align:right}img{max-width:100%}figure{margin:1em 0}")
    links = " · ".join(f'<a href="{p.name}">{p.name}</a>' for p in files.values())
    return (
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
        f"<style>{style}</style></head><body><h1>{html.escape(title)}</h1>"
        f"<h2>Run</h2><table>{rows}</table>"
        f"<h2>Posterior summary and CRLB audit</h2><p>{html.escape(verdict)}</p>"
        "<p>Angles in rad (summarised circularly; an HDI straddling &plusmn;&pi; reads "
        "hi &lt; lo), intensities in reading units.  crlb: Cram&eacute;r&ndash;Rao bound on "
        "the sd at the posterior mean; sd_over_crlb is 1 within crlb_mc_error at high SNR; "
        "tau: emcee integrated autocorrelation time (steps).</p>"
        f"{table.to_html(float_format=lambda v: f'{v:.6g}', na_rep='')}"
        f"<h2>Corner plot</h2>{_img(files['corner'], 'Corner plot with CRLB ellipses')}"
        f"<h2>Traces</h2>{_img(files['trace'], 'Walker traces')}"
        f"<h2>Files</h2><p>{links}</p></body></html>"
    )


def write_report(
    result: PosteriorResult,
    folder: str | os.PathLike,
    truths=None,
    title: str | None = None,
) -> ReportFiles:
    """Write corner.png, trace.png, summary.csv, summary.json, posterior.nc, report.html.

    Every file is written atomically; report.html embeds both images (base64),
    so it can be mailed on its own, and also links the files beside it.

    Parameters
    ----------
    result : PosteriorResult
    folder : path
        Created if missing.
    truths : Scene or ndarray (P,), optional
        Marked on the corner plot and listed in summary.json.
    title : str, optional
    """
    from ..plotting.corner import plot_corner, plot_trace

    out = ensure_dir(folder, "report folder")
    files = {"corner": out / "corner.png", "trace": out / "trace.png",
             "summary_csv": out / "summary.csv", "summary_json": out / "summary.json",
             "netcdf": out / "posterior.nc"}
    _save_fig(plot_corner(result, truths=truths), files["corner"])
    _save_fig(plot_trace(result), files["trace"])
    table = _table(result)
    write_text_atomic(files["summary_csv"], table.to_csv())
    info = _run_info(result)
    payload = {"run": info, "parameters": {
        name: {col: table.loc[name, col] for col in table.columns} for name in table.index}}
    if truths is not None:
        from ..plotting.corner import match_truths

        payload["truths"] = dict(zip(result.names, match_truths(result, truths)))
    write_text_atomic(files["summary_json"], json.dumps(_jsonable(payload), indent=2))
    result.to_netcdf(files["netcdf"])
    title = title or f"olsbayes posterior: K = {result.n_sources} ({result.model.kind})"
    page = out / "report.html"
    write_text_atomic(page, _html(title, info, table, files))
    return ReportFiles(folder=out, html=page, **files)
