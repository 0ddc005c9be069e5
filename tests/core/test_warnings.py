"""Warnings where methods are known to fail: specific classes, raised, never printed.

Covered here: sources closer than the array resolves (ResolutionWarning), a source
on the costn kink (KinkWarning), an ML fit that stops early (ConvergenceWarning),
and the CLI's one-line rendering of warnings.  The sampler's R-hat /
autocorrelation check, nested sampling's call cap and Laplace-vs-nested evidence
disagreement are tested next to their engines (tests/test_posterior.py,
tests/test_select_evidence.py).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.cli import main


def test_warning_classes_form_one_hierarchy():
    for cls in (ob.ResolutionWarning, ob.KinkWarning, ob.ConvergenceWarning,
                ob.EvidenceWarning, ob.NullSpaceWarning):
        assert issubclass(cls, ob.OlsBayesWarning) and issubclass(cls, UserWarning)


@pytest.mark.parametrize("separation", [0.0, 1e-4])
def test_sources_closer_than_resolvable_warn(separation):
    model = ob.Model(ob.Ring(30), 0.01)
    scene = ob.Scene(directions=[0.3, 0.3 + separation], intensities=[1.0, 1.0])
    with pytest.warns(ob.ResolutionWarning, match="resolve"):
        res = ob.crlb(model, scene)
    assert not res.resolvable and np.isinf(res.direction_std).all()


def test_well_separated_sources_do_not_warn():
    model = ob.Model(ob.Ring(30), 0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = ob.crlb(model, ob.Scene(directions=[0.3, 1.3], intensities=[1.0, 1.0]))
    assert res.resolvable


def test_source_on_the_kink_warns_only_for_kinked_laws():
    scene = ob.Scene(directions=[np.pi / 30], intensities=[1.0])  # sensors at +-90 deg
    with pytest.warns(ob.KinkWarning, match="90 deg"):
        ob.crlb(ob.Model(ob.Ring(30), 0.01), scene)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ob.crlb(ob.Model(ob.Ring(30), 0.01, ob.CosinePower(2.0)), scene)


def test_ml_fit_stopped_early_warns():
    model = ob.Model(ob.Ring(30), 0.01)
    data = model.simulate(ob.Scene(directions=[0.5, 2.0], intensities=[1.0, 1.0]), rng=6, size=3)
    with pytest.warns(ob.ConvergenceWarning):
        res = ob.fit_ml(model, data, 2, options=ob.ml.FastOptions(max_iter=1, n_restarts=0))
    assert not np.all(res.converged)


def test_cli_renders_a_warning_as_one_line_and_keeps_status(capsys):
    code = main(["crlb", "--set", "scene.directions=[0.3, 0.3]"])
    out, err = capsys.readouterr()
    assert code == 0 and "CRLB" in out
    lines = err.strip().splitlines()
    assert lines == [line for line in lines if line.startswith("olsbayes: warning: ")]
    assert len(lines) == 1 and "ResolutionWarning" in lines[0]
