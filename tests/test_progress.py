"""Progress bars only on a terminal (never in logs), a global --no-progress, and an optional log file."""

from __future__ import annotations

import io
import logging

import pytest

from nlipscalib import progress
from nlipscalib.cli import main
from nlipscalib.sim import dataset_pool
from tests.cli.test_faults import SPEC, _fake_render


@pytest.fixture(autouse=True)
def _restore_progress():
    yield
    progress.configure(progress=True)  # main() sets the global switch and a log file: undo both


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_bars_only_on_a_terminal_and_not_with_no_progress(monkeypatch):
    monkeypatch.setattr("sys.stderr", io.StringIO())
    assert not progress.bars_enabled()
    tty = _Tty()
    monkeypatch.setattr("sys.stderr", tty)
    progress.configure(progress=True)
    assert progress.bars_enabled()
    with progress.progress_bar(3, desc="x", file=tty) as bar:
        bar.update(3)
    assert "\r" in tty.getvalue()
    progress.configure(progress=False)  # --no-progress
    assert not progress.bars_enabled()


def test_working_logs_start_and_end_when_not_a_terminal(caplog):
    caplog.set_level(logging.INFO)
    with progress.working("rendering press"):
        pass
    assert "rendering press ..." in caplog.text and "rendering press done in" in caplog.text


def test_dataset_log_file_without_carriage_returns(tmp_path, monkeypatch, capsys):
    spec, out, log = tmp_path / "spec.toml", tmp_path / "out", tmp_path / "logs" / "run.log"
    spec.write_text(SPEC, encoding="utf-8")
    monkeypatch.setattr(dataset_pool, "_run_one", _fake_render([]))
    assert main(["-v", "--log-file", str(log), "dataset", str(spec), "--out", str(out), "--workers", "1"]) == 0
    text = log.read_text(encoding="utf-8")
    assert "press press_0003: rendered" in text and "\r" not in text
    assert "\r" not in capsys.readouterr().err  # stderr is not a terminal here: no bar


def test_worker_processes_append_whole_lines_to_the_log_file(tmp_path):
    """Workers log to the parent's --log-file; long records from several processes never split or clobber."""
    import re
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    log = tmp_path / "run.log"
    log.write_text("earlier run\n", encoding="utf-8")
    progress.configure(progress=False, log_file=log)
    logger = logging.getLogger("nlipscalib.test_workers")
    long = "x" * 9000  # longer than a FileHandler's write buffer
    with ProcessPoolExecutor(
        2, mp_context=get_context("spawn"), initializer=progress.configure_worker, initargs=progress.worker_logging()
    ) as pool:
        for future in [pool.submit(logger.warning, f"worker line {i} {long}") for i in range(24)]:
            future.result()
    logger.warning("parent line")
    progress.configure(progress=True)  # closes the file
    lines = log.read_text(encoding="utf-8").splitlines()
    assert lines[0] == "earlier run"  # appended, not truncated
    numbers = sorted(int(m.group(1)) for line in lines if (m := re.search(rf"worker line (\d+) {long}$", line)))
    assert numbers == list(range(24)) and len(lines) == 26 and lines[-1].endswith("parent line")


def test_parallel_solve_logs_to_the_log_file(tmp_path):
    """`nlips solve --workers 2 --log-file`: what the worker processes log reaches the file too."""
    from nlipscalib.pipeline import solve_presses

    folders = [tmp_path / "press_a", tmp_path / "press_b"]
    for folder in folders:
        folder.mkdir()
        (folder / "meta.json").write_text("{}", encoding="utf-8")  # a capture the worker refuses, with an ERROR line
    log = tmp_path / "run.log"
    progress.configure(progress=False, log_file=log)
    status = solve_presses(folders, workers=2, progress=False, figures=False)
    assert all(s.startswith("failed") for s in status.values())
    text = log.read_text(encoding="utf-8")
    assert "ERROR" in text and "press_a" in text and "press_b" in text, text


def test_results_printed_on_stdout_reach_the_log_file_too(tmp_path, capsys):
    """A successful `nlips --log-file F dataset ...` left F empty: its summary went to stdout only."""
    import sys

    log = tmp_path / "run.log"
    progress.configure(progress=False, log_file=log)
    real = sys.stdout
    with progress.results_to_log_file():
        print("3 rendered, 0 already there")
        print("mean AAE", end="")
        print(" 1.5")
    assert sys.stdout is real
    assert capsys.readouterr().out == "3 rendered, 0 already there\nmean AAE 1.5\n"
    lines = log.read_text(encoding="utf-8").splitlines()
    assert lines[0].endswith("3 rendered, 0 already there") and lines[1].endswith("mean AAE 1.5") and len(lines) == 2
    progress.configure(progress=False)  # without a log file nothing is wrapped
    with progress.results_to_log_file():
        assert sys.stdout is real


def test_the_cli_logs_a_commands_results_to_its_log_file(tmp_path, capsys):
    log = tmp_path / "cache.log"
    assert main(["--log-file", str(log), "cache"]) == 0
    printed = capsys.readouterr().out.strip().splitlines()
    assert printed and all(line in log.read_text(encoding="utf-8") for line in printed)


def test_the_log_tee_forwards_what_it_does_not_handle_and_steps_aside_without_stdout(tmp_path, monkeypatch):
    import sys

    progress.configure(progress=False, log_file=tmp_path / "run.log")
    real = sys.stdout
    with progress.results_to_log_file():
        assert sys.stdout is not real and sys.stdout.encoding == real.encoding and sys.stdout.errors == real.errors
    monkeypatch.setattr(sys, "stdout", None)  # fd 1 closed: print writes nothing, and must not fail
    with progress.results_to_log_file():
        print("lost")


def test_a_folder_given_as_the_log_file_is_one_line_naming_the_option(tmp_path, capsys):
    """`nlips --log-file out eval ...` said "nlips eval: error: out: Is a directory", naming no option."""
    folder = tmp_path / "out"
    folder.mkdir()
    assert main(["--log-file", str(folder), "cache"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"nlips cache: error: --log-file {folder}: a folder; give the file to append the log to (e.g. "
        f"{folder}/nlips.log)"
    ], err
    assert list(folder.iterdir()) == []
