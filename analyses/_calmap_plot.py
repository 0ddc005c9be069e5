"""The calibration map's figure: one panel per (method, group of cells).

Colour: 90 % coverage minus 0.9 (white = nominal, red = too narrow, i.e.
overconfident, blue = too wide); mark: a tick where the method is calibrated
(SBC p > 0.01 and both coverages within 0.03 of nominal), a cross where it
fails, "?" where the scenes are too few to tell; grey: the method does not
apply.  Text: the 90 % coverage and, for failing cells, the SBC p-value.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_map"]

MARK = {"calibrated": "\u2713", "fails": "\u2717", "undecided": "?"}


def _panel(ax, rows: list[dict], norm, cmap) -> None:
    xs = sorted({r["x"] for r in rows})
    ys = sorted({r["snr"] for r in rows})
    img = np.full((len(ys), len(xs)), np.nan)
    for r in rows:
        i, j = ys.index(r["snr"]), xs.index(r["x"])
        if r["state"]:
            img[i, j] = r["cov90"] - 0.9
        txt = "n/a" if not r["state"] else f"{MARK[r['state']]}\n{r['cov90']:.2f}"
        if r["state"] == "fails" and r["sbc_p"] <= 0.01:
            txt += f"\np={r['sbc_p']:.0e}"
        dark = bool(r["state"]) and not 0.15 < norm(r["cov90"] - 0.9) < 0.85
        ax.text(j, i, txt, ha="center", va="center", fontsize=6.5,
                color="white" if dark else "black")
    ax.set_facecolor("0.85")
    ax.imshow(np.ma.masked_invalid(img), cmap=cmap, norm=norm, origin="lower",
              aspect="auto")
    ax.set_xticks(range(len(xs)), [f"{x:g}" for x in xs], fontsize=7)
    ax.set_yticks(range(len(ys)), [f"{y:g}" for y in ys], fontsize=7)


def plot_map(rows: list[dict], path: Path, mode: str, n: int) -> None:
    """Write the map of ``rows`` (from ``calibration_map.summarise``) to ``path``."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm

    methods = list(dict.fromkeys(r["method"] for r in rows))
    grps = list(dict.fromkeys(r["group"] for r in rows))
    widths = [max(2, len({r["x"] for r in rows if r["group"] == g})) for g in grps]
    fig, axes = plt.subplots(len(methods), len(grps), squeeze=False,
                             figsize=(0.62 * sum(widths) + 0.5 * len(grps) + 2.0,
                                      2.0 * len(methods) + 1.2),
                             gridspec_kw=dict(wspace=0.45, hspace=0.35, width_ratios=widths))
    norm, cmap = TwoSlopeNorm(vmin=-0.9, vcenter=0.0, vmax=0.1), plt.get_cmap("RdBu")
    for i, m in enumerate(methods):
        for j, g in enumerate(grps):
            ax = axes[i, j]
            sub = [r for r in rows if r["method"] == m and r["group"] == g]
            if sub:
                _panel(ax, sub, norm, cmap)
            else:  # a study not run (yet)
                ax.text(0.5, 0.5, "not run", ha="center", va="center", fontsize=7,
                        transform=ax.transAxes)
                ax.set_xticks([])
                ax.set_yticks([])
            if i == 0:
                ax.set_title(g, fontsize=8)
            if i == len(methods) - 1:
                xname = sub[0]["x_name"] if sub else ""
                ax.set_xlabel("pair's gap from pi\n(spacings, bin from)" if xname == "antipodal"
                              else "separation\n(spacings)", fontsize=7)
            if j == 0:
                ax.set_ylabel(f"{m}\nSNR per source", fontsize=8)
    sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
    fig.colorbar(sm, ax=axes, shrink=0.6, fraction=0.02, pad=0.015, label="90 % coverage - 0.9")
    fig.suptitle(f"Calibration map ({mode}: {n} scenes per cell)\n\u2713 calibrated "
                 "(SBC p > 0.01, coverage within 0.03), \u2717 fails, ? undecided\n"
                 "text: 90 % coverage", fontsize=8)
    fig.savefig(path, dpi=130)
    plt.close(fig)
