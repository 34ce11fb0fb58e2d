"""An experiment's report folder is always one run's whole report (core.atomic.whole_dir).

It was written file by file into the folder: a rerun with other settings (``--config``) left the PNGs it did not
draw (fewer figure presses, a training that failed) from the earlier run beside its report.md, and a run killed
while writing left a mix of both. A fake experiment with no tasks stands in for a run: only the report is written.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from nlipscalib.cli import main
from nlipscalib.core.atomic import write_bytes
from nlipscalib.core.errors import ConfigError
from nlipscalib.experiments import framework
from nlipscalib.experiments.framework import Experiment, run_experiment


@dataclasses.dataclass(frozen=True)
class FakeConfig:
    figures: tuple[str, ...] = ("a.png", "b.png")
    fail_after: int = -1
    """Raise after drawing this many figures (-1: never): a run killed while writing its report."""


class Fake(Experiment):
    name = "fake"
    title = "Fake"
    config_cls = FakeConfig

    def tasks(self, cfg, solver_options=None):
        return []

    def tables(self, cfg, rows, learned):
        return []

    def figures(self, cfg, rows, tables, folder, learned):
        for i, name in enumerate(cfg.figures):
            if i == cfg.fail_after:
                raise KeyboardInterrupt
            write_bytes(folder / name, f"{name} of {cfg.figures}".encode())
        return [(name, name) for name in cfg.figures]


def _run(cfg: FakeConfig, tmp_path: Path) -> dict:
    return run_experiment(Fake(), cfg, tmp_path / "work", tmp_path / "report", size="custom", progress=False)


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def test_a_rerun_with_fewer_figures_leaves_none_of_the_earlier_run(tmp_path):
    _run(FakeConfig(), tmp_path)
    _run(FakeConfig(figures=("a.png",)), tmp_path)
    assert sorted(_files(tmp_path / "report")) == ["a.png", "report.md", "results.json"]  # b.png was left
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".tmp-")]


def test_a_run_killed_while_writing_its_report_leaves_the_earlier_report_whole(tmp_path):
    _run(FakeConfig(), tmp_path)
    before = _files(tmp_path / "report")
    with pytest.raises(KeyboardInterrupt):
        _run(FakeConfig(figures=("a.png", "c.png"), fail_after=1), tmp_path)
    assert _files(tmp_path / "report") == before  # a.png was the new run's, beside the old report.md
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".tmp-")]


def test_a_folder_of_other_files_is_never_replaced_by_a_report(tmp_path):
    mine = tmp_path / "report"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine", encoding="utf-8")
    with pytest.raises(ConfigError, match="no results.json"):
        _run(FakeConfig(), tmp_path)
    assert _files(mine) == {"notes.txt": b"mine"}


def test_the_command_refuses_a_report_folder_of_other_files_before_any_work(tmp_path, monkeypatch, capsys):
    ran = []
    monkeypatch.setattr(framework, "run_experiment", lambda *a, **k: ran.append(1))
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine", encoding="utf-8")
    argv = ["experiment", "q1", "--out", str(tmp_path / "out"), "--report", str(tmp_path / "mine")]
    assert main(argv) == 2
    assert "holds files but no results.json" in capsys.readouterr().err and not ran
