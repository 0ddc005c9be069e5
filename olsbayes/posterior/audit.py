"""Posterior summaries (circular for angles) and the audit against the CRLB."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ..bounds import kink_sources
from ..circular import wrap_angle
from ._arviz import summary_frame

__all__ = ["summary", "crlb_check", "CRLBCheck", "at_prior_bound", "BOUND_LEVEL",
           "narrower_than_crlb"]

class PosteriorDraws(Protocol):
    """What the audit reads of a posterior (a :class:`~olsbayes.posterior.PosteriorResult`).

    The audit depends on this shape, not on the result class, whose convenience
    methods call the audit.
    """

    model: Any
    prior: Any
    n_sources: int
    names: tuple[str, ...]
    estimate: np.ndarray
    crlb_cov: np.ndarray
    tau: np.ndarray

    @property
    def n_params(self) -> int:
        """Number P of parameters per draw."""

    @property
    def periodic(self) -> np.ndarray:
        """Which of the P parameters are angles, bool (P,)."""

    @property
    def crlb_std(self) -> np.ndarray:
        """CRLB standard deviations at the estimate, (P,)."""

    def unwrapped_samples(self) -> np.ndarray:
        """Draws (W, D, P) with angles unwrapped around their circular means."""


#: Below this ratio I / sd_CRLB(I) a source counts as low-SNR (nonlinear regime).
LOW_SNR = 10.0
#: A sub-sensor horizon closer than this many CRLB sds makes a source "near the kink".
KINK_SDS = 2.0
#: CRLB |correlation| above which two parameters count as strongly correlated (between
#: two sources: near the resolution limit).
HIGH_CORRELATION = 0.9


#: R-hat above which a parameter counts as poorly mixed: the default
#: ``SamplerOptions.rhat_max`` and ``ImageOptions.rhat_max``, one threshold everywhere.
RHAT_MAX = 1.01
#: Credibility of the highest-density interval that, reaching a prior bound, counts as
#: the posterior piling up there (the level of the summary's HDI).
BOUND_LEVEL = 0.94


def _physical_bound(name: str, bound: float) -> bool:
    """Bounds set by physics, not by the prior: I >= 0, z >= 0, background >= 0, |lat| <= pi/2."""
    base = name.split("[", 1)[0]
    return (base in ("I", "z", "b") and bound == 0.0) or (
        base == "lat" and abs(bound) >= np.pi / 2 - 1e-9)


def _hdi_reaches(x: np.ndarray, lo: float, hi: float, level: float) -> tuple[bool, bool]:
    """Whether the shortest ``level`` interval of draws x (S,) reaches ``lo`` / ``hi``.

    An end counts when fewer than a tenth of the excluded draws lie beyond it
    (the density is highest at that edge) and the extreme draw lies within 5 % of
    the interval's width from the bound.
    """
    s = np.sort(x)
    n = s.size
    m = max(1, int(np.ceil(level * n)))
    start = int(np.argmin(s[m - 1:] - s[: n - m + 1]))
    width = s[start + m - 1] - s[start]
    edge = 0.1 * (n - m)
    low = start <= edge and s[0] - lo <= 0.05 * width
    high = n - m - start <= edge and hi - s[-1] <= 0.05 * width
    return bool(low), bool(high)


def at_prior_bound(draws: np.ndarray, prior, level: float = BOUND_LEVEL) -> tuple[str, ...]:
    """Names of the parameters whose posterior piles up at a bound of their prior.

    Parameters
    ----------
    draws : ndarray (..., P)
        Posterior draws in the flat layout.
    prior : ScenePrior
    level : float
        Credibility of the highest-density interval tested: a parameter is listed
        when that interval reaches a finite prior bound (``_hdi_reaches``).
        Physical bounds (intensity or plate height 0, latitude +-pi/2) and
        periodic coordinates are not tested.
    """
    flat = np.asarray(draws, dtype=float).reshape(-1, prior.n_params)
    out = []
    for j, (name, marg) in enumerate(zip(prior.param_names, prior.marginals)):
        if marg.periodic or flat.shape[0] < 2:
            continue
        lo, hi = float(marg.lower), float(marg.upper)
        test_lo = np.isfinite(lo) and not _physical_bound(name, lo)
        test_hi = np.isfinite(hi) and not _physical_bound(name, hi)
        if test_lo or test_hi:
            low, high = _hdi_reaches(flat[:, j], lo, hi, level)
            if (test_lo and low) or (test_hi and high):
                out.append(name)
    return tuple(out)


def summary(result: PosteriorDraws, hdi_prob: float = 0.94):
    """Posterior table, one row per parameter in layout order.

    Angles are summarised circularly: draws are unwrapped around their circular
    mean before ArviZ computes mean, sd, HDI, ESS and R-hat, and the mean and
    HDI ends are wrapped back to (-pi, pi] (an HDI may then read hi < lo when it
    straddles +-pi).  A source at +-pi thus gets its true sd, not ~pi.

    Returns
    -------
    pandas.DataFrame
        Columns mean, sd, hdi_*, mcse_mean, mcse_sd, ess_bulk, ess_tail, r_hat,
        tau (emcee integrated autocorrelation time of the sampler coordinate,
        steps) and crlb (CRLB sd at the posterior mean).
    """
    per = result.periodic
    frame = summary_frame(result.unwrapped_samples(), list(result.names), hdi_prob=hdi_prob)
    hdi_cols = [c for c in frame.columns if c.startswith("hdi_")]
    for col in ["mean"] + hdi_cols:
        vals = frame[col].to_numpy(dtype=float).copy()
        vals[per] = wrap_angle(vals[per])
        frame[col] = vals
    frame["tau"] = result.tau
    frame["crlb"] = result.crlb_std
    frame.index.name = "parameter"
    return frame


@dataclass(frozen=True)
class CRLBCheck:
    """Posterior sd against the CRLB, per parameter (layout order).

    Attributes
    ----------
    names : tuple of str
    posterior_sd, crlb_sd, ratio, mc_error : ndarray (P,)
        ``ratio = posterior_sd / crlb_sd``; ``mc_error`` its Monte Carlo standard
        error (ArviZ's mcse of the sd over ``crlb_sd``).
    flagged : ndarray of bool (P,)
        ``|ratio - 1| > max(rtol, 3 mc_error)``.
    reasons : tuple of str
        Known causes present for each parameter (empty when none):
        ``unidentifiable`` (CRLB inf); ``prior-dominated`` (CRLB sd > 0.3 prior
        sd); ``near a prior boundary`` (support edge within 3 CRLB sd);
        ``near the resolution limit`` (|CRLB correlation| > 0.9 with a
        parameter of another source); ``strongly correlated`` (> 0.9 within one
        source or with sigma, e.g. a plate's z and I); ``low SNR`` (I / CRLB sd
        of I < 10 for the source); ``near the kink`` (a sub-sensor horizon
        within 2 CRLB sd of the direction); ``poor mixing`` (bulk ESS < 100 or
        R-hat > 1.01, the sampler's own convergence threshold).
    """

    names: tuple[str, ...]
    posterior_sd: np.ndarray
    crlb_sd: np.ndarray
    ratio: np.ndarray
    mc_error: np.ndarray
    flagged: np.ndarray
    reasons: tuple[str, ...]

    @property
    def ok(self) -> bool:
        """True when no parameter is flagged."""
        return not bool(np.any(self.flagged))

    def to_frame(self):
        """A pandas DataFrame with one row per parameter."""
        import pandas as pd

        return pd.DataFrame(
            {"posterior_sd": self.posterior_sd, "crlb_sd": self.crlb_sd, "ratio": self.ratio,
             "mc_error": self.mc_error, "flagged": self.flagged, "reason": list(self.reasons)},
            index=pd.Index(list(self.names), name="parameter"),
        )


def _prior_sd(prior) -> float:
    if prior.periodic:
        return np.pi / np.sqrt(3.0)  # sd of a uniform angle on (-pi, pi]
    u = np.linspace(0.0005, 0.9995, 2000)
    q = prior.ppf(u)
    return float(np.std(q))


def _reasons(result: PosteriorDraws, table, crlb_sd: np.ndarray) -> list[list[str]]:
    p = result.n_params
    w = result.prior.n_loc + 1
    k = result.n_sources
    est = result.estimate
    out: list[list[str]] = [[] for _ in range(p)]
    finite = np.isfinite(crlb_sd)
    cov = np.where(np.isfinite(result.crlb_cov), result.crlb_cov, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cov / np.outer(crlb_sd, crlb_sd)
    np.fill_diagonal(corr, 0.0)
    snr = np.full(k, np.inf)
    for s in range(k):
        snr[s] = est[s * w + w - 1] / crlb_sd[s * w + w - 1]
    kink = _near_kink(result, crlb_sd)
    for j, prior in enumerate(result.prior.marginals):
        src = j // w if j < k * w else None
        if not finite[j]:
            out[j].append("unidentifiable")
        elif crlb_sd[j] > 0.3 * _prior_sd(prior):
            out[j].append("prior-dominated")
        if finite[j] and not prior.periodic and min(
                est[j] - prior.lower, prior.upper - est[j]) < 3 * crlb_sd[j]:
            out[j].append("near a prior boundary")
        if finite[j]:
            out[j].extend(_correlation_reasons(j, corr[j], src, w, k, result.names))
        if src is not None and snr[src] < LOW_SNR:
            out[j].append("low SNR")
        if src is not None and kink[src]:
            out[j].append("near the kink (a sub-sensor horizon within 2 sd)")
        if table["ess_bulk"].iloc[j] < 100 or table["r_hat"].iloc[j] > RHAT_MAX:
            out[j].append("poor mixing")
    return out


def _correlation_reasons(j: int, corr_j: np.ndarray, src: int | None, w: int, k: int,
                         names: tuple[str, ...]) -> list[str]:
    """CRLB correlations above HIGH_CORRELATION.

    With another source's parameter the two sources are near the resolution limit;
    within one source (a plate's z and I, say) or with sigma the bound is strongly
    correlated, no resolution limit involved.
    """
    owner = np.array([i // w if i < k * w else -1 for i in range(corr_j.size)])
    r = np.where(np.isfinite(corr_j), np.abs(corr_j), 0.0)
    r[j] = 0.0
    other_source = (owner >= 0) & (owner != src) if src is not None else np.zeros(r.size, bool)
    out = []
    for label, mask in (("near the resolution limit", other_source),
                        ("strongly correlated", ~other_source)):
        if mask.any() and r[mask].max() > HIGH_CORRELATION:
            i = int(np.flatnonzero(mask)[np.argmax(r[mask])])
            out.append(f"{label} (CRLB |r| = {r[i]:.2f} with {names[i]})")
    return out


def _near_kink(result: PosteriorDraws, crlb_sd: np.ndarray) -> np.ndarray:
    """Per source: a sub-sensor's horizon (c = 0) within KINK_SDS CRLB sd of the direction.

    For distant sources |c| is the sine of the angle to the horizon, compared
    with the largest location sd (rad); for plates only an exact kink counts.
    """
    model, k, w = result.model, result.n_sources, result.prior.n_loc + 1
    if k == 0 or not model.sensitivity.kink:
        return np.zeros(k, bool)
    x = result.estimate[: k * w]
    if model.kind == "position":
        return kink_sources(model, x)
    margin = np.arcsin(np.min(np.abs(model.cosines(x)), axis=-1))  # (K,) rad
    loc_sd = crlb_sd[: k * w].reshape(k, w)[:, :-1]
    loc_sd = np.where(np.isfinite(loc_sd), loc_sd, np.inf).max(axis=1)
    return margin < KINK_SDS * loc_sd


def crlb_check(result: PosteriorDraws, rtol: float = 0.2) -> CRLBCheck:
    """Compare every posterior sd with its CRLB at the posterior mean.

    At high SNR the posterior is Gaussian with covariance ~ the inverse Fisher
    matrix, so the ratio is 1 within Monte Carlo error.  A parameter is flagged
    when ``|ratio - 1| > max(rtol, 3 mc_error)``; ``reasons`` gives the known
    causes present (prior truncation, resolution limit, low SNR, kink, mixing).
    """
    table = summary(result)
    crlb_sd = result.crlb_std
    post_sd = table["sd"].to_numpy(dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = post_sd / crlb_sd
        mc = table["mcse_sd"].to_numpy(dtype=float) / crlb_sd
    flagged = ~(np.abs(ratio - 1.0) <= np.maximum(rtol, 3 * mc))
    reasons = tuple("; ".join(r) for r in _reasons(result, table, crlb_sd))
    return CRLBCheck(names=result.names, posterior_sd=post_sd, crlb_sd=crlb_sd, ratio=ratio,
                     mc_error=mc, flagged=flagged, reasons=reasons)


def narrower_than_crlb(result: PosteriorDraws, rtol: float = 0.2
                       ) -> list[tuple[str, float, float]]:
    """Source parameters whose posterior sd is far below the CRLB at high SNR.

    At high SNR (I / CRLB sd of I >= :data:`LOW_SNR`) the posterior of a smooth
    likelihood is Gaussian with the inverse Fisher covariance, so a posterior sd
    below ``1 - max(rtol, 3 mc)`` times the CRLB (mc: the relative Monte Carlo
    error of an sd from ``W (steps - burn-in) / tau`` effective draws) means the
    walkers did not explore the posterior -- unless a known cause narrows it: a
    prior boundary within 3 CRLB sd of any parameter of the source, a sub-sensor
    horizon (kink) near the direction, an unidentifiable parameter.  Those are not reported here
    (:func:`crlb_check` lists every cause).  Cheap: numpy moments, no ArviZ.

    Returns
    -------
    list of (name, ratio, snr)
        Posterior sd / CRLB sd and the SNR of the parameter's source.
    """
    k, w = result.n_sources, result.prior.n_loc + 1
    if k == 0:
        return []
    x = result.unwrapped_samples()
    n_walkers = x.shape[0]
    sd = x.reshape(-1, x.shape[-1]).std(axis=0, ddof=1)[: k * w]
    crlb_sd = result.crlb_std[: k * w]
    est = result.estimate[: k * w]
    tau = np.maximum(np.asarray(result.tau, dtype=float)[: k * w], 1.0)
    n_eff = np.minimum(n_walkers * (result.n_steps - result.n_burn) / tau, x.shape[0] * x.shape[1])
    mc = 1.0 / np.sqrt(2.0 * np.maximum(n_eff, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = sd / crlb_sd
        snr = np.repeat(est[w - 1 :: w] / crlb_sd[w - 1 :: w], w)
    kink = np.repeat(_near_kink(result, result.crlb_std), w)
    # a parameter within 3 CRLB sd of a prior bound: the CRLB of its whole source is
    # evaluated at a clipped estimate, so none of that source's parameters is reported
    edge = np.array([not prior.periodic and min(est[j] - prior.lower, prior.upper - est[j])
                     < 3 * crlb_sd[j] for j, prior in enumerate(result.prior.marginals[: k * w])])
    edge = np.repeat(edge.reshape(k, w).any(axis=1), w)
    out = []
    for j in range(k * w):
        if (np.isfinite(crlb_sd[j]) and crlb_sd[j] > 0 and snr[j] >= LOW_SNR and not edge[j]
                and not kink[j] and ratio[j] < 1.0 - max(rtol, 3 * mc[j])):
            out.append((result.names[j], float(ratio[j]), float(snr[j])))
    return out
