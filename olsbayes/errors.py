"""Exception and warning classes used at every public boundary.

Every error a user can provoke with bad input is an :class:`OlsBayesError`, a
subclass of :class:`ValueError`, whose message names the argument, the value
received and the accepted range.  Known failure regions of a method raise a
specific :class:`OlsBayesWarning` subclass through :func:`warnings.warn`.
"""

from __future__ import annotations

__all__ = [
    "OlsBayesError",
    "InputError",
    "ConfigError",
    "OlsBayesWarning",
    "ResolutionWarning",
    "NearResolutionWarning",
    "KinkWarning",
    "ConvergenceWarning",
    "EvidenceWarning",
    "NullSpaceWarning",
    "MultimodalWarning",
    "AntipodalWarning",
    "PriorBoundWarning",
]


class OlsBayesError(ValueError):
    """Base class of every error raised for bad user input."""


class InputError(OlsBayesError):
    """An argument of a public function is out of its accepted range."""


class ConfigError(OlsBayesError):
    """A configuration (TOML) file is malformed or holds unknown keys."""


class OlsBayesWarning(UserWarning):
    """Base class of the package's warnings."""


class ResolutionWarning(OlsBayesWarning):
    """Sources closer than the array can resolve: the Fisher matrix is singular."""


class NearResolutionWarning(ResolutionWarning):
    """Sources near the resolution limit, or a weak source: Gaussian errors do not hold.

    The Fisher matrix is regular, but the posterior is not one Gaussian (flat
    valleys, rival optima, a bound at zero) and Fisher (CRLB) intervals cover the
    truth far less often than stated; see :mod:`olsbayes.resolution`.
    """


class KinkWarning(OlsBayesWarning):
    """A source lies on the kink of the clipped cosine (a sub-sensor 90 deg away)."""


class ConvergenceWarning(OlsBayesWarning):
    """An optimiser or sampler stopped before its convergence criterion held."""


class EvidenceWarning(OlsBayesWarning):
    """Two evidence estimates disagree, or one is not to be trusted."""


class NullSpaceWarning(OlsBayesWarning):
    """An imaging problem whose readings leave many intensity combinations to the prior."""


class MultimodalWarning(OlsBayesWarning):
    """A distinct local optimum fits almost as well as the estimate.

    The likelihood is multimodal there and Fisher (CRLB) errors understate the uncertainty.
    """


class AntipodalWarning(MultimodalWarning):
    """Two ring sources are nearly antipodal: mirrored configurations fit almost as well.

    See :mod:`olsbayes.antipodal`: the readings barely constrain the pair's offset
    from antipodal, and a sampler started in one configuration reports that one only.
    """


class PriorBoundWarning(OlsBayesWarning):
    """A posterior piles up at a bound of its prior.

    The prior, not the data, then limits the estimate: its mean and sd describe the
    bound (raise it, or derive it from the data).
    """
