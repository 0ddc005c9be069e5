"""A study started by a script's unguarded top-level code: refused at once, in one line."""

import ast
import os
import subprocess
import sys
import textwrap

import pytest

from olsbayes.studies._script import guarded_line

# (source, line, guarded): the call on ``line`` of each little script
CASES = [
    ("run()\n", 1, False),
    ("if __name__ == '__main__':\n    run()\n", 2, True),
    ("if '__main__' == __name__:\n    run()\n", 2, True),
    ("if __name__ == '__main__' and True:\n    x = 1\n    run()\n", 3, True),
    ("if __name__ != '__main__':\n    pass\nelse:\n    run()\n", 4, True),
    ("if True:\n    run()\n", 2, False),
    ("def main():\n    run()\n\nmain()\n", 4, False),
    ("import os\nif __name__ == '__main__':\n    pass\nrun()\n", 4, False),
]


@pytest.mark.parametrize(("source", "line", "guarded"), CASES)
def test_guarded_line_reads_the_if_around_a_top_level_line(source, line, guarded):
    assert guarded_line(ast.parse(source), line) is guarded


STUDY = textwrap.dedent("""
    import os, sys, time
    from olsbayes.studies import run_study
    from olsbayes.studies.trials import noise_check

    def dies_in_a_worker(settings, rng):
        if os.environ["STUDY_PARENT"] != str(os.getpid()):
            os._exit(3)  # a worker ending abruptly (as if killed)
        time.sleep(0.005)
        return noise_check(settings, rng=rng)

    {guard}
    {indent}os.environ["STUDY_PARENT"] = str(os.getpid())
    {indent}trial = dies_in_a_worker if sys.argv[3] == "die" else noise_check
    {indent}run_study(trial, {{"sigma": [0.01], "n_sensors": [8]}}, int(sys.argv[4]),
    {indent}          executor=sys.argv[1], workers=1, checkpoint=sys.argv[2], rng=1,
    {indent}          progress=False)
    {indent}print("done")
""")


def _run(tmp_path, executor, guarded, trial="plain", n=8):
    script = tmp_path / "study.py"
    script.write_text(STUDY.format(guard='if __name__ == "__main__":' if guarded else "",
                                   indent="    " if guarded else ""))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    ckpt = tmp_path / "s.ckpt"
    out = subprocess.run([sys.executable, str(script), executor, str(ckpt), trial, str(n)],
                         capture_output=True, text=True, timeout=300, env=env)
    return out, ckpt


@pytest.mark.parametrize("executor", ["processes", "dask"])
def test_an_unguarded_script_is_refused_before_any_work(tmp_path, executor):
    if executor == "dask":
        pytest.importorskip("distributed")
    out, ckpt = _run(tmp_path, executor, guarded=False)
    assert out.returncode == 1 and out.stdout == ""
    assert out.stderr.count("Traceback") == 1, out.stderr
    last = out.stderr.strip().splitlines()[-1]
    line = next(i for i, text in enumerate((tmp_path / "study.py").read_text().splitlines(), 1)
                if text.startswith("run_study("))
    assert last.startswith("olsbayes.errors.InputError: ") and f"line {line} " in last, last
    assert '__name__ == "__main__"' in last and "study.py" in last
    assert not ckpt.exists()  # refused before the checkpoint was opened


def test_an_unguarded_script_may_run_a_study_in_its_own_process(tmp_path):
    out, _ = _run(tmp_path, "threads", guarded=False)
    assert out.returncode == 0 and out.stdout.split() == ["done"], out.stderr


@pytest.mark.slow
def test_a_worker_that_ends_abruptly_gives_one_clear_error(tmp_path):
    out, _ = _run(tmp_path, "processes", guarded=True, trial="die", n=400)
    assert out.returncode == 1 and "done" not in out.stdout
    assert out.stderr.count("Traceback") == 1, out.stderr
    error = [line for line in out.stderr.splitlines() if "Error" in line and ": " in line]
    assert len(error) == 1 and error[0].startswith(
        "olsbayes.errors.InputError: the study's worker processes ended abruptly"), error


def test_no_script_no_refusal():
    code = ("from olsbayes.studies.executors import check_script_guard; "
            "check_script_guard('processes'); print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True)
    assert out.stdout.split() == ["ok"]
