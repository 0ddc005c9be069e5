"""A posterior report folder: figures, tables, NetCDF and a self-contained HTML page.

Every table, file and figure of one report lists the sources in the result's
order (``result.names``: the ML estimate's canonical order), and the run's
metadata -- package version, seed, data hash, command line -- goes into the
page, ``summary.json`` and ``posterior.nc`` alike.
"""

from __future__ import annotations

import base64
import html
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._io import atomic_path, ensure_dir, write_text_atomic
from .._notice import notice
from .._validation import file_path
from .result import PosteriorResult

__all__ = ["write_report", "ReportFiles"]


@dataclass(frozen=True)
class ReportFiles:
    """Paths written by :func:`write_report` (``k_posterior`` is None without a selection)."""

    folder: Path
    corner: Path
    trace: Path
    ppc: Path
    summary_csv: Path
    summary_json: Path
    netcdf: Path
    html: Path
    k_posterior: Path | None = None


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
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_jsonable(v) for v in np.asarray(value, dtype=object).tolist()]
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    return value


def _prior_text(prior) -> str:
    """``theta ~ CircularUniform(); I ~ Uniform(0, 2.19)``: the marginals, 4 digits."""
    def one(p) -> str:
        fields = getattr(p, "__dataclass_fields__", {})
        args = ", ".join(f"{getattr(p, f):.4g}" if isinstance(getattr(p, f), float)
                         else repr(getattr(p, f)) for f in fields)
        return f"{type(p).__name__}({args})"

    roles = [n.split("[")[0] for n in prior.param_names[: prior.n_loc + 1]]
    parts = [f"{r} ~ {one(p)}" for r, p in zip(roles, prior.location + (prior.intensity,))]
    if prior.noise is not None:
        parts.append(f"sigma ~ {one(prior.noise)}")
    return "; ".join(parts)


def _run_info(result: PosteriorResult, metadata: Mapping | None) -> dict:
    w, d, _ = result.samples.shape
    check = result.model_check()
    info = {
        "n_sources": result.n_sources, "names": " ".join(result.names),
        "kind": result.model.kind, "model": repr(result.model),
        "n_sensors": result.model.n_sensors, "sigma": result.model.sigma,
        "sigma_inferred": result.prior.noise is not None, "prior": _prior_text(result.prior),
        "n_walkers": w, "draws_per_walker": d, "n_steps": result.n_steps,
        "n_burn": result.n_burn, "thin": result.thin, "converged": result.converged,
        "tau_max": float(np.max(result.tau)), "elapsed_s": result.elapsed,
        "mean_acceptance": float(np.mean(result.acceptance_fraction)),
        "label_switch_fraction": result.switch_fraction,
        "at_prior_bound": ", ".join(result.at_bound) or "none",
        "chi2_dof": check.chi2_dof, "dof": check.dof, "ppp": check.ppp,
    }
    info.update({k: v for k, v in dict(result.provenance).items() if v is not None})
    info.update({k: v for k, v in dict(metadata or {}).items() if v is not None})
    return info


def _img(path: Path, alt: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (f'<figure><img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'
            f'<figcaption>{html.escape(alt)} (<a href="{path.name}">{path.name}</a>)'
            "</figcaption></figure>")


def _show(value) -> str:
    if isinstance(value, (float, np.floating)):
        return f"{value:.4g}"
    return str(value)


def _frame_html(frame) -> str:
    return ('<div class="wide">' + frame.to_html(float_format=lambda v: f"{v:.5g}", na_rep="")
            + "</div>")


def _sources_frame(result: PosteriorResult, ml, truths):
    """Posterior mean next to the ML estimate and the truth, one row per parameter."""
    import pandas as pd

    from ..plotting.corner import match_truths

    cols = {"posterior_mean": result.estimate, "posterior_sd": result.summary()["sd"].to_numpy(),
            "crlb_sd": result.crlb_std}
    p_model = result.model.n_params(result.n_sources)
    if ml is not None:
        pad = np.full(result.n_params - p_model, np.nan)
        cols["ml_estimate"] = np.concatenate([np.asarray(ml.params, dtype=float), pad])
        cols["ml_sd"] = np.concatenate([np.asarray(ml.std, dtype=float), pad])
    if truths is not None:
        cols["truth"] = match_truths(result, truths)
    return pd.DataFrame(cols, index=pd.Index(list(result.names), name="parameter"))


def _html(title: str, info: dict, tables: dict, files: dict[str, Path]) -> str:
    rows = "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(_show(v))}</td></tr>"
                   for k, v in info.items())
    table = tables["summary"]
    flagged = table.index[table["crlb_flagged"].astype(bool)].tolist()
    verdict = ("Every posterior sd agrees with its CRLB." if not flagged else
               "Posterior sd differs from the CRLB for: " + ", ".join(flagged) +
               " (see the reason column).")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em}"
             "table{border-collapse:collapse;font-size:0.8em}td,th{border:1px solid #ccc;"
             "padding:2px 5px;text-align:right}.wide{overflow-x:auto;max-width:100%}"
             "img{max-width:100%}figure{margin:1em 0}td{word-break:break-all}")
    links = " · ".join(f'<a href="{p.name}">{p.name}</a>' for p in files.values())
    k_part = ""
    if "k_posterior" in files:
        k_part = ("<h2>Number of sources</h2>" + _frame_html(tables["selection"])
                  + _img(files["k_posterior"], "p(K | data) per candidate K"))
    return (
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
        f"<style>{style}</style></head><body><h1>{html.escape(title)}</h1>"
        f"<h2>Run</h2><div class='wide'><table>{rows}</table></div>"
        "<h2>Estimates</h2><p>Sources in the same order in every table, file and figure "
        "(the ML estimate's).</p>" + _frame_html(tables["sources"]) +
        f"<h2>Posterior summary and CRLB audit</h2><p>{html.escape(verdict)}</p>"
        "<p>Angles in rad (summarised circularly; an HDI straddling &plusmn;&pi; reads "
        "hi &lt; lo), intensities in reading units.  crlb: Cram&eacute;r&ndash;Rao bound on "
        "the sd at the posterior mean; sd_over_crlb is 1 within crlb_mc_error at high SNR; "
        "tau: emcee integrated autocorrelation time (steps).</p>"
        + _frame_html(table) +
        "<h2>Model check</h2>"
        f"{_img(files['ppc'], 'Readings, posterior predictive band, residuals')}"
        f"{k_part}"
        f"<h2>Corner plot</h2>{_img(files['corner'], 'Corner plot with CRLB ellipses')}"
        f"<h2>Traces</h2>{_img(files['trace'], 'Walker traces')}"
        f"<h2>Files</h2><p>{links}</p></body></html>"
    )


def _summary_payload(result: PosteriorResult, info: dict, tables: dict, ml, selection) -> dict:
    """The content of summary.json: run facts, names in order, tables, model check."""
    table = tables["summary"]
    payload = {"run": info, "names": list(result.names),
               "model_check": result.model_check().to_dict(),
               "parameters": {name: {col: table.loc[name, col] for col in table.columns}
                              for name in table.index}}
    if ml is not None:
        payload["ml"] = {"names": list(result.model.param_names(result.n_sources)),
                         "params": ml.params, "std": ml.std, "method": ml.method}
    if "truth" in tables["sources"]:
        payload["truths"] = dict(zip(result.names, tables["sources"]["truth"]))
    if selection is not None:
        payload["selection"] = selection.to_dict()
    return payload


def write_report(
    result: PosteriorResult,
    folder: str | os.PathLike,
    truths=None,
    title: str | None = None,
    *,
    ml=None,
    selection=None,
    metadata: Mapping | None = None,
) -> ReportFiles:
    """Write the report files and report.html into ``folder``.

    Files: corner.png, trace.png, ppc.png (readings, posterior predictive band,
    residuals), summary.csv, summary.json, posterior.nc (readable back with
    :meth:`PosteriorResult.from_netcdf`), report.html and, with ``selection``,
    k_posterior.png.  Every file is written atomically; report.html embeds the
    images (base64), so it can be mailed on its own, and also links the files
    beside it.  The figures take seconds, so one line on stderr says so as the
    call starts (the command line's ``--quiet`` silences it).

    Parameters
    ----------
    result : PosteriorResult
    folder : path
        Created if missing.
    truths : Scene or ndarray (P,), optional
        Marked on the corner plot and listed in the tables and summary.json.
    title : str, optional
    ml : MLResult, optional
        A single ML fit of the same K: listed next to the posterior (same order).
    selection : SelectionResult, optional
        Adds the per-K evidence table and the p(K | data) plot.
    metadata : mapping, optional
        Extra run facts (strings and numbers, e.g. the data file and its hash)
        shown with the result's provenance.
    """
    from ..plotting.checks import plot_k_posterior, plot_ppc
    from ..plotting.corner import plot_corner, plot_trace

    out = ensure_dir(file_path("folder", folder), "report folder")
    notice(f"writing the posterior report to {out} (figures, tables, NetCDF, HTML) ...")
    files = {"corner": out / "corner.png", "trace": out / "trace.png", "ppc": out / "ppc.png",
             "summary_csv": out / "summary.csv", "summary_json": out / "summary.json",
             "netcdf": out / "posterior.nc"}
    _save_fig(plot_corner(result, truths=truths), files["corner"])
    _save_fig(plot_trace(result), files["trace"])
    _save_fig(plot_ppc(result), files["ppc"])
    tables = {"summary": _table(result), "sources": _sources_frame(result, ml, truths)}
    if selection is not None:
        files["k_posterior"] = _save_fig(plot_k_posterior(selection), out / "k_posterior.png")
        tables["selection"] = selection.summary()
    write_text_atomic(files["summary_csv"], tables["summary"].to_csv())
    info = _run_info(result, metadata)
    payload = _summary_payload(result, info, tables, ml, selection)
    write_text_atomic(files["summary_json"], json.dumps(_jsonable(payload), indent=2))
    result.to_netcdf(files["netcdf"])
    title = title or f"olsbayes posterior: K = {result.n_sources} ({result.model.kind})"
    page = out / "report.html"
    write_text_atomic(page, _html(title, info, tables, files))
    return ReportFiles(folder=out, html=page, **files)
