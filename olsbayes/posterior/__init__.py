"""Bayesian posteriors of OLS scenes: emcee ensembles, ArviZ output, CRLB audit.

>>> from olsbayes.posterior import SamplerOptions, sample          # doctest: +SKIP
>>> res = sample(model, data, n_sources=2, rng=1)                  # doctest: +SKIP
>>> res.summary(); res.crlb_check()                                # doctest: +SKIP
>>> sample(model, data, 2, options=SamplerOptions(n_steps=2000), rng=1)  # doctest: +SKIP
>>> res = sample(model, data, 4, options=SamplerOptions(multimodal=True))  # doctest: +SKIP
>>> res.modes                          # modes found and their weights  # doctest: +SKIP

ArviZ is used only through :mod:`olsbayes.posterior._arviz` (imported lazily).
"""

from .audit import CRLBCheck, crlb_check, summary
from .modes import ModeOptions, ModeReport
from .options import MOVES, SamplerOptions
from .report import ReportFiles, write_report
from .result import PosteriorResult
from .sampler import sample

__all__ = [
    "sample",
    "SamplerOptions",
    "MOVES",
    "ModeOptions",
    "ModeReport",
    "PosteriorResult",
    "summary",
    "crlb_check",
    "CRLBCheck",
    "write_report",
    "ReportFiles",
]
