"""Coverage of 90 % intervals where the posterior has several modes.

The scene: four sources on a ring of 30, two pairs within 0.7 sensor spacings of
antipodal, sigma = 1e-3 (each pair has two fits of equal quality, so the
posterior has 2 x 2 modes).  A single ensemble started at the ML point reports
one mode; the automatic choice finds the mirrored optima and samples all four.
Over 64 noise draws (the same truth), a parameter is covered when its true value
lies between the 5 % and 95 % quantiles of its marginal.
"""

import warnings

import numpy as np
import pytest

from olsbayes import Model, Ring
from olsbayes.circular import wrap_angle
from olsbayes.exchange import match_sources
from olsbayes.posterior import SamplerOptions, sample

TRUTH4 = np.array([-2.6, 1.0, -1.05, 0.8, 0.45, 1.2, 1.95, 0.9])
N_DRAWS = 64
STEPS = 300  # per ensemble


def _covered(res, model) -> np.ndarray:
    """(P,) bools: the truth inside each parameter's central 90 % interval."""
    x = res.unwrapped_samples().reshape(-1, res.n_params)
    t = match_sources(model, TRUTH4, res.estimate)
    per = res.periodic
    t[per] = res.estimate[per] + wrap_angle(t[per] - res.estimate[per])
    lo, hi = np.quantile(x, [0.05, 0.95], axis=0)
    return (lo <= t) & (t <= hi)


def _coverage(multimodal, seeds) -> tuple[float, float]:
    """Coverage pooled over (draw, parameter) and its standard error from the spread of
    the per-draw coverages (the 8 parameters of one draw miss together)."""
    model = Model(Ring(30), sigma=1e-3)
    opts = SamplerOptions(n_steps=STEPS, rhat_max=None, multimodal=multimodal)
    per_draw = []
    for seed in seeds:
        data = model.simulate(TRUTH4, rng=seed)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the antipodal / multimodal notices
            res = sample(model, data, 4, rng=1000 + seed, progress=False, options=opts)
        per_draw.append(_covered(res, model).mean())
    per_draw = np.array(per_draw)
    return float(per_draw.mean()), float(per_draw.std(ddof=1) / np.sqrt(per_draw.size))


@pytest.mark.slow
def test_automatic_choice_covers_where_one_ensemble_does_not():
    # one ensemble: one of four modes, so about a quarter of the pairs' angles covered
    # (0.37 measured over 64 draws); 16 draws show it, its se ~0.1
    single, se_single = _coverage(False, range(16))
    assert single + 3 * se_single < 0.8
    # the automatic choice samples all four modes: nominal 0.9, >= 0.8 asked for over
    # >= 64 parameter draws (0.87 measured, se 0.02)
    auto, se_auto = _coverage(None, range(N_DRAWS))
    assert auto >= 0.8
    assert abs(auto - 0.9) < 3 * se_auto + 0.03  # within the band of the calibration map
