"""Model-checking figures: posterior predictive band with residuals, and p(K | data)."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["plot_ppc", "plot_k_posterior"]


def _sensor_axis(model) -> tuple[np.ndarray, np.ndarray, str]:
    """x positions, plotting order and axis label of the sub-sensors."""
    if model.kind == "angle":
        x = np.arctan2(model.array.normals[:, 1], model.array.normals[:, 0])
        return x, np.argsort(x), "sub-sensor normal angle (rad)"
    x = np.arange(model.n_sensors, dtype=float)
    return x, np.arange(model.n_sensors), "sub-sensor index"


def plot_ppc(result, level: float = 0.9, fig: Any = None) -> Any:
    """Readings against the posterior predictive band (top) and residuals (bottom).

    Top: the readings, the response at the posterior mean and the central
    ``level`` band of the posterior predictive readings (``idata``'s
    ``posterior_predictive`` group), per sub-sensor.  Bottom: standardised
    residuals ``(y - mu(x_hat)) / sigma`` with the +-2 lines; the title gives
    chi^2/dof and the posterior predictive p-value
    (:func:`olsbayes.posterior.checks.model_check`).

    Parameters
    ----------
    result : PosteriorResult
    level : float
        Credibility of the predictive band, in (0, 1).
    fig : matplotlib Figure, optional
        An empty figure to draw into.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    model, k = result.model, result.n_sources
    data = np.asarray(result.idata.observed_data["obs"].values, dtype=float)
    rep = np.asarray(result.idata.posterior_predictive["obs"].values).reshape(-1, data.size)
    lo, hi = np.quantile(rep, [(1 - level) / 2, (1 + level) / 2], axis=0)
    p_model = model.n_params(k)
    est = np.asarray(result.estimate, dtype=float)
    mu = model.response(est[:p_model])
    sigma = est[-1] if result.prior.noise is not None else model.sigma
    check = result.model_check()
    x, order, label = _sensor_axis(model)
    if fig is None:
        fig = plt.figure(figsize=(7.5, 5.0), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    top.fill_between(x[order], lo[order], hi[order], color="tab:blue", alpha=0.25, step="mid",
                     label=f"posterior predictive {level:.0%}")
    top.plot(x[order], mu[order], "-", color="tab:blue", lw=1.2, label="Eq. 1 at the mean")
    top.plot(x[order], data[order], "o", ms=3, color="0.15", label="readings")
    top.set_ylabel("reading")
    top.legend(loc="best", fontsize="small")
    resid = (data - mu) / sigma
    bottom.axhline(0.0, color="0.5", lw=0.8)
    for s in (-2.0, 2.0):
        bottom.axhline(s, color="0.5", lw=0.8, ls="--")
    bottom.plot(x[order], resid[order], "o", ms=3, color="tab:red")
    bottom.set_ylabel("residual / sigma")
    bottom.set_xlabel(label)
    top.set_title(rf"$\chi^2$/dof = {check.chi2_dof:.3g} (dof {check.dof}), "
                  f"posterior predictive p = {check.ppp:.3g}")
    return fig


def plot_k_posterior(selection, ax: Any = None) -> Any:
    """Bar chart of p(K | data) with log Z_K +- its error per candidate K.

    Parameters
    ----------
    selection : SelectionResult
    ax : matplotlib Axes, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=(5.5, 3.5), layout="constrained")
    else:
        fig = ax.figure
    ks = np.asarray(selection.ks)
    probs = np.asarray(selection.probabilities)
    colours = ["tab:orange" if k == selection.best else "tab:blue" for k in ks]
    ax.bar(ks, probs, color=colours)
    for k, p, ev in zip(ks, probs, selection.evidences):
        err = "" if not (np.isfinite(ev.error) and ev.error > 0) else f" ± {ev.error:.2g}"
        ax.text(k, p, f"log Z {ev.log_evidence:.1f}{err}\n{ev.method}", ha="center",
                va="bottom", fontsize=7)
    ax.set_xticks(ks)
    ax.set_xlabel("number of sources K")
    ax.set_ylabel("p(K | data)")
    ax.set_ylim(0, 1.25)
    ax.set_title(f"best K = {selection.best} ({selection.method})")
    return fig
