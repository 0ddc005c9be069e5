"""Maximum-likelihood fit of K sources to readings, with the CRLB at the estimate.

Readings come from --data FILE, else from the config's [data] section (a file
or a simulation of [scene]).  K comes from --n-sources, else from [scene].
A file with T rows is fitted in one batched call and printed as one table (a line
per row and source).

With --posterior the ML point seeds an emcee ensemble (olsbayes.posterior) and
the posterior sd is printed next to the CRLB, with chi^2/dof and the posterior
predictive p-value; --report DIR also writes corner, trace and posterior
predictive plots, summary tables, the NetCDF posterior and report.html into DIR.
The posterior lists its sources as the ML table does (source k is the ML
estimate's source k), in the text, the JSON and every report file.  While the
sampler runs, a status line on stderr shows the steps taken, the autocorrelation
time tau with the steps it asks for and the last R-hat (--quiet: none).

Without --seed a seed is drawn, printed and recorded in the outputs (JSON,
report), with the package version, the SHA-256 of the readings (and of --data)
and the command line.  Angles are printed in the [scene] angle_unit (rad or deg).

Example:
  olsbayes simulate --out readings.txt
  olsbayes fit --data readings.txt --n-sources 2
  olsbayes fit scene.toml --json --method multistart --seed 3
  olsbayes fit --posterior --report fit-report --seed 1
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._provenance import draw_seed, file_sha256, provenance
from ..build import model_from_config, scene_from_config
from ..build_measurement import prior_from_config, sampler_options_from_config
from ..circular import wrap_angle
from ..errors import InputError
from ..model import Model
from ..scene import Scene
from ._common import (
    add_command,
    add_config_args,
    add_json_arg,
    add_quiet_arg,
    add_seed_arg,
    emit,
    format_table,
    load_cli_config,
    output_dir,
)
from ._measurement import (
    FIT_SECTIONS,
    as_frames,
    extra_payload,
    extra_text,
    is_general,
    pearson_chi2,
    read_data,
)

__all__ = ["register", "run", "fit_payload", "fit_text", "batch_text", "load_fit_inputs",
           "PosteriorRequest", "posterior_block", "angle_unit_of", "in_unit"]


def register(subparsers: Any) -> None:
    """Add the ``fit`` subcommand and its options to ``subparsers``."""
    p = add_command(subparsers, "fit", help="maximum-likelihood fit of K sources",
                    description=__doc__)
    add_config_args(p)
    p.add_argument("--data", type=Path, default=None, metavar="FILE",
                   help="readings (text/CSV/.npy, one row of N readings per measurement)")
    p.add_argument("--n-sources", type=int, default=None, metavar="K",
                   help="number of sources to fit (default: as many as in [scene])")
    p.add_argument("--method", choices=("fast", "multistart", "exact"), default="fast",
                   help="fast (polynomial-time, default), multistart (the paper's baseline) "
                        "or exact (global optimum by enumeration; ring, clipped cosine, K <= 4)")
    add_seed_arg(p, help="seed of the multistart starts, the sampler and a [data] simulation")
    p.add_argument("--posterior", action="store_true",
                   help="also sample the posterior with emcee, seeded at the ML point")
    p.add_argument("--report", type=Path, default=None, metavar="DIR",
                   help="write the posterior report (corner plot, tables, NetCDF, HTML) to DIR;"
                        " implies --posterior")
    p.add_argument("--max-steps", type=int, default=20000, metavar="S",
                   help="step cap of the emcee run (default 20000)")
    add_quiet_arg(p)
    add_json_arg(p)
    p.set_defaults(run=run)


def load_fit_inputs(args: argparse.Namespace) -> tuple[Model, Scene | None, np.ndarray, int]:
    """(model, truth scene or None, readings, K) from CONFIG, --data, --n-sources."""
    cfg = load_cli_config(args, FIT_SECTIONS, required=("sensor",))
    model = model_from_config(cfg)
    truth = scene_from_config(cfg, model) if "scene" in cfg else None
    data, truth = read_data(args, cfg, model, truth, "fit")
    if args.n_sources is not None:
        k = args.n_sources
    elif truth is not None and truth.n_sources > 0:
        k = truth.n_sources
    else:
        raise InputError("fit needs the number of sources: give --n-sources K or a [scene]")
    if truth is not None and truth.n_sources != k:
        truth = None  # a truth with another K cannot be compared source by source
    return model, truth, data, k


def angle_unit_of(args: argparse.Namespace) -> str:
    """The [scene] angle_unit of the command's configuration ("rad" or "deg")."""
    cfg = load_cli_config(args, FIT_SECTIONS, required=("sensor",))
    return (cfg.get("scene") or {}).get("angle_unit", "rad")


def in_unit(model: Model, names: list[str], values: np.ndarray, unit: str) -> np.ndarray:
    """``values`` (..., P) with the angle parameters (theta, lon, lat) converted to ``unit``.

    Parameters are named by ``names`` (length P); non-angles are returned unchanged.
    """
    out = np.array(values, dtype=float)
    if unit == "deg" and model.kind != "position":
        angles = [i for i, n in enumerate(names) if n.split("[")[0] in ("theta", "lon", "lat")]
        out[..., angles] = np.rad2deg(out[..., angles])
    return out


def _rows(model: Model, params: np.ndarray, std: np.ndarray) -> list[list[Any]]:
    k = model.n_sources_of(params)
    blocks, sds = params.reshape(k, -1), std.reshape(k, -1)
    return [[*blocks[i, :-1], blocks[i, -1], *sds[i, :-1], sds[i, -1]] for i in range(k)]


def _chi2(model: Model, data: np.ndarray, params: np.ndarray) -> np.ndarray:
    """chi^2 = sum ((y - mu) / sigma)^2 of each fit, shape () or (T,)."""
    resid = (np.asarray(data, dtype=float) - model.response(np.asarray(params))) / model.sigma
    return np.sum(resid**2, axis=-1)


def fit_payload(model: Model, result: Any, truth: Scene | None, data: np.ndarray | None = None,
                unit: str = "rad", std: np.ndarray | None = None) -> dict[str, Any]:
    """JSON-ready dictionary of an :class:`~olsbayes.ml.MLResult`.

    Angles in ``unit``; with ``data``, ``chi2`` and ``chi2_dof`` (dof = N - P) of the fit.
    ``std``: the result's standard errors when already computed (``result.std``).
    """
    std = result.std if std is None else std
    names = model.param_names(result.n_sources)
    payload: dict[str, Any] = {
        "model": repr(model),
        "method": result.method,
        "n_sources": result.n_sources,
        "param_names": names,
        "angle_unit": unit,
        "params": in_unit(model, names, result.params, unit),
        "std": in_unit(model, names, std, unit),
        "log_likelihood": result.log_likelihood,
        "converged": result.converged,
        "rival_gap": result.rival_gap,
    }
    if data is not None:
        chi2 = _chi2(model, data, result.params)
        dof = model.n_sensors - len(names)
        payload.update(chi2=chi2, dof=dof, chi2_dof=chi2 / dof if dof > 0 else np.nan)
    if truth is not None:
        x_true = model.canonical(model.pack(truth))
        payload["truth"] = in_unit(model, names, x_true, unit)
        payload["error_over_std"] = _z(model, result.params, x_true, std)
    return payload


def _z(model: Model, est: np.ndarray, true: np.ndarray, std: np.ndarray) -> np.ndarray:
    err = np.asarray(est) - true
    if model.kind != "position":
        blocks = err.reshape(err.shape[:-1] + (-1, model.n_loc + 1))
        blocks[..., 0] = wrap_angle(blocks[..., 0])
        err = blocks.reshape(err.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        return err / std


_LOC_NAMES = {"angle": ["theta"], "lonlat": ["lon", "lat"], "position": ["x", "y", "z"]}


def fit_text(model: Model, result: Any, truth: Scene | None, row: int | None = None,
             unit: str = "rad") -> str:
    """Estimate +- Fisher std per source (and the truth, when known) as a table; angles in unit."""
    names = _LOC_NAMES[model.kind]
    flat_names = model.param_names(result.n_sources)
    params = in_unit(model, flat_names,
                     result.params if row is None else result.params[row], unit)
    std = in_unit(model, flat_names, result.std if row is None else result.std[row], unit)
    header = ["k", *names, "I", *(f"sd({n})" for n in names), "sd(I)"]
    rows = [[i, *r] for i, r in enumerate(_rows(model, params, std))]
    lines = [format_table(header, rows)]
    if truth is not None:
        x_true = model.canonical(model.pack(truth))
        z = _z(model, result.params if row is None else result.params[row], x_true,
               result.std if row is None else result.std[row]).reshape(result.n_sources, -1)
        x_true = in_unit(model, flat_names, x_true, unit)
        t_rows = [[i, *x_true.reshape(result.n_sources, -1)[i], *z[i]]
                  for i in range(result.n_sources)]
        lines += ["Truth and error / sd:", format_table(
            ["k", *names, "I", *(f"err/sd({n})" for n in names), "err/sd(I)"], t_rows, 4)]
    return "\n".join(lines)


def batch_text(model: Model, result: Any, truth: Scene | None, std: np.ndarray,
               unit: str = "rad", chi2_dof: np.ndarray | None = None) -> str:
    """One table of a batch fit: a line per data vector and source.

    Columns: row, k, estimate, Fisher std (angles in ``unit``), the row's
    log-likelihood and chi^2/dof (on its first source) and, when the truth is known,
    error / std.  ``std`` (T, P) is ``result.std``, computed once by the caller.
    """
    names = _LOC_NAMES[model.kind]
    k, d1 = result.n_sources, model.n_loc + 1
    flat_names = model.param_names(k)
    est = in_unit(model, flat_names, result.params, unit).reshape(-1, k, d1)
    sd = in_unit(model, flat_names, std, unit).reshape(-1, k, d1)
    ll = np.asarray(result.log_likelihood, dtype=float)
    header = ["row", "k", *names, "I", *(f"sd({n})" for n in names), "sd(I)", "log L"]
    per_row = [ll.repeat(k).tolist()]
    if chi2_dof is not None:
        header.append("chi^2/dof")
        per_row.append(np.broadcast_to(chi2_dof, ll.shape).repeat(k).tolist())
    cols = [est[..., j] for j in range(d1)] + [sd[..., j] for j in range(d1)]
    if truth is not None:
        z = _z(model, result.params, model.canonical(model.pack(truth)), std).reshape(-1, k, d1)
        header += [f"err/sd({n})" for n in (*names, "I")]
        cols += [z[..., j] for j in range(d1)]
    flat = [c.ravel().tolist() for c in cols]
    rows = [[t // k, t % k, *(c[t] for c in flat[: 2 * d1]),
             *(r[t] if t % k == 0 else "" for r in per_row), *(c[t] for c in flat[2 * d1 :])]
            for t in range(ll.size * k)]
    return format_table(header, rows)


def _check_posterior_args(args: argparse.Namespace, data: np.ndarray,
                          frames: bool = False) -> None:
    """Contradictory or out-of-range posterior options fail before any fitting."""
    if data.ndim != (2 if frames else 1):
        raise InputError(
            f"--posterior/--report fit one measurement; the readings hold {data.shape[0]} "
            "rows (give a file with one row, or [noise] frames = true for frames of one "
            "scene)"
        )
    if not 1 <= args.max_steps <= 10_000_000:
        raise InputError(f"--max-steps must be in [1, 10000000]; got {args.max_steps}")
    if args.report is not None:
        output_dir(args.report, "--report")


@dataclass(frozen=True)
class PosteriorRequest:
    """What :func:`posterior_block` samples and where it reports.

    Attributes
    ----------
    priors : ScenePrior, optional
        Passed to :func:`olsbayes.posterior.sample` (None: its default).
    options : SamplerOptions, optional
        The sampler's settings (None: the defaults).
    frames : bool
        The readings are frames of one scene.
    report : Path, optional
        Folder of the HTML report (None: no report).
    metadata : dict, optional
        Recorded in the report (the data file and its hash).
    selection : SelectionResult, optional
        Adds p(K | data) to the report.
    """

    priors: Any = None
    options: Any = None
    frames: bool = False
    report: Path | None = None
    metadata: dict[str, Any] | None = None
    selection: Any = None


def posterior_block(model: Model, data: np.ndarray, k: int, truth: Scene | None, rng: Any,
                    request: PosteriorRequest = PosteriorRequest(), *, ml: Any = None,
                    unit: str = "rad", progress: bool = True) -> tuple[dict[str, Any], str]:
    """Sample the posterior (and write the report the request asks for): payload and text.

    ``ml`` (the MLResult printed above) is the walkers' start, so the posterior
    labels its sources as the ML table does; angles are printed in ``unit``.
    ``progress``: the sampler's status line on stderr.
    """
    from ..posterior import SamplerOptions, sample

    folder = None if request.report is None else output_dir(request.report, "--report")
    opts = SamplerOptions() if request.options is None else request.options
    post = sample(model, data, k, priors=request.priors, start=ml, options=opts, rng=rng,
                  progress=progress, frames=request.frames)
    check, mc = post.crlb_check(), post.model_check()
    names = list(post.names)

    def conv(values: np.ndarray) -> np.ndarray:
        return in_unit(model, names, values, unit)

    payload: dict[str, Any] = {
        "names": names, "angle_unit": unit, "estimate": conv(post.estimate),
        "posterior_sd": conv(check.posterior_sd), "crlb_sd": conv(check.crlb_sd),
        "ratio": check.ratio, "flagged": check.flagged, "converged": post.converged,
        "n_steps": post.n_steps, "tau": post.tau, "at_prior_bound": list(post.at_bound),
        "model_check": mc.to_dict(),
    }
    d1 = model.n_loc + 1
    rows = [[i // d1 if i < k * d1 else "-", names[i].split("[")[0], conv(post.estimate)[i],
             conv(check.posterior_sd)[i], conv(check.crlb_sd)[i], check.ratio[i]]
            for i in range(len(names))]
    text = ["", f"Posterior (emcee, {post.n_steps} steps, converged={post.converged}; "
            "k as in the ML table):",
            format_table(["k", "param", "mean", "posterior sd", "CRLB sd", "ratio"], rows),
            f"Model check: chi^2/dof = {mc.chi2_dof:.4g} (dof {mc.dof}), posterior predictive "
            f"p = {mc.ppp:.3g}"]
    if folder is not None:
        from ..posterior.report import write_report

        files = write_report(post, folder, truths=truth, ml=ml, selection=request.selection,
                             metadata=request.metadata)
        payload["report"] = files.html
        text.append(f"Report: {files.html}")
    return payload, "\n".join(text)


def run(args: argparse.Namespace) -> int:
    """Fit K sources to the readings and print the estimate with its CRLB.

    With --posterior (or --report) also samples the posterior, seeded at the ML
    point.  Prints text, or JSON with --json; returns the exit status 0.
    """
    from ..ml import fit_ml

    model, truth, data, k = load_fit_inputs(args)
    unit = angle_unit_of(args)
    cfg = load_cli_config(args, FIT_SECTIONS, required=("sensor",))
    data, frames = as_frames(cfg, model, data)
    general = is_general(model, frames)
    want_posterior = args.posterior or args.report is not None
    if want_posterior:
        _check_posterior_args(args, data, frames)
    # --seed S simulates exactly the readings of `olsbayes simulate --seed S`; the
    # optimiser and the sampler get independent child streams of the same seed (drawn,
    # printed and recorded when not given; --seed S would also reseed a [data] simulation)
    seed = args.seed if args.seed is not None else draw_seed()
    ml_rng, post_rng = np.random.SeedSequence(seed).spawn(2)
    result = fit_ml(model, data, k, method=args.method, rng=ml_rng, frames=frames)
    record = provenance(seed=seed, data=data)
    if args.data is not None:
        record.update(data_file=str(args.data), data_file_sha256=file_sha256(args.data))
    std = result.std  # once: (T, P) for a batch
    payload = fit_payload(model, result, truth, None if general else data, unit, std)
    if general:
        chi2, dof = pearson_chi2(model, result, data, frames), (model.n_sensors - std.shape[-1]
                                                         - len(result.extra_names))
        payload.update(chi2=chi2, dof=dof, chi2_dof=chi2 / dof if dof > 0 else np.nan,
                       frames=data.shape[0] if frames else None, **extra_payload(result))
    payload["provenance"] = record
    chi = np.atleast_1d(payload["chi2_dof"])
    if args.json:
        blocks = []  # the text is not printed
    elif result.is_batch:
        blocks = [batch_text(model, result, truth, std, unit, chi)]
    else:
        fit_line = (f"log-likelihood {float(result.log_likelihood):.6g}, "
                    f"{_chi2_words(payload, model.n_sensors)}\n")
        blocks = [fit_line + fit_text(model, result, truth, unit=unit)]
        if general and extra_text(result):
            blocks.append(extra_text(result))
    blocks.insert(0, _head(model, result.method, k, unit, seed, drawn=args.seed is None))
    if want_posterior:
        if not args.json:  # the ML table now, not after the sampling
            emit(args, payload, "\n".join(blocks))
            sys.stdout.flush()
            blocks = []
        request = PosteriorRequest(
            priors=prior_from_config(cfg, model, k, data, frames),
            options=sampler_options_from_config(cfg, args.max_steps), frames=frames,
            report=args.report,
            metadata={key: record[key] for key in ("data_file", "data_file_sha256")
                      if key in record})
        payload["posterior"], text = posterior_block(model, data, k, truth, post_rng, request,
                                                     ml=result, unit=unit,
                                                     progress=not args.quiet)
        blocks.append(text)
    emit(args, payload, "\n".join(blocks))
    return 0


def _head(model: Model, method: str, k: int, unit: str, seed: int, drawn: bool) -> str:
    """The lines above the ML table: the model, the fit and the seed."""
    return (f"{model!r}\nML fit ({method}) of K = {k} source(s); sd = Fisher (CRLB) at the "
            "estimate; locations in " + (unit if model.kind != "position" else "length units")
            + f"\nseed {seed}" + (" (drawn; recorded in the JSON and the report)" if drawn
                                  else ""))


def _chi2_words(payload: dict[str, Any], n: int) -> str:
    """chi^2/dof with its dof; with no degrees of freedom left, chi^2 and why there is no ratio."""
    dof = payload["dof"]
    if dof > 0:
        return f"chi^2/dof {float(np.atleast_1d(payload['chi2_dof'])[0]):.4g} (dof {dof})"
    return (f"chi^2 {float(np.atleast_1d(payload['chi2'])[0]):.4g} (no chi^2/dof: "
            f"{n - dof} free parameters for {n} readings per frame, held by their priors)")
