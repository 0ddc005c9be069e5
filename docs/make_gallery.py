"""Refresh the gallery's figures: run the analyses (quick sizes) and keep their PNGs.

Each script of ``analyses/`` runs with its default (quick) sizes into a temporary
folder; its figures are stored in ``docs/gallery/<script>.png`` (or
``<script>-<name>.png`` when it draws several) as 256-colour PNGs, small enough
to keep in the repository: the analyses take minutes each, too long for a
documentation build.  The documentation build
(``docs/hooks.py``) then shows every script's summary, command and figures on the
gallery page.  Slow: minutes per script; run it when an analysis changes::

    python docs/make_gallery.py                      # every analysis
    python docs/make_gallery.py fig3_crlb k4_threshold
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GALLERY = ROOT / "docs" / "gallery"

#: Extra arguments per analysis (the rest run with their defaults).
ARGS = {
    "resolution_limit": ["--quick"],
    "fig2_imaging": ["--mode-only", "--sensors", "linspace"],
}
#: Analyses that print tables but draw no figure (the gallery shows their summary only).
NO_FIGURE = ("fig2_two_level_gibbs", "ml_global_check")  # the same list in docs/hooks.py


def scripts(names: list[str]) -> list[Path]:
    """The analysis scripts to run (all but the helpers when ``names`` is empty)."""
    every = sorted(p for p in (ROOT / "analyses").glob("*.py")
                   if not p.name.startswith("_") and p.stem not in NO_FIGURE)
    return [p for p in every if not names or p.stem in names]


def shrink(source: Path, target: Path) -> None:
    """Save a figure as a 256-colour PNG (median-cut palette, no dithering)."""
    from PIL import Image

    with Image.open(source) as image:
        small = image.convert("RGB").quantize(
            colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
        small.save(target, optimize=True)


def run(script: Path) -> list[Path]:
    """Run one analysis into a temporary folder; copy its PNGs into the gallery."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, str(script), "--out", tmp, *ARGS.get(script.stem, [])]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, cwd=ROOT)
        print(f"{script.stem}: {time.perf_counter() - t0:.0f} s", flush=True)
        pngs = sorted(Path(tmp).rglob("*.png"))
        out = []
        for png in pngs:
            name = script.stem if len(pngs) == 1 else f"{script.stem}-{png.stem}"
            target = GALLERY / f"{name}.png"
            shrink(png, target)
            out.append(target)
        return out


def main(argv: list[str]) -> int:
    """Run the analyses named in ``argv`` (every one when empty); 0 on success."""
    GALLERY.mkdir(parents=True, exist_ok=True)
    for script in scripts(argv):
        for path in run(script):
            print("wrote", path.relative_to(ROOT), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
