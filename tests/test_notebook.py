"""What a Jupyter notebook meets that a command does not: one kernel for many cells, interrupted cells whose
traceback the kernel keeps (``sys.last_traceback``), the kernel's own stderr stream.

Found in a real kernel (nbclient + ipykernel, s27-jupyter, benchmarks/RESULTS.md)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

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


class _InterruptedWhileWriting(_KernelStream):
    """A notebook's stderr whose first write the stop button interrupts (the kernel's zmq send, seen there)."""

    def write(self, text):
        if not getattr(self, "interrupted", False):
            self.interrupted = True
            raise KeyboardInterrupt
        return super().write(text)


def test_a_solve_interrupted_while_its_bar_first_draws_leaves_no_bar_open(monkeypatch, tmp_path):
    """The interrupt can land in the bar's first write, inside tqdm's constructor, which has already registered
    the bar: no handle was returned to close it (seen in a kernel 2.5 s into a solve)."""
    from nlipscalib.solver import solve_press

    synth.make_press(tmp_path / "press", "sphere", size=(64, 48))
    monkeypatch.setattr(progress, "_enabled", True)
    monkeypatch.setattr("sys.stderr", _InterruptedWhileWriting())
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


def _bar_makers() -> dict:
    return {
        "progress_bar": lambda: progress.progress_bar(3, desc="presses"),
        "track": lambda: progress.track(range(3), desc="presses"),
        "working": lambda: progress.working("rendering").__enter__(),
    }


@pytest.mark.parametrize("kind", sorted(_bar_makers()))
def test_a_bar_interrupted_in_its_first_draw_is_closed(monkeypatch, kind):
    """The package's other bars (training, ``solve FOLDER``, ``dataset``, ``calibrate``, experiments) drew in tqdm's
    constructor, which registers the bar before its first write: a Ctrl-C there left a bar nobody could close."""
    monkeypatch.setattr(progress, "_enabled", True)
    monkeypatch.setattr("sys.stderr", _InterruptedWhileWriting())
    before = _open_bars()
    kept = _interrupted(_bar_makers()[kind])
    assert _open_bars() == before
    del kept


def test_a_batch_bar_still_shows_its_zero_line_at_once_and_its_last_line_when_closed(monkeypatch):
    """Drawn outside tqdm's constructor, not later: a batch's ``0/N`` line shows before its first press ends, and
    a bar closed before any update still ends its line (the next output starts on a line of its own)."""
    _as_in_a_notebook(monkeypatch)
    bar = progress.progress_bar(3, desc="presses", unit="press")
    assert "presses:   0%" in sys.stderr.getvalue() and "0/3" in sys.stderr.getvalue()
    bar.close()
    assert sys.stderr.getvalue().endswith("\n")
    assert "0/3" in sys.stderr.getvalue().splitlines()[-1]


def test_a_training_interrupted_while_its_bar_first_draws_leaves_no_bar_open(monkeypatch, built, tmp_path):  # noqa: F811
    from nlipscalib.learn import train as train_module

    monkeypatch.setattr(progress, "_enabled", True)
    monkeypatch.setattr("sys.stderr", _InterruptedWhileWriting())
    before = _open_bars()
    kept = _interrupted(lambda: train_module.train(built, TINY, tmp_path / "model.pt", progress=True))
    assert _open_bars() == before
    del kept


def test_a_batch_solve_interrupted_while_its_bar_first_draws_leaves_no_bar_open(monkeypatch, tmp_path):
    from nlipscalib.pipeline import solve_presses

    for name in ("a", "b"):
        synth.make_press(tmp_path / name, "sphere", size=(64, 48))
    monkeypatch.setattr(progress, "_enabled", True)
    monkeypatch.setattr("sys.stderr", _InterruptedWhileWriting())
    before = _open_bars()
    kept = _interrupted(lambda: solve_presses([tmp_path / "a", tmp_path / "b"], progress=True, figures=False))
    assert _open_bars() == before
    del kept


def test_an_experiment_ended_by_an_exception_leaves_no_bar_open(monkeypatch, tmp_path):
    """experiments/runner.py closed its task bar only when the run returned."""
    from nlipscalib.experiments import runner
    from nlipscalib.experiments.tasks import Task

    def failing(*args, **kwargs):
        raise RuntimeError("a bug in a task")

    monkeypatch.setattr(runner, "execute", failing)
    _as_in_a_notebook(monkeypatch)
    before = _open_bars()
    with pytest.raises(RuntimeError) as caught:
        runner.run_tasks([Task(kind="reference", id="ref-none", scene={})], tmp_path)
    assert _open_bars() == before
    del caught


EXAMPLE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "quickstart.ipynb"


def test_the_shipped_example_notebook_is_stripped_of_outputs():
    """Outputs would go stale with the code (and carry a machine's paths): the file holds the code only."""
    notebook = json.loads(EXAMPLE.read_text(encoding="utf-8"))
    code = [cell for cell in notebook["cells"] if cell["cell_type"] == "code"]
    assert code and all(cell["outputs"] == [] and cell["execution_count"] is None for cell in code)


def test_the_shipped_example_notebook_runs_in_a_jupyter_kernel(tmp_path, monkeypatch):
    """docs/examples/quickstart.ipynb run headless in a real kernel (nbclient, ipykernel), as a lab runs it: no
    error, no warning, each figure shown once, under its own cell (our figures drawn to files left the notebook's
    inline backend alone), and the point cloud written."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    root = str(EXAMPLE.parents[2])  # the kernel imports this checkout's package, installed or not
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")])))
    notebook = nbformat.read(EXAMPLE, as_version=4)
    nbclient.NotebookClient(notebook, timeout=600, resources={"metadata": {"path": str(tmp_path)}}).execute()
    for cell in notebook.cells:
        if cell.cell_type != "code":
            continue
        outputs = cell.outputs
        assert not [o for o in outputs if o.output_type == "error"]
        stderr = "".join(o.text for o in outputs if o.output_type == "stream" and o.name == "stderr")
        assert "Warning" not in stderr and "Traceback" not in stderr, stderr
        shown = sum("image/png" in o.get("data", {}) for o in outputs)
        assert shown == cell.source.count("plt.show()") + cell.source.count("display(Image"), cell.source
    assert (tmp_path / "quickstart_out" / "nlipsnet_points.ply").stat().st_size > 0
