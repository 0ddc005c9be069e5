"""Imaging mode: intensities of sources at known directions (Fig. 2 of the paper).

With the directions fixed, Eq. 1 is linear in the intensities, ``s = A I +
noise``; :func:`image` returns their posterior under a Gaussian (closed form,
with evidence), nonnegative, bounded, sparse (spike-and-slab) or two-level
prior, plus the design matrix's rank, conditioning and null space -- what the array cannot see;
``n_samples=0`` returns the mode only, and ``prior="two-level"`` (each
intensity 0 or i_max) the MAP scene of a local search.
"""

from .binary import BinaryMap, two_level_log_posterior, two_level_map
from .binary_gibbs import BinaryGibbs, credible_sets, two_level_gibbs
from .core import PRIORS, SAMPLERS, image
from .design import Design, analyse_design, check_directions, design_matrix
from .eigen import eigen_gibbs
from .gaussian import GaussianPosterior, gaussian_posterior
from .result import ImageResult, hpd_interval, split_rhat
from .sparse import GibbsSamples, gibbs_intensities
from .truncated import TruncatedSamples, sample_truncated_gaussian, truncnorm_1d

__all__ = [
    "image",
    "ImageResult",
    "PRIORS",
    "SAMPLERS",
    "Design",
    "design_matrix",
    "analyse_design",
    "check_directions",
    "GaussianPosterior",
    "gaussian_posterior",
    "TruncatedSamples",
    "sample_truncated_gaussian",
    "truncnorm_1d",
    "eigen_gibbs",
    "GibbsSamples",
    "gibbs_intensities",
    "BinaryMap",
    "two_level_map",
    "two_level_log_posterior",
    "BinaryGibbs",
    "two_level_gibbs",
    "credible_sets",
    "hpd_interval",
    "split_rhat",
]
