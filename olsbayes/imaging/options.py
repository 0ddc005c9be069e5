"""Settings of the imaging samplers and MAP search: one frozen, validated record.

Every field is checked when the record is built.  A field left at None takes
its default for the prior (:meth:`ImageOptions.resolve`); a field given must be
one that the prior -- with the sampler and ``n_samples`` chosen -- uses, else
:class:`~olsbayes.errors.InputError`: no setting is ignored silently.

=================  ============================================================
prior              fields used besides ``level`` and ``null_warn``
=================  ============================================================
Gaussian           none (closed form)
NonNegative,       ``n_samples``; when it is not 0 also ``n_chains``, ``n_burn``,
Bounded            ``sampler`` and, with the Gibbs sampler, ``neighbours``, ``window``,
                   ``block``; with the Gibbs sampler and ``n_samples`` unset (the
                   convergence-driven run) also ``ess_min`` and ``max_samples``
Sparse             ``n_samples`` (>= 4), ``n_chains``, ``n_burn``, ``sampler``
(experimental)     (``"gibbs"`` only), ``neighbours``
TwoLevel           ``n_samples`` (0 only), ``neighbours``, ``restarts``, ``reference``
=================  ============================================================
"""

from __future__ import annotations

import dataclasses
import numbers
from dataclasses import dataclass, field

import numpy as np

from .._validation import finite_array, integer, positive_float
from ..errors import InputError
from .priors import ImagingPrior

__all__ = ["ImageOptions", "SAMPLERS", "WITHDRAWN"]

#: Samplers of the box priors.  The eigen-direction Gibbs sampler
#: (:mod:`olsbayes.imaging.eigen`) is not offered: it mixes worse than the default Gibbs
#: sampler on every scene measured (:data:`WITHDRAWN`).
SAMPLERS: tuple[str, ...] = ("hmc", "gibbs")
#: Samplers no longer offered, and why (the measured split R-hat).
WITHDRAWN = {
    "eigen": "it mixes worse than 'gibbs' on every scene measured (largest split R-hat "
             "19 against 1.4 at 200 draws per chain on the Fig. 2 scene, 1.16 against "
             "1.015 on a 12-direction ring); use 'gibbs' or 'hmc'",
}

_DEFAULTS = {"n_samples": 200, "n_chains": 4, "n_burn": 100, "sampler": "gibbs",
             "neighbours": 4, "window": 15, "restarts": 0, "block": 0.01, "ess_min": 400.0,
             "max_samples": 2000}
_BOX = ("nonnegative", "bounded")
_SAMPLING = "sampling (NonNegative and Bounded with n_samples > 0, Sparse)"
_APPLIES = {
    "n_samples": "every prior but Gaussian (closed form)",
    "n_chains": _SAMPLING,
    "n_burn": _SAMPLING,
    "sampler": _SAMPLING,
    "neighbours": "the Gibbs sampler and the TwoLevel search",
    "window": "the Gibbs sampler of NonNegative and Bounded",
    "block": "the Gibbs sampler of NonNegative and Bounded",
    "ess_min": "the convergence-driven run (NonNegative and Bounded, Gibbs, n_samples unset)",
    "max_samples": "the convergence-driven run (NonNegative and Bounded, Gibbs, "
                   "n_samples unset)",
    "restarts": "the TwoLevel search",
    "reference": "the TwoLevel search",
}
_OPTIONAL = tuple(_APPLIES)


@dataclass(frozen=True)
class ImageOptions:
    """Options of :func:`olsbayes.imaging.image`; None means the prior's default.

    Attributes
    ----------
    level : float
        Credibility of the intervals, in (0, 1).
    null_warn : float
        Warn :class:`~olsbayes.errors.NullSpaceWarning` when the share of
        intensity combinations the readings pin less well than the prior's
        scale (``1 - effective_rank / K``, the null space included) exceeds
        this fraction, in (0, 1].
    rhat_max : float
        Warn :class:`~olsbayes.errors.ConvergenceWarning` when the chains'
        largest split R-hat exceeds this (> 1; default 1.01, the threshold of
        :class:`olsbayes.posterior.SamplerOptions`); the convergence-driven
        run samples until its rank-normalised split R-hat is at most this.
    n_samples : int or None
        Draws kept per chain: exactly this many when given.  Unset, NonNegative
        and Bounded with the Gibbs sampler run until converged (``ess_min``,
        ``rhat_max``, ``max_samples``); otherwise the default is 200 (0 for
        TwoLevel, which has no sampler).  0 for NonNegative and Bounded is the
        mode-only path: the
        posterior mode (bounded / nonnegative least squares) and the design
        diagnostics, no sampling; ``mean`` is then the mode and ``sd``,
        ``lower``, ``upper`` and ``rhat`` are NaN (no spread is computed: a
        Gaussian approximation at a mode on the box walls would be wrong).
        Otherwise >= 4.
    n_chains : int or None
        Chains (>= 1; default 4).
    n_burn : int or None
        Discarded sweeps (Gibbs) or trajectories (HMC) per chain (>= 0; default 100).
    sampler : {"gibbs", "hmc"} or None
        Gibbs (single-site, neighbour-pair and window moves; the default and the
        only sampler of Sparse) or exact HMC (Pakman & Paninski; exact, but a
        trajectory can bounce off the walls very many times on large ill-posed
        grids).  ``"eigen"`` is refused (:data:`WITHDRAWN`).
    neighbours : int or None
        Gibbs also trades intensity between each source and its ``neighbours``
        nearest sources (exact moves along ``e_k - e_l``); TwoLevel's search
        also flips up to 4 sources of each source's group of ``2 * neighbours``
        nearest.  0 disables; default 4.
    window : int or None
        Box priors with Gibbs: each sweep also makes exact moves along the slow
        eigen-directions of ``A_B^T A_B`` for every window ``B`` of a source and
        its ``window`` nearest sources -- local patterns the array barely sees
        (:mod:`olsbayes.imaging.window`).  0 disables; default 15.
    block : float or None
        Box priors with Gibbs: the intensities whose sd over the pilot (the
        first half of the burn-in) exceeds ``block * scale`` (the prior's
        scale; for ``Bounded`` with the bound derived from the readings, the
        largest intensity of the mode, if smaller) form a block that every
        sweep also moves jointly by one exact-HMC trajectory
        (:mod:`olsbayes.imaging.block`): the wide, non-local directions of an
        ill-posed design.  >= 0; 0 disables; default 0.01.
    ess_min : float or None
        The convergence-driven run stops when every intensity has bulk and
        tail ESS >= ``ess_min`` and rank-normalised split R-hat <= ``rhat_max``
        (> 0; default 400).
    max_samples : int or None
        Cap on the draws per chain of the convergence-driven run (>= 4;
        default 2000); reaching it unconverged warns
        :class:`~olsbayes.errors.ConvergenceWarning`.
    restarts : int or None
        TwoLevel: extra searches, each from the L1 relaxation rounded at random
        (a source starts bright with probability relaxed value / i_max, drawn
        from ``rng``); the best local optimum is kept (default 0).
    reference : tuple of float, shape (K,), or None
        TwoLevel: a known scene (e.g. the truth of a simulation) whose log
        posterior ``result.search`` reports next to the one found, so a search
        failure (reference better than the scene found) is visible.  Given as
        any 1-D array_like; stored as a tuple.
    """

    level: float = 0.9
    null_warn: float = 0.1
    rhat_max: float = 1.01
    n_samples: int | None = None
    n_chains: int | None = None
    n_burn: int | None = None
    sampler: str | None = None
    neighbours: int | None = None
    window: int | None = None
    restarts: int | None = None
    block: float | None = None
    ess_min: float | None = None
    max_samples: int | None = None
    reference: tuple[float, ...] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        lvl = self.level
        if isinstance(lvl, bool) or not isinstance(lvl, numbers.Real) or not 0 < lvl < 1:
            raise InputError(f"level must be a number in (0, 1); got {lvl!r}")
        object.__setattr__(self, "level", float(lvl))
        object.__setattr__(self, "null_warn",
                           positive_float("null_warn", self.null_warn, upper=1.0))
        rmax = self.rhat_max
        if isinstance(rmax, bool) or not isinstance(rmax, numbers.Real) or not rmax > 1:
            raise InputError(f"rhat_max must be a number > 1; got {rmax!r}")
        object.__setattr__(self, "rhat_max", float(rmax))
        lows = {"n_samples": 0, "n_chains": 1, "n_burn": 0, "neighbours": 0, "window": 0,
                "restarts": 0, "max_samples": 4}
        for name, low in lows.items():
            if getattr(self, name) is not None:
                object.__setattr__(self, name, integer(name, getattr(self, name), low=low))
        if self.block is not None:
            b = self.block
            if isinstance(b, bool) or not isinstance(b, numbers.Real) or not 0 <= b < np.inf:
                raise InputError(f"block must be a finite number >= 0; got {b!r}")
            object.__setattr__(self, "block", float(b))
        if self.ess_min is not None:
            object.__setattr__(self, "ess_min", positive_float("ess_min", self.ess_min))
        s = self.sampler
        if isinstance(s, str) and s.lower() in WITHDRAWN:
            raise InputError(f"sampler {s!r} is not offered: {WITHDRAWN[s.lower()]}")
        if s is not None:
            if not isinstance(s, str) or s.lower() not in SAMPLERS:
                raise InputError(
                    f"sampler must be one of {', '.join(map(repr, SAMPLERS))}; got {s!r}")
            object.__setattr__(self, "sampler", s.lower())
        if self.reference is not None:
            ref = finite_array("reference", self.reference, ndim=1)
            object.__setattr__(self, "reference", tuple(ref.tolist()))

    def resolve(self, prior: ImagingPrior) -> ImageOptions:
        """These options with the defaults for ``prior`` filled in.

        Returns a record whose fields that ``prior`` uses are all set and whose
        other optional fields are None.

        Raises
        ------
        InputError
            A field set that ``prior`` does not use with this sampler and
            ``n_samples``, or an ``n_samples`` or ``sampler`` it cannot honour.
        """
        name = prior.name
        sampler = self.sampler or _DEFAULTS["sampler"]
        n = _n_samples(name, self.n_samples, sampler)
        if name == "sparse" and sampler != "gibbs":
            raise InputError(f"sampler must be 'gibbs' for prior 'sparse' (the spike-and-slab "
                             f"posterior is sampled by Gibbs only); got {sampler!r}")
        used = _used(name, n, sampler)
        for key in _OPTIONAL:
            if getattr(self, key) is not None and key not in used:
                _refuse(key, getattr(self, key), name, n, sampler)
        fill = {key: _DEFAULTS[key] for key in used
                if key in _DEFAULTS and getattr(self, key) is None}
        if "n_samples" in used:
            fill["n_samples"] = n
        return dataclasses.replace(self, **fill)


def _n_samples(prior: str, n_samples: int | None, sampler: str) -> int | None:
    """Draws per chain for ``prior`` (None: closed form, or the convergence-driven run)."""
    if prior == "gaussian":
        return None
    if n_samples is None and prior in _BOX and sampler == "gibbs":
        return None
    if n_samples is None:
        return 0 if prior == "two-level" else _DEFAULTS["n_samples"]
    n = n_samples
    if 0 < n < 4 or (n == 0 and prior == "sparse") or (n > 0 and prior == "two-level"):
        need = {"sparse": ">= 4", "two-level": "0 (MAP only, no sampler)"}
        need = need.get(prior, "0 (mode only) or >= 4")
        raise InputError(f"n_samples must be {need} for prior {prior!r}; got {n_samples!r}")
    return n


def _used(prior: str, n_samples: int | None, sampler: str) -> set[str]:
    """The optional fields that ``prior`` uses with this ``n_samples`` and sampler."""
    if prior == "gaussian":
        return set()
    if prior == "two-level":
        return {"n_samples", "neighbours", "restarts", "reference"}
    if n_samples == 0:
        return {"n_samples"}
    used = {"n_samples", "n_chains", "n_burn", "sampler"}
    if sampler == "gibbs":
        used |= {"neighbours"} if prior == "sparse" else {"neighbours", "window", "block"}
    if n_samples is None:
        used |= {"ess_min", "max_samples"}
    return used


def _refuse(key: str, value: object, prior: str, n_samples: int | None, sampler: str) -> None:
    shown = "" if key == "reference" else f" = {value!r}"
    context = ""
    if prior in ("nonnegative", "bounded") and key not in ("restarts", "reference"):
        context = " with n_samples = 0" if n_samples == 0 else f" with sampler {sampler!r}"
        if key in ("ess_min", "max_samples") and n_samples:
            context = f" with n_samples = {n_samples} (a fixed run)"
    raise InputError(f"{key}{shown} does not apply to prior {prior!r}{context}: it is used by "
                     f"{_APPLIES[key]}; leave it unset")
