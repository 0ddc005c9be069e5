"""Monte Carlo studies: sweeps over grids of settings on a local pool or a Dask cluster.

:func:`run_study` sends chunks of trials to an executor, checkpoints every
finished chunk so a killed study resumes, and returns an ``xarray.Dataset``.

Modules: :mod:`~olsbayes.studies.runner` (``run_study``),
:mod:`~olsbayes.studies.executors` (serial, threads, processes, Dask, any
Executor), :mod:`~olsbayes.studies.checkpoint` (append-only checkpoint),
:mod:`~olsbayes.studies.seeds` (one SeedSequence per trial),
:mod:`~olsbayes.studies.grid` (settings grids); ready-made trials in
:mod:`~olsbayes.studies.trials` (noise checks), :mod:`~olsbayes.studies.estimators`
(``ring_estimate``: ML / posterior / nested sampling scored against the CRLB,
see :mod:`~olsbayes.studies.scoring`; the estimator is an
:class:`~olsbayes.studies.estimator_spec.Estimator`, a name plus its options)
and :mod:`~olsbayes.studies.sbc` (simulation-based calibration).
"""

from ._work import trial_outputs, trial_settings, vectorized
from .checkpoint import Checkpoint
from .estimator_spec import ESTIMATORS, Estimator, as_estimator
from .executors import EXECUTORS, make_backend
from .grid import Setting
from .runner import dataset_seed, run_study, trial_name
from .seeds import study_entropy, trial_seed

__all__ = [
    "run_study",
    "vectorized",
    "trial_settings",
    "trial_outputs",
    "dataset_seed",
    "Setting",
    "Estimator",
    "as_estimator",
    "ESTIMATORS",
    "Checkpoint",
    "make_backend",
    "EXECUTORS",
    "study_entropy",
    "trial_seed",
    "trial_name",
]
