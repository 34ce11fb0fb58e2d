"""Progress bars only on a terminal (never in logs), a global --no-progress, and an optional log file."""

from __future__ import annotations

import io
import logging
import re

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


class _KernelStream(io.StringIO):
    """Stands for ipykernel's OutStream (a notebook's stderr): not a terminal, drawn under the cell."""

    def isatty(self):
        return False


_KernelStream.__module__ = "ipykernel.iostream"


class _SpyderStream(_KernelStream):  # a kernel's stream subclassed elsewhere (Spyder's console)
    pass


_SpyderStream.__module__ = "spyder_kernels.console.outstream"


def test_bars_in_a_notebook_but_not_in_a_log_file_it_redirects_to(monkeypatch, tmp_path):
    """A notebook's stderr is not a terminal, so a notebook user saw no bar at all; it shows the plain bar (no
    ipywidgets needed). A file the notebook redirects stderr to stays quiet."""
    for stream in (_KernelStream(), _SpyderStream()):
        monkeypatch.setattr("sys.stderr", stream)
        progress.configure(progress=True)
        assert progress.bars_enabled(), type(stream)
        with progress.progress_bar(3, desc="solve") as bar:  # to sys.stderr, as the package's bars are
            bar.update(3)
        assert "\r" in stream.getvalue() and "3/3" in stream.getvalue()
        assert not progress.bars_enabled(requested=False)  # a function's progress=False
        progress.configure(progress=False)
        assert not progress.bars_enabled()
    progress.configure(progress=True)
    with open(tmp_path / "cell.log", "w", encoding="utf-8") as log:
        monkeypatch.setattr("sys.stderr", log)
        assert not progress.bars_enabled()
    monkeypatch.setattr("sys.stderr", None)  # pythonw, a daemon with fd 2 closed: no bar, no error
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


def test_a_log_file_typed_as_a_folder_is_one_line_naming_the_option(tmp_path, capsys):
    """`nlips --log-file logs/ cache` (a folder meant, not there yet) said "nlips cache: error: logs: Is a
    directory", naming no option."""
    typed = f"{tmp_path / 'logs'}/"
    assert main(["--log-file", typed, "cache"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"nlips cache: error: --log-file {typed}: a folder; give the file to append the log to (e.g. "
        f"{tmp_path / 'logs' / 'nlips.log'})"
    ], err
    assert not (tmp_path / "logs").exists()


LINE = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3} \[\d+\] (DEBUG|INFO|WARNING|ERROR|CRITICAL) \S+: ")
"""A log file's line: timestamp, process id, level, logger."""


def test_the_log_file_says_which_command_started_and_how_it_ended_and_runs_append(tmp_path, capsys):
    """A log read a day later had no line saying where a run began, what was run (version, command line,
    working folder) or how it ended: a run's last line was its last result, whatever its exit status."""
    import os

    from nlipscalib import __version__

    log = tmp_path / "lab.log"
    assert main(["--log-file", str(log), "cache"]) == 0
    assert main(["cache", "--log-file", str(log)]) == 0  # a second run appends
    lines = log.read_text(encoding="utf-8").splitlines()
    assert all(LINE.match(line) for line in lines), lines
    starts = [i for i, line in enumerate(lines) if " started (pid " in line]
    assert len(starts) == 2 and starts[0] == 0, lines
    assert (
        f"nlips {__version__} started (pid {os.getpid()}, in {os.getcwd()}): nlips --log-file {log} cache" in (lines[0])
    )
    ends = [i for i, line in enumerate(lines) if "nlips cache ended: exit status 0 after" in line]
    assert ends == [starts[1] - 1, len(lines) - 1], lines


def test_an_error_that_ends_the_command_and_its_exit_status_are_in_the_log_file(tmp_path, capsys):
    log = tmp_path / "lab.log"
    missing = tmp_path / "missing"
    assert main(["--log-file", str(log), "solve", str(missing)]) == 2
    text = log.read_text(encoding="utf-8")
    assert f"ERROR nlipscalib: nlips solve: {missing}" in text
    assert text.splitlines()[-1].split("] ", 1)[1].startswith("ERROR nlipscalib: nlips solve ended: exit status 2")
    assert capsys.readouterr().err.count("\n") == 1  # stderr stays one line


def test_an_unexpected_error_leaves_its_traceback_and_status_in_the_log_file(tmp_path, monkeypatch, capsys):
    from nlipscalib.cli import cache

    def broken(args):
        raise RuntimeError("a bug")

    monkeypatch.setattr(cache, "run", broken)
    log = tmp_path / "lab.log"
    with pytest.raises(RuntimeError):
        main(["--log-file", str(log), "cache"])
    text = log.read_text(encoding="utf-8")
    assert "ERROR nlipscalib: nlips cache: unexpected error\nTraceback (most recent call last):" in text
    assert "RuntimeError: a bug" in text and "nlips cache ended: exit status 1" in text.splitlines()[-1]


def test_an_interrupted_command_says_so_in_the_log_file(tmp_path, monkeypatch, capsys):
    from nlipscalib.cli import cache

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cache, "run", interrupted)
    log = tmp_path / "lab.log"
    assert main(["--log-file", str(log), "cache"]) == 130
    lines = log.read_text(encoding="utf-8").splitlines()
    assert "WARNING nlipscalib: nlips cache: interrupted;" in lines[-2] and "exit status 130" in lines[-1], lines


def test_verbose_shows_our_debug_lines_not_the_libraries(tmp_path, capsys):
    """`nlips -v --log-file F train` for a minute wrote 2,200 lines, 2,191 of them matplotlib's font scoring."""
    log = tmp_path / "lab.log"
    progress.configure(progress=False, verbose=True, log_file=log)
    logging.getLogger("matplotlib.font_manager").debug("findfont: score(FontEntry(...)) = 10.05")
    logging.getLogger("nlipscalib.solver").debug("kept: identical result")
    logging.getLogger("distributed.worker").warning("a library's warning still shows")
    text = log.read_text(encoding="utf-8")
    assert "findfont" not in text and "kept: identical result" in text and "a library's warning" in text
    assert "findfont" not in capsys.readouterr().err


def test_a_file_only_line_reaches_stderr_only_with_verbose():
    record = logging.LogRecord("nlipscalib.learn.train", logging.INFO, __file__, 0, "epoch 3", None, None)
    record.__dict__.update(progress.FILE_ONLY)
    progress.configure(progress=False)
    assert not progress._shown_on_stderr(record)
    progress.configure(progress=False, verbose=True)
    assert progress._shown_on_stderr(record)


def test_a_dataset_logs_each_press_and_how_far_it_got_in_the_log_file_without_verbose(tmp_path, monkeypatch, capsys):
    """A long `nlips --log-file F dataset` left only its end in F: the presses were logged at DEBUG (-v only)."""
    spec, out, log = tmp_path / "spec.toml", tmp_path / "out", tmp_path / "run.log"
    spec.write_text(SPEC, encoding="utf-8")
    monkeypatch.setattr(dataset_pool, "_run_one", _fake_render([]))
    assert main(["--log-file", str(log), "dataset", str(spec), "--out", str(out), "--workers", "1"]) == 0
    lines = [
        line.split(": ", 1)[1]
        for line in log.read_text(encoding="utf-8").splitlines()
        if "] INFO nlipscalib.sim." in line
    ]
    presses = [line for line in lines if line.startswith("press ")]
    assert presses and presses[-1].endswith(f"rendered ({len(presses)} of {len(presses)})"), lines


def test_a_terminal_of_no_size_still_shows_the_bars(monkeypatch):
    """A terminal that reports 0 x 0 (a pty made by `script`, some `docker exec -t` and CI runners): tqdm took -1 x -1
    and drew nothing, not the bar, not its last line (s35-walk)."""
    import os
    import sys

    class Terminal(io.StringIO):
        def isatty(self):
            return True

        def fileno(self):
            return 2

    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    monkeypatch.setattr(os, "get_terminal_size", lambda fd=None: os.terminal_size((0, 0)))
    monkeypatch.setattr("tqdm.std._screen_shape_wrapper", lambda: lambda fp: (-1, -1))  # what tqdm measured there
    progress.configure(progress=True)
    with progress.progress_bar(3, desc="presses") as bar:
        bar.update(3)
    assert "presses: 100%" in terminal.getvalue() and "3/3" in terminal.getvalue(), terminal.getvalue()
    assert (bar.ncols, bar.nrows) == progress.UNSIZED_TERMINAL
