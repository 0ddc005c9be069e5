"""The README's real-sensor example runs and finds the background and the sources."""

import re
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[2] / "README.md"


def _snippet() -> str:
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    return next(b for b in blocks if "select_structure(cands" in b)


@pytest.mark.filterwarnings("ignore::olsbayes.errors.EvidenceWarning")
def test_readme_counts_example(capsys):
    env: dict = {}
    exec(compile(_snippet(), str(README), "exec"), env)  # noqa: S102 (the README's own code)
    fit, bound, choice = env["fit"], env["bound"], env["choice"]
    b, b_sd = fit.extra[0], fit.extra_std[0]
    assert abs(b - 3.0) < 4 * b_sd  # the true background
    assert "background" in choice.supported
    est = np.sort(fit.scene.intensities)
    assert np.abs(est - [20.0, 40.0]).max() < 4 * fit.std[2::3].max()
    assert np.all(np.isfinite(bound.direction_std))
    assert "background" in capsys.readouterr().out


def test_readme_counts_configuration_builds_its_model():
    from olsbayes.build import model_from_config
    from olsbayes.build_measurement import sampler_options_from_config
    from olsbayes.config import parse_config
    from olsbayes.noise import Poisson

    blocks = re.findall(r"```toml\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    cfg = parse_config(next(b for b in blocks if 'model = "poisson"' in b))
    model = model_from_config(cfg)
    assert model.noise == Poisson(2.0) and model.n_sensors == 60
    assert model.nuisance.infer_gains and model.nuisance.infer_background
    n_params = 2 * 3 + 1 + 60
    assert sampler_options_from_config(cfg, 100).n_walkers >= 2 * n_params
