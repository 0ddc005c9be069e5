"""select_structure: nuisance terms are added only when the evidence asks for them."""

import numpy as np
import pytest

import olsbayes as ob
from olsbayes.noise import GaussianUnknown, Poisson
from olsbayes.priors import LogNormal, Uniform
from olsbayes.select import (
    StructureOptions,
    select_structure,
    structure_candidates,
)

pytestmark = pytest.mark.filterwarnings("ignore::olsbayes.errors.EvidenceWarning")

RING, SIGMA, TRUTH = ob.Ring(24), 0.1, np.array([0.5, 1.0])
TRIALS = 40
#: Wrong choices allowed in TRIALS trials when the true rate of a right choice is
#: >= 0.95: P(Binomial(40, 0.05) > 5) = 0.014.
ALLOWED = 5


def _background_candidates():
    return structure_candidates(ob.Model(RING, SIGMA), background=Uniform(0.0, 2.0))


def _rate(background, seed0):
    cands = _background_candidates()
    truth = ob.Model(RING, SIGMA, nuisance=ob.Nuisance(background=background))
    chosen = 0
    for s in range(TRIALS):
        data = truth.simulate(TRUTH, rng=seed0 + s)
        chosen += select_structure(cands, data, 1, rng=s).best == "background"
    return chosen


def test_background_is_not_preferred_on_scenes_without_one():
    """No background: the background model is chosen in at most ALLOWED of 40 trials."""
    assert _rate(0.0, 1000) <= ALLOWED


def test_a_five_sigma_background_is_chosen():
    """A background of 5 times its marginal CRLB sd is chosen in >= 35 of 40 trials."""
    cands = _background_candidates()
    bound = ob.crlb(cands["background"], ob.Model(RING, SIGMA).unpack(TRUTH))
    assert bound.extra_names == ("b",)
    assert _rate(5.0 * float(bound.extra_std[0]), 2000) >= TRIALS - ALLOWED


def test_candidates_and_supported_terms():
    base = ob.Model(RING, SIGMA)
    cands = structure_candidates(base, background=Uniform(0.0, 1.0), gains=LogNormal(0.0, 0.1))
    assert list(cands) == ["plain", "background", "gains", "background+gains"]
    assert cands["background+gains"].nuisance.infer_gains
    assert cands["background+gains"].nuisance.infer_background
    assert not cands["gains"].nuisance.infer_background
    truth = ob.Model(RING, SIGMA, nuisance=ob.Nuisance(background=0.5))
    res = select_structure({k: cands[k] for k in ("plain", "background")},
                           truth.simulate(TRUTH, rng=3), 1, rng=0)
    assert res.best == "background" and res.supported == ("background",)
    assert res.probabilities.sum() == pytest.approx(1.0)
    assert "background*" in res.table()


def test_poisson_is_preferred_for_low_counts():
    """Counts of ~5-30 per sub-sensor: Poisson beats a Gaussian of unknown sigma."""
    pois = ob.Model(RING, noise=Poisson(exposure=20.0))
    counts = pois.simulate(TRUTH, rng=5)
    cands = structure_candidates(pois.with_noise(GaussianUnknown(3.0)), noise=Poisson(20.0))
    assert list(cands) == ["gaussian_unknown:plain", "poisson:plain"]
    res = select_structure(cands, counts, 1, rng=1)
    assert res.best == "poisson:plain" and res.supported == ()


@pytest.mark.parametrize("call, match", [
    (lambda: select_structure({"a": ob.Model(RING, SIGMA)}, np.zeros(24)), "at least two"),
    (lambda: select_structure({"a": ob.Model(RING, SIGMA), "b": ob.Model(ob.Ring(23), SIGMA)},
                              np.zeros(24)), "another array"),
    (lambda: select_structure({"a": ob.Model(RING, SIGMA), "b": "x"}, np.zeros(24)),
     "olsbayes.Model"),
    (lambda: select_structure(_background_candidates(), np.zeros(23)), "length 24"),
    (lambda: select_structure(_background_candidates(), np.zeros(24), options=1),
     "StructureOptions"),
    (lambda: StructureOptions(tie=-1.0), "tie"),
    (lambda: StructureOptions(method="grid"), "method must be one of"),
    (lambda: structure_candidates(ob.Model(RING, SIGMA)), "at least one of"),
    (lambda: structure_candidates(ob.Model(RING, SIGMA), gains=Uniform(-1.0, 2.0)),
     "support within"),
    (lambda: structure_candidates(ob.Model(RING, SIGMA), background=0.3), "prior"),
    (lambda: select_structure({"a": ob.Model(RING, noise=Poisson()), "b": ob.Model(
        RING, SIGMA)}, np.full(24, 0.5)), "counts"),
])
def test_bad_structure_input(call, match):
    with pytest.raises(ob.InputError, match=match):
        call()


def test_a_gaussian_choice_on_low_counts_is_warned_about():
    """Counts of ~1-5: the Gaussian candidate listed first wins a tie only with a warning."""
    pois = ob.Model(RING, noise=Poisson(exposure=4.0, dark=0.5))
    counts = pois.simulate(TRUTH, rng=8)
    cands = {"gaussian": pois.with_noise(GaussianUnknown(1.0)), "poisson": pois}
    opts = StructureOptions(tie=1e6)  # the first candidate is chosen whatever the evidence
    with pytest.warns(ob.EvidenceWarning, match="Gaussian approximation"):
        assert select_structure(cands, counts, 1, options=opts, rng=0).best == "gaussian"
