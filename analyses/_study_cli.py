"""Command-line plumbing shared by the study analyses (speed_vs_accuracy, stability,
calibration): --full, --out, executor options, and running one study per group
with its own checkpoint so an interrupted analysis resumes where it stopped."""

from __future__ import annotations

import argparse
from pathlib import Path

from olsbayes import run_study
from olsbayes._io import ensure_dir

__all__ = ["parser", "study", "slug", "table"]


def parser(name: str, doc: str, full_help: str = "paper-size run") -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("--full", action="store_true", help=full_help)
    ap.add_argument("--out", type=Path, default=Path("out") / name, help="output folder")
    ap.add_argument("--executor", default="processes",
                    choices=("serial", "threads", "processes", "dask"))
    ap.add_argument("--workers", type=int, default=2, help="local workers")
    ap.add_argument("--scheduler", default=None, help="Dask scheduler address")
    ap.add_argument("--seed", type=int, default=20260123, help="root seed")
    ap.add_argument("--no-progress", action="store_true")
    return ap


def study(args: argparse.Namespace, tag: str, trial, grid: dict, n_trials: int,
          fixed: dict | None = None, seed_offset: int = 0, chunk_size: int | None = None):
    """Run (or resume) one study, checkpointed and saved under ``args.out``."""
    out = ensure_dir(args.out)
    mode = "full" if args.full else "quick"
    return run_study(
        trial, grid, n_trials, fixed=fixed,
        executor="dask" if args.scheduler else args.executor,
        workers=args.workers, scheduler=args.scheduler,
        checkpoint=out / f"{tag}-{mode}.ckpt", out=out / f"{tag}-{mode}.nc",
        rng=args.seed + seed_offset, progress=not args.no_progress, chunk_size=chunk_size,
    )


def slug(label: str) -> str:
    """A file-name part from an estimator label, e.g. "multistart(n_starts=5)" ->
    "multistart-n_starts5"."""
    return label.replace("(", "-").replace(")", "").replace("=", "").replace(", ", "-")


def table(header: list[str], rows: list[list], digits: int = 3) -> str:
    """Aligned plain-text table."""
    def cell(v):
        if isinstance(v, float):
            return f"{v:.{digits}g}"
        return str(v)
    cells = [header] + [[cell(v) for v in r] for r in rows]
    w = [max(len(r[i]) for r in cells) for i in range(len(header))]
    lines = ["  ".join(c.rjust(x) for c, x in zip(r, w)) for r in cells]
    lines.insert(1, "  ".join("-" * x for x in w))
    return "\n".join(lines)
