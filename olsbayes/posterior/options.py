"""Run settings of :func:`olsbayes.posterior.sample`: one frozen, validated record."""

from __future__ import annotations

import numbers
from collections.abc import Sequence
from dataclasses import dataclass

from .._validation import flag, integer, positive_float
from ..errors import InputError
from .modes import ModeOptions

__all__ = ["SamplerOptions", "MOVES", "emcee_moves"]

#: Names of the built-in emcee move sets accepted as ``SamplerOptions.moves``.
MOVES = ("de", "de-snooker", "stretch")


def _check_moves(moves: object) -> object:
    """``moves`` unchanged if valid, else InputError.

    Valid: a name of :data:`MOVES`, an emcee ``Move``, or a sequence of moves or of
    ``(move, weight)`` pairs with weights > 0 (emcee's own forms).
    """
    if isinstance(moves, str):
        if moves not in MOVES:
            raise InputError(f"moves must be one of {MOVES} or emcee moves; got {moves!r}")
        return moves
    from emcee.moves import Move  # emcee is imported only when moves are given as objects

    if isinstance(moves, Move):
        return moves
    items = list(moves) if isinstance(moves, Sequence) else []
    pairs = [m if isinstance(m, tuple) and len(m) == 2 else (m, 1.0) for m in items]
    ok = bool(pairs) and all(
        isinstance(m, Move) and isinstance(w, numbers.Real) and not isinstance(w, bool)
        and w > 0 for m, w in pairs)
    if not ok:
        raise InputError(
            f"moves must be one of {MOVES}, an emcee Move, or a non-empty sequence of moves "
            f"or of (move, weight > 0) pairs; got {moves!r}")
    return moves


@dataclass(frozen=True)
class SamplerOptions:
    """How long to run the emcee ensemble, what to keep, and which moves to use.

    Every field is checked on construction (an :class:`~olsbayes.errors.InputError`
    naming the field); ``n_walkers`` is checked against the number of parameters
    P by :func:`~olsbayes.posterior.sample`, before any work.

    Attributes
    ----------
    n_walkers : int or None
        Walkers of the ensemble; None: ``max(32, 4 P)``.  At least ``2 P``.
    max_steps : int
        Step limit (>= 1); if reached before convergence a
        :class:`~olsbayes.errors.ConvergenceWarning` is issued.
    n_steps : int or None
        Run exactly this many steps instead (>= 1; no early stop, no warning;
        ``converged`` still reports whether the tau criterion holds).
    tau_multiple : float
        Run until ``steps >= tau_multiple * max(tau)`` (> 0), tau the integrated
        autocorrelation time (steps), checked every ``check_every`` steps.
    rhat_max : float or None
        Also require the rank-normalised split R-hat of the relabelled draws
        (walkers as chains) below this (> 0); None drops the requirement.
    check_every : int
        Steps between convergence checks (>= 1).
    n_burn : int or None
        Steps discarded as burn-in, 0 <= n_burn < the step limit (``n_steps`` or
        ``max_steps``); honoured exactly when the run is longer.  None:
        ``ceil(5 max(tau))``, at most half the chain.  A run that stops early (its
        convergence criteria held) at or before an explicit ``n_burn`` keeps its
        second half, with a :class:`~olsbayes.errors.ConvergenceWarning`.
    thin : int
        Keep every ``thin``-th step (>= 1; more if needed to keep <= 5000 draws
        per walker).
    moves : {"de", "de-snooker", "stretch"} or emcee moves
        "de": emcee's differential-evolution ``DEMove``, whose autocorrelation
        times on these posteriors are much shorter than those of the
        affine-invariant ``"stretch"`` move; "de-snooker": the mixture
        ``DEMove`` 0.8 + ``DESnookerMove`` 0.2 (emcee's suggestion for
        multimodal targets; its snooker step loops over the walkers in Python).
        emcee ``Move`` objects (or a sequence of moves or ``(move, weight)``
        pairs) are passed to emcee as given.
    vectorize : bool
        One log-posterior call per ensemble step (True) or per walker (False).
    relabel_sources : bool
        Fix the labels of exchangeable sources (True).  False keeps the raw,
        exchangeable draws (e.g. to check them against the prior).
    use_likelihood : bool
        False samples the prior (a check of the sampler itself).
    multimodal : bool or None
        The multimodal sampler (:mod:`olsbayes.posterior.multimodal`: one
        ensemble per mode, modes weighted by their evidence, ``result.modes``):
        True always, False never (a near-antipodal ring pair then warns
        :class:`~olsbayes.errors.AntipodalWarning`), None (default) when the
        ML fit or the default run shows signs of several modes and the mode
        search finds them -- a rival ML optimum, a near-antipodal ring pair, a
        near-singular Fisher matrix, a posterior sd far below the CRLB -- with a
        :class:`~olsbayes.errors.MultimodalWarning` saying so.  Needs a start
        point (None, an MLResult or a point).
    modes : ModeOptions
        Settings of the mode search and of the evidence weights.
    """

    n_walkers: int | None = None
    max_steps: int = 20000
    n_steps: int | None = None
    tau_multiple: float = 50.0
    rhat_max: float | None = 1.01
    check_every: int = 100
    n_burn: int | None = None
    thin: int = 1
    moves: object = "de"
    vectorize: bool = True
    relabel_sources: bool = True
    use_likelihood: bool = True
    multimodal: bool | None = None
    modes: ModeOptions = ModeOptions()

    def __post_init__(self) -> None:
        checked = {
            "n_walkers": None if self.n_walkers is None else integer(
                "n_walkers", self.n_walkers, low=2),
            "max_steps": integer("max_steps", self.max_steps, low=1),
            "n_steps": None if self.n_steps is None else integer(
                "n_steps", self.n_steps, low=1),
            "tau_multiple": positive_float("tau_multiple", self.tau_multiple),
            "rhat_max": None if self.rhat_max is None else positive_float(
                "rhat_max", self.rhat_max),
            "check_every": integer("check_every", self.check_every, low=1),
            "n_burn": None if self.n_burn is None else integer("n_burn", self.n_burn, low=0),
            "thin": integer("thin", self.thin, low=1),
            "moves": _check_moves(self.moves),
            "vectorize": flag("vectorize", self.vectorize),
            "relabel_sources": flag("relabel_sources", self.relabel_sources),
            "use_likelihood": flag("use_likelihood", self.use_likelihood),
            "multimodal": None if self.multimodal is None else flag("multimodal",
                                                                     self.multimodal),
        }
        if not isinstance(self.modes, ModeOptions):
            raise InputError(f"modes must be an olsbayes.posterior.ModeOptions; got "
                             f"{type(self.modes).__name__}")
        for name, value in checked.items():
            object.__setattr__(self, name, value)
        if self.n_burn is not None and self.n_burn >= self.step_limit:
            which = "n_steps" if self.n_steps is not None else "max_steps"
            raise InputError(f"n_burn must be < {which} = {self.step_limit} (some steps must "
                             f"remain after the burn-in); got {self.n_burn}")

    @property
    def step_limit(self) -> int:
        """Steps the run may take: ``n_steps`` when fixed, else ``max_steps``."""
        return self.max_steps if self.n_steps is None else self.n_steps


def emcee_moves(moves: object) -> object:
    """The emcee move object(s) of a checked ``SamplerOptions.moves`` (new ones per call)."""
    if not isinstance(moves, str):
        return moves
    import emcee

    if moves == "de":
        return emcee.moves.DEMove()
    if moves == "de-snooker":
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    return emcee.moves.StretchMove()
