"""Maximum-likelihood fit of K sources to readings, with the CRLB at the estimate.

Readings come from --data FILE, else from the config's [data] section (a file
or a simulation of [scene]).  K comes from --n-sources, else from [scene].
A file with T rows is fitted in one batched call and printed as one table (a line
per row and source).

With --posterior the ML point seeds an emcee ensemble (olsbayes.posterior) and
the posterior sd is printed next to the CRLB; --report DIR also writes corner and
trace plots, summary tables, the NetCDF posterior and report.html into DIR.

Example:
  olsbayes simulate --out readings.txt
  olsbayes fit --data readings.txt --n-sources 2
  olsbayes fit scene.toml --json --method multistart --seed 3
  olsbayes fit --posterior --report fit-report --seed 1
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from ..build import data_from_config, model_from_config, scene_from_config
from ..circular import wrap_angle
from ..config import read_readings
from ..errors import InputError
from ..model import Model
from ..scene import Scene
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

__all__ = ["register", "run", "fit_payload", "fit_text", "batch_text", "load_fit_inputs",
           "posterior_block"]


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
    add_json_arg(p)
    p.set_defaults(run=run)


def load_fit_inputs(args: argparse.Namespace) -> tuple[Model, Scene | None, np.ndarray, int]:
    """(model, truth scene or None, readings, K) from CONFIG, --data, --n-sources."""
    cfg = load_cli_config(args, required=("sensor",))
    model = model_from_config(cfg)
    truth = scene_from_config(cfg, model) if "scene" in cfg else None
    if args.data is not None:
        data = read_readings(args.data, model.n_sensors, name="--data")
        if "scene" in cfg and args.config is None:
            truth = None  # the default scene is no truth for the user's readings
    else:
        data = data_from_config(cfg, model, truth, rng=args.seed)
        if data is None:
            raise InputError("fit needs readings: give --data FILE or a [data] section")
    if args.n_sources is not None:
        k = args.n_sources
    elif truth is not None and truth.n_sources > 0:
        k = truth.n_sources
    else:
        raise InputError("fit needs the number of sources: give --n-sources K or a [scene]")
    if truth is not None and truth.n_sources != k:
        truth = None  # a truth with another K cannot be compared source by source
    return model, truth, data, k


def _rows(model: Model, params: np.ndarray, std: np.ndarray) -> list[list[Any]]:
    k = model.n_sources_of(params)
    blocks, sds = params.reshape(k, -1), std.reshape(k, -1)
    return [[*blocks[i, :-1], blocks[i, -1], *sds[i, :-1], sds[i, -1]] for i in range(k)]


def fit_payload(model: Model, result: Any, truth: Scene | None,
                std: np.ndarray | None = None) -> dict[str, Any]:
    """JSON-ready dictionary of an :class:`~olsbayes.ml.MLResult`.

    ``std``: the result's standard errors when already computed (``result.std``).
    """
    std = result.std if std is None else std
    payload: dict[str, Any] = {
        "model": repr(model),
        "method": result.method,
        "n_sources": result.n_sources,
        "param_names": model.param_names(result.n_sources),
        "params": result.params,
        "std": std,
        "log_likelihood": result.log_likelihood,
        "converged": result.converged,
        "rival_gap": result.rival_gap,
    }
    if truth is not None:
        x_true = model.canonical(model.pack(truth))
        payload["truth"] = x_true
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


def fit_text(model: Model, result: Any, truth: Scene | None, row: int | None = None) -> str:
    """Estimate +- Fisher std per source (and the truth, when known) as a table."""
    names = _LOC_NAMES[model.kind]
    params = result.params if row is None else result.params[row]
    std = result.std if row is None else result.std[row]
    header = ["k", *names, "I", *(f"sd({n})" for n in names), "sd(I)"]
    rows = [[i, *r] for i, r in enumerate(_rows(model, params, std))]
    lines = [format_table(header, rows)]
    if truth is not None:
        x_true = model.canonical(model.pack(truth))
        z = _z(model, params, x_true, std).reshape(result.n_sources, -1)
        t_rows = [[i, *x_true.reshape(result.n_sources, -1)[i], *z[i]]
                  for i in range(result.n_sources)]
        lines += ["Truth and error / sd:", format_table(
            ["k", *names, "I", *(f"err/sd({n})" for n in names), "err/sd(I)"], t_rows, 4)]
    return "\n".join(lines)


def batch_text(model: Model, result: Any, truth: Scene | None, std: np.ndarray) -> str:
    """One table of a batch fit: a line per data vector and source.

    Columns: row, k, estimate, Fisher std, the row's log-likelihood (on its first
    source) and, when the truth is known, error / std.  ``std`` (T, P) is
    ``result.std``, computed once by the caller.
    """
    names = _LOC_NAMES[model.kind]
    k, d1 = result.n_sources, model.n_loc + 1
    est = result.params.reshape(-1, k, d1)
    sd = std.reshape(-1, k, d1)
    ll = np.asarray(result.log_likelihood, dtype=float)
    header = ["row", "k", *names, "I", *(f"sd({n})" for n in names), "sd(I)", "log L"]
    cols = [est[..., j] for j in range(d1)] + [sd[..., j] for j in range(d1)]
    if truth is not None:
        z = _z(model, result.params, model.canonical(model.pack(truth)), std).reshape(-1, k, d1)
        header += [f"err/sd({n})" for n in (*names, "I")]
        cols += [z[..., j] for j in range(d1)]
    flat = [c.ravel().tolist() for c in cols]
    first = ll.repeat(k).tolist()
    rows = [[t // k, t % k, *(c[t] for c in flat[: 2 * d1]), first[t] if t % k == 0 else "",
             *(c[t] for c in flat[2 * d1 :])] for t in range(ll.size * k)]
    return format_table(header, rows)


def _check_posterior_args(args: argparse.Namespace, data: np.ndarray) -> None:
    """Contradictory or out-of-range posterior options fail before any fitting."""
    if data.ndim != 1:
        raise InputError(
            f"--posterior/--report fit one measurement; the readings hold {data.shape[0]} "
            "rows (give a file with one row)"
        )
    if not 1 <= args.max_steps <= 10_000_000:
        raise InputError(f"--max-steps must be in [1, 10000000]; got {args.max_steps}")
    if args.report is not None:
        output_dir(args.report, "--report")


def _ml_table_order(model: Model, estimate: np.ndarray, k: int) -> list[tuple[Any, int]]:
    """(source index of the ML table, parameter index) pairs, sources in canonical order.

    The posterior labels sources by its own relabelling rule (cyclic from a pivot);
    the ML table by :meth:`Model.canonical`.  Rows follow the ML table so a reader
    compares the same source in both; parameters after the sources (sigma) come last.
    """
    d1 = model.n_loc + 1
    blocks = np.asarray(estimate[: k * d1], dtype=float).reshape(k, d1)
    key = blocks[:, 0] if model.kind == "position" else wrap_angle(blocks[:, 0])
    order = np.argsort(key, kind="stable")  # the rule of Model.canonical
    pairs = [(rank, int(src) * d1 + j) for rank, src in enumerate(order) for j in range(d1)]
    return pairs + [("-", i) for i in range(k * d1, len(estimate))]


def posterior_block(model: Model, data: np.ndarray, k: int, truth: Scene | None, rng: Any,
                    max_steps: int = 20000, report: Path | None = None
                    ) -> tuple[dict[str, Any], str]:
    """Sample the posterior (and write the report into ``report``): payload and text."""
    from ..posterior import SamplerOptions, sample

    folder = None if report is None else output_dir(report, "--report")
    post = sample(model, data, k, options=SamplerOptions(max_steps=max_steps), rng=rng,
                  progress=False)
    check = post.crlb_check()
    payload: dict[str, Any] = {
        "estimate": post.estimate, "posterior_sd": check.posterior_sd, "crlb_sd": check.crlb_sd,
        "ratio": check.ratio, "flagged": check.flagged, "converged": post.converged,
        "n_steps": post.n_steps, "tau": post.tau,
    }
    rows = [[k_ml, post.names[i].split("[")[0], post.estimate[i], check.posterior_sd[i],
             check.crlb_sd[i], check.ratio[i]]
            for k_ml, i in _ml_table_order(model, post.estimate, k)]
    text = ["", f"Posterior (emcee, {post.n_steps} steps, converged={post.converged}; "
            "k as in the ML table):",
            format_table(["k", "param", "mean", "posterior sd", "CRLB sd", "ratio"], rows)]
    if folder is not None:
        from ..posterior.report import write_report

        files = write_report(post, folder, truths=truth)
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
    want_posterior = args.posterior or args.report is not None
    if want_posterior:
        _check_posterior_args(args, data)
    # --seed S simulates exactly the readings of `olsbayes simulate --seed S`; the
    # optimiser and the sampler get independent child streams of the same seed
    ml_rng, post_rng = (None, None) if args.seed is None else np.random.SeedSequence(
        args.seed).spawn(2)
    result = fit_ml(model, data, k, method=args.method, rng=ml_rng)
    std = result.std  # once: (T, P) for a batch
    payload = fit_payload(model, result, truth, std)
    if args.json:
        blocks = []  # the text is not printed
    elif result.is_batch:
        blocks = [batch_text(model, result, truth, std)]
    else:
        blocks = [f"log-likelihood {float(result.log_likelihood):.6g}\n"
                  + fit_text(model, result, truth)]
    head = (f"{model!r}\nML fit ({result.method}) of K = {k} source(s); sd = Fisher "
            "(CRLB) at the estimate; locations in "
            + ("rad" if model.kind != "position" else "length units"))
    if want_posterior:
        payload["posterior"], text = posterior_block(model, data, k, truth, post_rng,
                                                     args.max_steps, args.report)
        blocks.append(text)
    emit(args, payload, "\n".join([head, *blocks]))
    return 0
