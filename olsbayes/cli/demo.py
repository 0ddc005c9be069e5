"""The main job: simulate the paper's Fig. 3 scene, fit it, compare with the CRLB.

Default scene: a ring of N = 30 sub-sensors with the clipped-cosine law, noise
sigma = 0.01, two sources pi apart with intensities 1.0 and 0.2.  Prints the
truth, the exact CRLB next to the paper's Eq. 3 / Eq. 4, the maximum-likelihood
estimate, and the emcee posterior sd next to the CRLB with the model check
(chi^2/dof, posterior predictive p-value); writes the response plot to --out and
the posterior report (corner plot with CRLB ellipses, traces, posterior
predictive and residual panel, ML and truth tables, the Laplace evidence for
K = 0..3 with p(K | data), NetCDF, report.html) to --out/posterior/.  Each part
is printed as soon as it is computed; the posterior run shows a status line on
stderr (steps, tau and the steps it asks for, R-hat) unless --quiet.

Example:
  olsbayes demo
  olsbayes demo --seed 7 --out my-demo --json
  olsbayes demo --print-config > scene.toml     # a template for your own runs
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from .._provenance import provenance
from ..bounds import crlb
from ..build import data_from_config, model_from_config, scene_from_config
from ..config import parse_config
from ._common import (
    DEFAULT_CONFIG,
    add_command,
    add_json_arg,
    add_quiet_arg,
    add_seed_arg,
    emit,
    output_dir,
)
from .crlb import crlb_payload, crlb_text
from .fit import PosteriorRequest, fit_payload, fit_text, posterior_block

__all__ = ["register", "run"]


def register(subparsers: Any) -> None:
    """Add the ``demo`` subcommand and its options to ``subparsers``."""
    p = add_command(subparsers, "demo", help="simulate, fit and bound the Fig. 3 scene",
                    description=__doc__)
    p.add_argument("--out", type=Path, default=Path("olsbayes-demo"), metavar="DIR",
                   help="folder for figures (default: olsbayes-demo/)")
    add_seed_arg(p, help="seed of the simulated readings (default: [data] seed of the scene)")
    p.add_argument("--no-figures", action="store_true", help="do not write figures")
    p.add_argument("--no-posterior", action="store_true",
                   help="skip the emcee posterior (and its report in DIR/posterior/)")
    p.add_argument("--print-config", action="store_true",
                   help="print the demo's TOML configuration and exit")
    add_quiet_arg(p)
    add_json_arg(p)
    p.set_defaults(run=run)


def _figures(out: Path, model: Any, data: Any, truth: Any, estimate: Any) -> list[Path]:
    import matplotlib

    if "matplotlib.pyplot" not in sys.modules:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import atomic_path
    from ..plotting import plot_response

    paths = []
    fig = plot_response(model, data, truth, estimate)
    target = out / "response.png"
    with atomic_path(target) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    paths.append(target)
    return paths


def run(args: argparse.Namespace) -> int:
    """Simulate, fit and bound the Fig. 3 scene; sample its posterior unless --no-posterior.

    Prints the results (text, or JSON with --json); unless --no-figures, writes the
    response plot to --out and the posterior report to --out/posterior/.  With
    --print-config, prints the demo's TOML configuration instead.  Returns the exit
    status 0.
    """
    from ..ml import fit_ml

    if args.print_config:
        sys.stdout.write(DEFAULT_CONFIG)
        return 0
    cfg = parse_config(DEFAULT_CONFIG, source="<demo config>")
    model = model_from_config(cfg)
    truth = scene_from_config(cfg, model).sorted()  # canonical order, as fits report
    seed = args.seed if args.seed is not None else cfg.section("data")["seed"]
    data = data_from_config(cfg, model, truth, rng=seed)
    out = None if args.no_figures else output_dir(args.out)
    bound = crlb(model, truth)
    ml_rng, post_rng, sel_rng = np.random.SeedSequence(seed).spawn(3)
    fit = fit_ml(model, data, truth.n_sources, rng=ml_rng)
    payload = crlb_payload(model, truth, bound)
    payload.update(seed=seed, readings=data, fit=fit_payload(model, fit, truth, data),
                   provenance=provenance(seed=seed, data=data))
    say = _Printer(args)
    say(f"Simulated {model.n_sensors} readings (seed {seed}) of the Fig. 3 scene.",
        crlb_text(model, truth, bound), "",
        f"Maximum-likelihood estimate ({fit.method}), log-likelihood "
        f"{float(fit.log_likelihood):.6g}, chi^2/dof {float(payload['fit']['chi2_dof']):.4g}; "
        "sd = Fisher at the estimate:",
        fit_text(model, fit, truth))
    figs = [] if out is None else _figures(out, model, data, truth, fit.params)
    if not args.no_posterior:
        from ..select import select_k

        report = None if out is None else out / "posterior"
        selection = select_k(model, data, 3, method="laplace", rng=sel_rng,
                             progress=not args.quiet)
        payload["selection"] = selection.to_dict()
        say("", "Evidence for K = 0..3 sources:", selection.table())
        payload["posterior"], post_text = posterior_block(
            model, data, truth.n_sources, truth, post_rng,
            PosteriorRequest(report=report, selection=selection), ml=fit,
            progress=not args.quiet)
        say(post_text)
        if report is not None:
            figs += [report / name for name in ("corner.png", "trace.png", "ppc.png",
                                                "k_posterior.png")]
    if out is not None:
        payload["figures"] = figs
        say("Figures: " + ", ".join(str(p) for p in figs))
    if args.json:
        emit(args, payload, "")
    return 0


class _Printer:
    """Prints text blocks at once (nothing with --json, whose object comes at the end)."""

    def __init__(self, args: argparse.Namespace):
        self.quiet = bool(getattr(args, "json", False))

    def __call__(self, *blocks: str) -> None:
        if not self.quiet:
            sys.stdout.write("\n".join(blocks).rstrip("\n") + "\n")
            sys.stdout.flush()
