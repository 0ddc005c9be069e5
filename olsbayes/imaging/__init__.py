"""Imaging mode: intensities of sources at known directions (Fig. 2 of the paper).

With the directions fixed, Eq. 1 is linear in the intensities, ``s = A I +
noise``; :func:`image` returns their posterior under a prior object --
:class:`Gaussian` (closed form, with evidence), :class:`NonNegative`,
:class:`Bounded` or :class:`TwoLevel` (each intensity 0 or i_max; the MAP scene
of a local search), and the experimental :class:`Sparse` (spike-and-slab; not
offered by name, see ``olsbayes.imaging.priors.WITHDRAWN``) -- with the sampler
settings in one :class:`ImageOptions`, plus the design matrix's rank,
conditioning and null space: what the array cannot see.  A box prior given
without ``i_max`` takes its bound from the readings (:func:`data_bound`), and
every result flags (and warns about) a posterior that piles up at its bound.

    >>> from olsbayes.imaging import Bounded, ImageOptions, image
    >>> res = image(model, data, directions, Bounded(i_max=2.0),
    ...             options=ImageOptions(n_samples=400), rng=1)  # doctest: +SKIP
    >>> res.summary()          # one row per direction (pandas)     # doctest: +SKIP
    >>> res.save("image.nc"); ImageResult.load("image.nc")          # doctest: +SKIP
"""

from .binary import BinaryMap, two_level_log_posterior, two_level_map
from .binary_gibbs import WITHDRAWN as _GIBBS_WITHDRAWN
from .binary_gibbs import credible_sets
from .core import image
from .design import Design, analyse_design, check_directions, design_matrix
from .eigen import eigen_gibbs
from .gaussian import GaussianPosterior, gaussian_posterior
from .neighbours import neighbour_groups, neighbour_pairs
from .options import SAMPLERS, ImageOptions
from .priors import (
    PRIORS,
    Bounded,
    Gaussian,
    ImagingPrior,
    NonNegative,
    Sparse,
    TwoLevel,
    data_bound,
    with_data_bound,
)
from .result import ImageResult, hpd_interval, split_rhat
from .sparse import GibbsSamples, SweepMoves, gibbs_intensities
from .truncated import (
    Dynamics,
    Ridge,
    TruncatedSamples,
    sample_truncated_gaussian,
    truncnorm_1d,
)

__all__ = [
    "image",
    "ImageResult",
    "ImageOptions",
    "ImagingPrior",
    "Gaussian",
    "NonNegative",
    "Bounded",
    "Sparse",
    "TwoLevel",
    "PRIORS",
    "data_bound",
    "with_data_bound",
    "SAMPLERS",
    "Design",
    "design_matrix",
    "analyse_design",
    "check_directions",
    "neighbour_pairs",
    "neighbour_groups",
    "GaussianPosterior",
    "gaussian_posterior",
    "TruncatedSamples",
    "sample_truncated_gaussian",
    "Ridge",
    "Dynamics",
    "truncnorm_1d",
    "eigen_gibbs",
    "GibbsSamples",
    "gibbs_intensities",
    "SweepMoves",
    "BinaryMap",
    "two_level_map",
    "two_level_log_posterior",
    "credible_sets",
    "hpd_interval",
    "split_rhat",
]


def __getattr__(name: str):
    """A withdrawn sampler named as an attribute: say why it is not offered."""
    if name in _GIBBS_WITHDRAWN:
        raise AttributeError(f"olsbayes.imaging.{name} is not offered: {_GIBBS_WITHDRAWN[name]}")
    raise AttributeError(f"module 'olsbayes.imaging' has no attribute {name!r}")
