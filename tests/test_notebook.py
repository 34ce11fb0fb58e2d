"""What a Jupyter notebook meets that a command does not: one kernel for many cells, interrupted cells whose
traceback the kernel keeps (``sys.last_traceback``), the kernel's own stderr stream.

Found in a real kernel (nbclient + ipykernel, s27-jupyter, benchmarks/RESULTS.md)."""

from __future__ import annotations

import pytest

from nlipscalib import progress
from tests.learn.test_resume import TINY, built, solved  # noqa: F401 (fixtures)
from tests.solver import synth
from tests.test_progress import _KernelStream


def _as_in_a_notebook(monkeypatch) -> None:
    """stderr as a notebook's (bars drawn), bars switched on. Set in the test itself: pytest's capture sets
    sys.stderr again between a fixture and the test."""
    monkeypatch.setattr("sys.stderr", _KernelStream())
    monkeypatch.setattr(progress, "_enabled", True)


def _open_bars() -> set:
    from tqdm import tqdm

    return set(tqdm._instances)


def _interrupted(run) -> object:
    """The traceback of ``run()``, which Ctrl-C (the kernel's interrupt) ends, kept as IPython keeps it."""
    with pytest.raises(KeyboardInterrupt) as caught:
        run()
    return caught.value.__traceback__


def _ctrl_c(*args, **kwargs):
    raise KeyboardInterrupt


def test_an_interrupted_solve_leaves_no_bar_open(monkeypatch, tmp_path):
    """A solve stopped with the notebook's stop button left its bar open (held by the traceback the kernel keeps):
    the next bar of the kernel was drawn as a second, nested one, whose cursor-up escapes a notebook does not
    understand, so every later solve printed a new line per iteration, '\\n\\x1b[A' each."""
    from nlipscalib.solver import nlips, solve_press

    synth.make_press(tmp_path / "press", "sphere", size=(64, 48))
    monkeypatch.setattr(nlips, "solve_coarse_to_fine", _ctrl_c)
    _as_in_a_notebook(monkeypatch)
    before = _open_bars()
    kept = _interrupted(lambda: solve_press(tmp_path / "press", progress=True))
    assert _open_bars() == before
    del kept


def test_an_interrupted_training_leaves_no_bar_open(monkeypatch, built, tmp_path):  # noqa: F811
    from nlipscalib.learn import train as train_module

    monkeypatch.setattr(train_module, "_epoch", _ctrl_c)
    _as_in_a_notebook(monkeypatch)
    before = _open_bars()
    kept = _interrupted(lambda: train_module.train(built, TINY, tmp_path / "model.pt", progress=True))
    assert _open_bars() == before
    del kept
