"""`olsbayes select`: table and JSON output, one-line errors."""

from __future__ import annotations

import json

import numpy as np

from olsbayes.cli import main


def test_select_json_on_the_default_scene(capsys):
    assert main(["select", "--method", "laplace", "--seed", "1", "--json", "--k-max", "3"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["true_k"] == 2
    (res,) = out["results"]
    assert res["best"] == 2
    probs = [c["probability"] for c in res["candidates"]]
    assert len(probs) == 4 and abs(sum(probs) - 1) < 1e-12


def test_select_table_from_a_data_file_and_a_select_section(tmp_path, capsys):
    from olsbayes import Model, Ring

    data = Model(Ring(30), 0.01).simulate(np.array([0.4, 1.0]), rng=np.random.default_rng(2))
    f = tmp_path / "r.txt"
    np.savetxt(f, data[None, :])
    cfg = tmp_path / "s.toml"
    cfg.write_text('[sensor]\ngeometry = "ring"\nn = 30\nsigma = 0.01\n'
                   '[select]\nk_max = 2\nmethod = "laplace"\ni_max = 2.0\n')
    assert main(["select", str(cfg), "--data", str(f)]) == 0
    text = capsys.readouterr().out
    assert "best K = 1" in text and "p(K|data)" in text


def test_select_bad_input_is_one_line_and_status_2(tmp_path, capsys):
    assert main(["select", "--k-max", "20", "--method", "laplace"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "k_max" in err
    cfg = tmp_path / "s.toml"
    cfg.write_text('[sensor]\ngeometry = "ring"\nn = 30\nsigma = 0.01\n[select]\nkmax = 2\n')
    assert main(["select", str(cfg)]) == 2
    assert "kmax" in capsys.readouterr().err
    assert main(["select", "--method", "nested-sampling"]) == 2
