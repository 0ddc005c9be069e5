"""The progress bar: nothing on stderr for a quick call, even one that sets a status."""

from __future__ import annotations

import olsbayes._progress as progress


def test_a_quick_call_that_sets_a_status_prints_nothing(capsys, monkeypatch):
    monkeypatch.setattr(progress, "DELAY", 30.0)
    with progress.progress_bar(enabled=True, desc="select_k", unit=" K", total=3) as bar:
        bar.update(1)
        bar.set_postfix_str("K = 2: importance sampling")
        bar.set_description("select_k again")
        bar.update(2)
    assert capsys.readouterr().err == ""


def test_after_the_delay_the_bar_shows_its_latest_status(capsys, monkeypatch):
    monkeypatch.setattr(progress, "DELAY", 0.0)
    with progress.progress_bar(enabled=True, desc="select_k", unit=" K", total=3) as bar:
        bar.set_postfix_str("K = 2: importance sampling")
        assert "K = 2: importance sampling" in capsys.readouterr().err


def test_a_disabled_bar_prints_nothing(capsys):
    with progress.progress_bar(enabled=False, desc="posterior", unit=" step") as bar:
        bar.set_postfix_str("tau 12")
        bar.update(5)
    assert capsys.readouterr().err == ""


def test_a_bar_that_counts_nothing_shows_once_the_delay_has_passed(capsys, monkeypatch):
    """A call still setting up, or assembling after its last count, is not silent."""
    import time

    monkeypatch.setattr(progress, "DELAY", 0.05)
    with progress.progress_bar(enabled=True, desc="posterior", unit=" steps") as bar:
        bar.set_postfix_str("assembling the draws", refresh=False)
        deadline = time.monotonic() + 5.0  # the timer draws it ~0.1 s in
        while "assembling the draws" not in capsys.readouterr().err:
            assert time.monotonic() < deadline, "the bar never showed"
            time.sleep(0.02)


def test_a_bar_closed_before_its_delay_never_shows(capsys, monkeypatch):
    import time

    monkeypatch.setattr(progress, "DELAY", 0.2)
    with progress.progress_bar(enabled=True, desc="posterior", unit=" steps") as bar:
        bar.update(3)
    time.sleep(0.4)  # past the delay: the timer was cancelled with the bar
    assert capsys.readouterr().err == ""
