"""Settings of the fast ML fit: one frozen, validated record with per-K defaults.

Every knob of :mod:`olsbayes.ml.fast.pipeline` lives here.  A field left at None
takes its default for the number of sources K and the model
(:meth:`FastOptions.resolve`); a field given is validated before any work.

The defaults, and why:

* ``n_coarse``: coarse atom subsets searched exhaustively over K-tuples -- 3 up
  to K = 3, 24 from K = 4 on, where the likelihood has many shallow cells and
  near-ambiguous configurations far apart in angle compete, and three subsets
  stopped a few per cent of fits of random scenes short of the global optimum.
* ``pursuit``: matching pursuit + alternating projection and its runners-up as
  candidates besides the tuples -- everywhere but K = 4, where the 24 subsets'
  tuples already reach the optimum as often and the pursuit's starts cost a
  quarter of the fit (with ``n_coarse = 0`` the pursuit always runs).
* ``distinct_modes``: each coarse subset also gives its best tuple of a second,
  distinct mode -- at K = 3, where near-equilateral scenes have a rotated alias
  that the best coarse tuple often picks.
* ``tuple_budget``: K-tuples per coarse subset (which sets its size): 5,000, or
  3,000 where the second modes are searched too.
* ``single_precision``: tuple scores in float32 at K = 4 (they only rank coarse
  candidates for the float64 refinement; twice the lanes per vector instruction).
* ``escalate``: fits with close or lopsided sources refitted by exact enumeration
  (:mod:`olsbayes.ml.fast.escalate`) -- K = 2, 3 on rings with the clipped cosine,
  where the search alone missed the global optimum of such fits, up to
  :data:`ESCALATE_CONFIGURATIONS` configurations per data vector (about half a
  second; even rings up to N = 2234 for K = 2 and N = 194 for K = 3, odd rings
  half that) and within the memory budget of the enumeration's O(N^2) arrays.
  Beyond, a refit would cost minutes to hours per fit (K = 3 on a 1000-ring: 1.3e9
  configurations), and the fit is the search's.
* ``runners_up``: runner-up positions per source as candidates -- 2, none where
  the second modes are searched and the escalation covers close fits (K = 3 on
  such rings).
* ``kink_hops``: one round of starts just past the nearest sub-sensor horizon of
  each source -- K >= 2 on planar arrays with a kinked law, whose likelihood has
  shallow minima in neighbouring smooth cells about one CRLB std apart.
* ``scatter``: fixed configurations spread over the whole source space, refined
  by LM (:mod:`~olsbayes.ml.fast.scatter`) -- 300 from K = 5 on, where optima of
  nearly equal height differ in several sources at once and the grid search
  alone often stops in one that is not the global optimum; ``distinct_modes``
  from K = 5 on too, for the same reason.
* ``slide``: the sliding search (:mod:`~olsbayes.ml.fast.slide`) from the best
  distinct optima found, from K = 5 on: moves of one or two sources to the atoms
  best correlated with the residual reach optima that the scattered starts alone
  miss, at a cost polynomial in K.  16 starts; on planar arrays (rings), whose
  readings fix sums of source phasors per arc, the optima nearly as high as the
  best multiply with K, and so does the share of fits that one sliding path from
  each of 16 starts leaves short of the best: there twice as many starts with
  each source beyond six, up to 64 (K >= 8).  On spheres the fits that 16 starts
  leave short are a few 1e-4 nats from the best: the same optimum.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ..._validation import flag, integer, nonnegative_float, positive_float
from ...errors import InputError
from ...geometry import Ring
from ...sensitivity import is_clipped_cosine

__all__ = ["FastOptions", "ESCALATE_CONFIGURATIONS"]

#: Largest enumeration (configurations per data vector) the default escalation runs.
ESCALATE_CONFIGURATIONS = 10_000_000


def _affordable(model, k: int) -> bool:
    """Whether an escalated refit of K sources stays within the defaults' budgets."""
    from ..._budget import memory_limit
    from ..exact import design_bytes, n_configurations

    return (n_configurations(model, k) <= ESCALATE_CONFIGURATIONS
            and design_bytes(model) <= memory_limit())


@dataclass(frozen=True)
class FastOptions:
    """Options of ``fit_ml(method="fast")``; None means the default for K (see module).

    Attributes
    ----------
    n_restarts : int
        Deterministic perturbed restarts around the refined optimum (0..64).
    restart_scale : float
        Their size in grid steps (> 0).
    max_iter : int
        Iteration cap of each Levenberg–Marquardt run (>= 1).
    n_coarse : int or None
        Coarse atom subsets searched over all K-tuples (0..64; 0 = pursuit only).
    tuple_budget : int or None
        K-tuples per coarse subset (>= 1).
    distinct_modes : bool or None
        Each subset also gives its best tuple of a second, distinct mode.
    pursuit : bool or None
        Matching pursuit, alternating projection and runners-up as candidates.
    runners_up : int or None
        Runner-up positions per source added as candidates (0..16).
    single_precision : bool or None
        Score the K-tuples in float32.
    max_sweeps : int
        Alternating-projection sweeps at most (>= 1).
    kink_cuts : bool
        LM steps are cut at the first sub-sensor horizon they cross (rings with
        the clipped cosine).  On a sphere a cut costs one more evaluation on nearly
        every step, so there only the final polish cuts steps and holds sources
        on horizons (:func:`~olsbayes.ml.fast.refine.kink_polish`).
    dedupe_tol : float
        A run stops within this distance (max norm, rad and intensity units) of an
        optimum already found for its data (>= 0; 0 turns it off).
    cell_stop : bool
        ... and on entering the linear cell of one (rings with the clipped cosine).
    kink_hops : bool or None
        Starts just past each source's nearest sub-sensor horizon.
    escalate : bool or None
        Refit close or lopsided fits by exact enumeration (rings with the clipped
        cosine, K <= 4).
    scatter : int or None
        Fixed spread-out configurations refined by LM after the search (0..100,000).
    slide : int or None
        Distinct optima the sliding search starts from (0..64; 0 = off).
    slide_sweeps : int
        Its sweeps of moves at most (>= 1).
    close_spacings : float
        Escalated: fitted sources closer than this many sensor spacings (> 0).
    weak_ratio : float
        ... or a weakest intensity below this fraction of the strongest (>= 0).
    """

    n_restarts: int = 4
    restart_scale: float = 3.0
    max_iter: int = 300
    n_coarse: int | None = None
    tuple_budget: int | None = None
    distinct_modes: bool | None = None
    pursuit: bool | None = None
    runners_up: int | None = None
    single_precision: bool | None = None
    max_sweeps: int = 8
    kink_cuts: bool = True
    dedupe_tol: float = 1e-4
    cell_stop: bool = True
    kink_hops: bool | None = None
    escalate: bool | None = None
    scatter: int | None = None
    slide: int | None = None
    slide_sweeps: int = 16
    close_spacings: float = 4.0
    weak_ratio: float = 0.01

    def __post_init__(self) -> None:
        checks = {
            "n_restarts": lambda v: integer("n_restarts", v, low=0, high=64),
            "restart_scale": lambda v: positive_float("restart_scale", v),
            "max_iter": lambda v: integer("max_iter", v, low=1, high=100_000),
            "n_coarse": lambda v: integer("n_coarse", v, low=0, high=64),
            "tuple_budget": lambda v: integer("tuple_budget", v, low=1, high=10**8),
            "runners_up": lambda v: integer("runners_up", v, low=0, high=16),
            "scatter": lambda v: integer("scatter", v, low=0, high=100_000),
            "slide": lambda v: integer("slide", v, low=0, high=64),
            "slide_sweeps": lambda v: integer("slide_sweeps", v, low=1, high=1000),
            "max_sweeps": lambda v: integer("max_sweeps", v, low=1, high=1000),
            "dedupe_tol": lambda v: nonnegative_float("dedupe_tol", v),
            "close_spacings": lambda v: positive_float("close_spacings", v),
            "weak_ratio": lambda v: nonnegative_float("weak_ratio", v),
        }
        for name, check in checks.items():
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, check(value))
        for name in ("distinct_modes", "pursuit", "single_precision", "kink_cuts",
                     "cell_stop", "kink_hops", "escalate"):
            value = getattr(self, name)
            if value is not None:  # a plain bool: the kernels see one type
                object.__setattr__(self, name, flag(name, value))

    def resolve(self, model, k: int) -> FastOptions:
        """These options with every None replaced by its default for K sources.

        The result is kept in the model's memo (both are immutable), so repeated fits
        resolve once.

        Raises
        ------
        InputError
            ``escalate=True`` for a model the exact enumeration does not cover, or
            ``kink_hops=True`` for one without sub-sensor horizons in its likelihood.
        """
        return model.memo(("fast_options", self, k), lambda: self._resolve(model, k))

    def _resolve(self, model, k: int) -> FastOptions:
        ring_cosine = isinstance(model.array, Ring) and is_clipped_cosine(model.sensitivity)
        if self.escalate and not (ring_cosine and k <= 4):
            raise InputError("escalate=True needs a Ring model with the clipped cosine and "
                             f"n_sources <= 4; got {type(model.array).__name__} with "
                             f"{model.sensitivity!r} and n_sources = {k}")
        if self.escalate:
            from ..exact import check_design_memory

            check_design_memory(model, "escalate=True")
        if self.kink_hops and not (model.kind == "angle" and model.sensitivity.kink):
            raise InputError("kink_hops=True needs a planar array (angles) and a law with a "
                             f"kink; got {model.kind!r} sources and {model.sensitivity!r}")
        distinct = (k == 3 or k >= 5) if self.distinct_modes is None else self.distinct_modes
        escalate = (ring_cosine and k in (2, 3) and _affordable(model, k)
                    if self.escalate is None else self.escalate)
        hops = (k >= 2 and model.kind == "angle" and model.sensitivity.kink
                if self.kink_hops is None else self.kink_hops)
        planar = model.kind == "angle"
        pick = {
            "n_coarse": 3 if k <= 3 else 24,
            "tuple_budget": 3_000 if distinct else 5_000,
            "distinct_modes": distinct,
            "pursuit": k != 4,
            "runners_up": 0 if distinct and escalate else 2,
            "single_precision": k == 4,
            "kink_hops": hops,
            "escalate": escalate,
            "scatter": 300 if k >= 5 else 0,
            "slide": 0 if k < 5 else 16 * 2 ** (min(max(k - 6, 0), 2) if planar else 0),
        }
        return dataclasses.replace(self, **{name: value for name, value in pick.items()
                                            if getattr(self, name) is None})
