"""Corner and trace plots of posterior draws, audited against the CRLB."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InputError

__all__ = ["plot_corner", "plot_trace", "param_labels", "match_truths"]

_UNITS = {"theta": "rad", "lon": "rad", "lat": "rad", "x": "length", "y": "length",
          "z": "length", "I": "reading units", "sigma": "reading units"}
_TEX = {"theta": r"\theta", "lon": r"\lambda", "lat": r"\varphi", "x": "x", "y": "y",
        "z": "z", "I": "I", "sigma": r"\sigma"}


def param_labels(names: list[str] | tuple[str, ...]) -> list[str]:
    r"""Axis labels with units, e.g. ``theta[0]`` -> ``$\theta_{0}$ [rad]``."""
    out = []
    for nm in names:
        base, _, rest = nm.partition("[")
        idx = rest.rstrip("]")
        sym = _TEX.get(base, base) + (f"_{{{idx}}}" if idx else "")
        out.append(f"${sym}$ [{_UNITS.get(base, '')}]")
    return out


def match_truths(result, truths) -> np.ndarray:
    """True parameters (Scene or flat (P,)) relabelled to match the result's sources.

    Sources are matched to the posterior mean by the nearest permutation in
    CRLB-standardised (circular) distance; angles are unwrapped around the
    estimate so they land on the plotted axes.
    """
    from ..circular import unwrap_around
    from ..exchange import best_permutation, pair_costs
    from ..scene import Scene

    x = result.model.pack(truths) if isinstance(truths, Scene) else np.asarray(truths, float)
    p_model = result.model.n_params(result.n_sources)
    if x.shape not in ((p_model,), (result.n_params,)):
        raise InputError(
            f"truths must be a Scene or a flat vector of length {p_model} or {result.n_params}; "
            f"got shape {x.shape}"
        )
    full = np.array(result.estimate, dtype=float)
    full[: x.size] = x
    k, w = result.n_sources, result.prior.n_loc + 1
    per = result.periodic[:w]
    scale = np.where(np.isfinite(result.crlb_std), result.crlb_std, 1.0)[: k * w]
    scale = np.maximum(scale.reshape(k, w).mean(axis=0), 1e-12)
    blocks = full[: k * w].reshape(1, k, w)
    ref = result.estimate[: k * w].reshape(k, w)
    perm = best_permutation(pair_costs(blocks, ref, per, np.broadcast_to(scale, (k, w))))[0]
    full[: k * w] = blocks[0, perm].ravel()
    if x.size < result.n_params:
        full[x.size:] = np.nan
    return unwrap_around(full, result.estimate, result.periodic)


def _ellipse(ax: Any, mean: np.ndarray, cov: np.ndarray, n_sigma: float, **kw: Any) -> None:
    from matplotlib.patches import Ellipse

    # the 2 x 2 eigensystem in closed form: the small axis as det / large, accurate
    # when the two parameters' units differ by many decades (eigh's is not)
    a, b, c = float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])
    big = 0.5 * (a + c) + np.hypot(0.5 * (a - c), b)
    rho2 = b * b / (a * c) if a > 0 and c > 0 else 1.0
    small = max(a * c * (1.0 - rho2), 0.0) / big if big > 0 else 0.0
    angle = 0.5 * np.degrees(np.arctan2(2.0 * b, a - c))
    ax.add_patch(Ellipse(mean, 2 * n_sigma * np.sqrt(big), 2 * n_sigma * np.sqrt(small),
                         angle=angle, fill=False, **kw))


def plot_corner(result, truths=None, crlb: bool = True, fig: Any = None, bins: int = 30) -> Any:
    """Corner plot of the relabelled posterior with the CRLB drawn around the estimate.

    Parameters
    ----------
    result : PosteriorResult
    truths : Scene or ndarray (P,), optional
        Marked in every panel (matched to the posterior's source labels).
    crlb : bool
        Draw the CRLB 1- and 2-sigma ellipses centred on the posterior mean in
        the 2-D panels and the CRLB normal density on the diagonal, so the
        posterior width can be read against the bound at a glance.
    fig : matplotlib Figure, optional
        A figure with P x P axes or none (corner creates the axes).
    bins : int
    """
    import corner

    samples = result.unwrapped_samples().reshape(-1, result.n_params)
    est = np.asarray(result.estimate, dtype=float)
    sd = result.crlb_std
    tru = None if truths is None else match_truths(result, truths)
    lo, hi = samples.min(axis=0), samples.max(axis=0)
    if crlb:
        ok = np.isfinite(sd)
        lo = np.where(ok, np.minimum(lo, est - 2.5 * sd), lo)
        hi = np.where(ok, np.maximum(hi, est + 2.5 * sd), hi)
    if tru is not None:
        fin = np.isfinite(tru)
        lo, hi = np.where(fin, np.minimum(lo, tru), lo), np.where(fin, np.maximum(hi, tru), hi)
    pad = 0.02 * np.maximum(hi - lo, 1e-12)
    ranges = list(zip(lo - pad, hi + pad))
    fig = corner.corner(samples, bins=bins, range=ranges, labels=param_labels(result.names),
                        truths=tru, fig=fig, quantiles=None, show_titles=False,
                        plot_datapoints=False, smooth=None)
    if crlb:
        _draw_crlb(fig, result, est, ranges, samples.shape[0], bins)
    return fig


def _draw_crlb(fig: Any, result, est: np.ndarray, ranges, n: int, bins: int) -> None:
    p = result.n_params
    axes = np.array(fig.axes).reshape(p, p)
    cov = result.crlb_cov
    sd = result.crlb_std
    style = dict(color="crimson", lw=1.0)
    for i in range(p):
        if np.isfinite(sd[i]) and sd[i] > 0:
            x = np.linspace(*ranges[i], 200)
            width = (ranges[i][1] - ranges[i][0]) / bins
            pdf = np.exp(-0.5 * ((x - est[i]) / sd[i]) ** 2) / (np.sqrt(2 * np.pi) * sd[i])
            axes[i, i].plot(x, n * width * pdf, ls="--", **style)
        for j in range(i):
            sub = cov[np.ix_([j, i], [j, i])]
            if np.all(np.isfinite(sub)):
                for s, ls in ((1.0, "-"), (2.0, "--")):
                    _ellipse(axes[i, j], est[[j, i]], sub, s, ls=ls, **style)
    if p > 1:
        axes[0, p - 1].text(0.0, 1.0, "CRLB 1$\\sigma$ (solid), 2$\\sigma$ (dashed)\n"
                            "around the posterior mean", color="crimson", va="top",
                            fontsize=9, transform=axes[0, p - 1].transAxes)


def plot_trace(result, fig: Any = None, max_walkers: int = 32) -> Any:
    """Walker traces (left) and pooled marginal histograms (right), one row per parameter.

    Angles are unwrapped around their circular means (no jumps at +-pi).
    """
    import matplotlib.pyplot as plt

    x = result.unwrapped_samples()
    p = result.n_params
    if fig is None:
        fig = plt.figure(figsize=(9.0, 1.7 * p + 0.6), layout="constrained")
    axes = fig.subplots(p, 2, squeeze=False, gridspec_kw={"width_ratios": [3, 1]})
    labels = param_labels(result.names)
    draws = np.arange(x.shape[1]) * result.thin + result.n_burn
    for j in range(p):
        ax, hx = axes[j]
        ax.plot(draws, x[:max_walkers, :, j].T, lw=0.4, alpha=0.5)
        ax.set_ylabel(labels[j])
        hx.hist(x[..., j].ravel(), bins=40, orientation="horizontal", color="0.4")
        hx.sharey(ax)
        hx.tick_params(labelleft=False)
    axes[-1, 0].set_xlabel(f"step (the first {result.n_burn} removed as burn-in)")
    axes[-1, 1].set_xlabel("count")
    fig.suptitle(f"emcee traces: {x.shape[0]} walkers, burn-in {result.n_burn}, thin {result.thin}")
    return fig
