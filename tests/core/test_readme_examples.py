"""The README's Python study example runs as a script (a process pool re-imports it)."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[2] / "README.md"


def _study_snippet() -> str:
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    return next(b for b in blocks if "run_study(ring_estimate" in b)


@pytest.mark.slow
def test_readme_study_example_runs_as_a_script(tmp_path):
    code = _study_snippet().replace("n_trials=200", "n_trials=4")  # the same call, shorter
    assert "n_trials=4" in code and 'if __name__ == "__main__":' in code
    script = tmp_path / "sweep.py"
    script.write_text(code, encoding="utf-8")
    env = dict(os.environ, MPLBACKEND="Agg",
               PYTHONPATH=os.pathsep.join([str(README.parent), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "dir_z2" in proc.stdout or "estimator" in proc.stdout
    assert (tmp_path / "sweep.nc").is_file()
