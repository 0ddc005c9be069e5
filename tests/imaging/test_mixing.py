"""Imaging samplers: calibration when the truth is drawn from the prior."""

from __future__ import annotations

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.imaging import Bounded, ImageOptions


@pytest.mark.filterwarnings("ignore::olsbayes.errors.PriorBoundWarning")  # truths near 1
def test_bounded_intervals_are_calibrated_when_the_truth_is_drawn_from_the_prior():
    """Truths from Uniform(0, 1) on a small ring problem where the walls matter
    (sigma = 0.3: posterior sd of a few tenths): a calibrated posterior covers the
    truth with its 90 % intervals 90 % of the time on average over the prior.
    Pooled over 3 x 60 intervals the binomial sd is 0.022; the sources of one draw
    are correlated, so the tolerance is 4 of those sd.  The chains run by the
    default rule: until every intensity has R-hat <= 1.01 and ESS >= 400."""
    rng = np.random.default_rng(8)
    model = ob.Model(ob.Ring(8), sigma=0.3)
    dirs = np.array([-1.0, 0.4, 2.0])
    hits = []
    for _ in range(60):
        truth = rng.random(3)
        y = model.simulate(np.column_stack([dirs, truth]).ravel(), rng=rng)
        res = ob.imaging.image(model, y, dirs, Bounded(i_max=1.0), rng=rng,
                               options=ImageOptions(n_burn=50), progress=False)
        hits.append(res.covers(truth))
    cov = float(np.mean(hits))
    assert abs(cov - 0.9) < 4 * np.sqrt(0.09 / 180), cov


def test_the_two_level_gibbs_sampler_is_withdrawn_with_its_reason():
    with pytest.raises(AttributeError, match="does not mix at sigma = 0.01"):
        ob.imaging.two_level_gibbs  # noqa: B018
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        ob.imaging.nope  # noqa: B018
    assert "two_level_gibbs" not in ob.imaging.__all__


def test_the_result_reports_its_smallest_effective_sample_size():
    model = ob.Model(ob.Ring(8), sigma=0.3)
    y = model.simulate(np.array([-1.0, 0.5, 1.5, 0.5]), rng=np.random.default_rng(1))
    res = ob.imaging.image(model, y, [-1.0, 1.5], Bounded(i_max=3.0), rng=2,
                           options=ImageOptions(n_samples=100, n_burn=20, n_chains=2))
    assert 20 < res.ess <= 2 * 100 * 1.5 and res.diagnostics()["ess"] == res.ess
    closed = ob.imaging.image(model, y, [-1.0, 1.5], "gaussian")
    assert np.isnan(closed.ess)
