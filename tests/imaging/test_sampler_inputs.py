"""The imaging samplers refuse bad settings before any work (records and arguments)."""

from __future__ import annotations

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.imaging import (
    Dynamics,
    Ridge,
    SweepMoves,
    gibbs_intensities,
    sample_truncated_gaussian,
)


@pytest.mark.parametrize("strength", [0.0, -1.0, np.inf, np.nan, True, "1"])
def test_a_ridge_refuses_a_strength_that_is_not_positive_and_finite(strength):
    with pytest.raises(ob.InputError, match=r"Ridge.strength must be"):
        Ridge(strength)


@pytest.mark.parametrize("kwargs,match", [
    (dict(t_total=0.0), r"Dynamics.t_total must be in \(0, inf\)"),
    (dict(t_total=np.inf), r"Dynamics.t_total must be in \(0, inf\)"),
    (dict(max_bounces=0), r"Dynamics.max_bounces must be in \[1, inf\]"),
    (dict(max_bounces=2.5), r"Dynamics.max_bounces must be an integer"),
])
def test_the_dynamics_refuse_a_bad_length_or_cap(kwargs, match):
    with pytest.raises(ob.InputError, match=match):
        Dynamics(**kwargs)


def test_a_ridge_centre_of_the_wrong_length_is_refused():
    with pytest.raises(ob.InputError, match=r"ridge.centre must have shape \(2,\)"):
        sample_truncated_gaussian(np.eye(2), np.zeros(2), np.zeros(2), np.ones(2),
                                  np.full((2, 2), 0.5), 4, rng=np.random.default_rng(0),
                                  ridge=Ridge(1.0, np.zeros(3)))


def test_the_spike_refuses_extra_moves_after_the_sweep():
    with pytest.raises(ob.InputError, match="moves.after_sweep"):
        gibbs_intensities(np.eye(2), np.zeros(2), 0.1, 1.0, np.full((2, 2), 0.5), 4,
                          rng=np.random.default_rng(0), spike=(1.0, 1.0),
                          moves=SweepMoves(after_sweep=lambda x: None))


@pytest.mark.parametrize("kwargs,match", [
    (dict(spike=True), r"spike must be a pair \(a, b\) of numbers > 0"),
    (dict(spike=(1.0, 0.0)), r"spike must be in \(0, inf\)"),
    (dict(moves=SweepMoves(pairs=np.array([[0, 2]]))), r"moves.pairs must index the 2 "),
    (dict(moves=SweepMoves(pairs=np.array([0, 1]))), r"moves.pairs must be integers of shape"),
    (dict(moves=SweepMoves(pairs=np.array([[0.0, 1.0]]))), r"moves.pairs must be integers"),
])
def test_gibbs_refuses_a_bad_spike_or_pairs_before_any_work(kwargs, match):
    with pytest.raises(ob.InputError, match=match):
        gibbs_intensities(np.eye(2), np.zeros(2), 0.1, 1.0, np.full((2, 2), 0.5), 4,
                          rng=np.random.default_rng(0), **kwargs)
