"""What a solved press says on stderr: everything for one press, one line per press in a batch, details with -v.

Run as a user runs it (a process of its own): the filter sits on the command's own stderr handler, which pytest's
handlers would replace in-process.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.solver import synth

ROOT = Path(__file__).resolve().parents[2]
DETAILS = ("anchored", "anchoring")  # the anchoring decision's line (anchored N of M pixels, or anchoring off)
SUMMARY = "pixels reconstructed"


@pytest.fixture(scope="module")
def presses(tmp_path_factory):
    root = tmp_path_factory.mktemp("press_lines")
    for name, shape in (("press_a", "sphere"), ("press_b", "cube")):
        synth.make_press(root / name, shape, size=(64, 48))
    (root / "solver.toml").write_text("max_iters = 3\n", encoding="utf-8")
    return root


def _nlips(*args: str) -> str:
    run = subprocess.run(
        [sys.executable, "-m", "nlipscalib", "--no-progress", *args], capture_output=True, text=True, cwd=ROOT
    )
    assert run.returncode == 0, run.stderr
    return run.stderr


def _lines(stderr: str, *words: str) -> list[str]:
    return [line for line in stderr.splitlines() if any(w in line for w in words)]


def test_one_press_says_what_was_decided(presses, tmp_path):
    err = _nlips(
        "solve", str(presses / "press_a"), "--out", str(tmp_path / "a"), "--config", str(presses / "solver.toml")
    )
    assert len(_lines(err, *DETAILS)) == 1 and len(_lines(err, SUMMARY)) == 1, err


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_folder_of_presses_says_one_line_per_press(presses, tmp_path, workers):
    folder = tmp_path / "presses"
    for name in ("press_a", "press_b"):
        _copy(presses / name, folder / name)
    log = tmp_path / "run.log"
    err = _nlips(
        "--log-file", str(log), "solve", str(folder), "--workers", workers, "--config", str(presses / "solver.toml")
    )
    assert _lines(err, *DETAILS) == [], err  # in the worker processes too
    assert len(_lines(err, SUMMARY)) == 2, err
    assert len(_lines(log.read_text(encoding="utf-8"), *DETAILS)) == 2  # the log file keeps every line


def test_verbose_shows_each_press_details_in_a_batch(presses, tmp_path):
    folder = tmp_path / "presses"
    for name in ("press_a", "press_b"):
        _copy(presses / name, folder / name)
    err = _nlips("-v", "solve", str(folder), "--config", str(presses / "solver.toml"))
    assert len(_lines(err, *DETAILS)) == 2 and len(_lines(err, SUMMARY)) == 2, err


def test_one_press_prints_where_its_result_is_on_stdout_alone(presses, tmp_path):
    """`nlips solve PRESS` said where its result went on stderr only (an INFO line among others): a script had to
    parse the log. Now stdout is that folder, one line; stderr as before."""
    out = tmp_path / "a"
    run = subprocess.run(
        [sys.executable, "-m", "nlipscalib", "--no-progress", "solve", str(presses / "press_a"), "--out", str(out)]
        + ["--config", str(presses / "solver.toml")],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert run.returncode == 0 and run.stdout == f"{out}\n", run
    assert len(_lines(run.stderr, SUMMARY)) == 1 and len(_lines(run.stderr, *DETAILS)) == 1, run.stderr


@pytest.mark.parametrize("workers", ["1", "2"])
def test_quiet_leaves_stderr_to_warnings_and_errors(presses, tmp_path, workers):
    """No `--quiet`: INFO lines always reached stderr (`2>/dev/null` hid the warnings too). Now `nlips --quiet`
    leaves stderr to warnings and errors, in the worker processes too; stdout keeps the results, the --log-file
    every line."""
    folder, log = tmp_path / "presses", tmp_path / "run.log"
    run = _solve_with_a_failing_press(presses, folder, log, workers, "--quiet")
    assert run.returncode == 1 and run.stdout == f"{folder / 'press_a' / 'nlips'}\n", run
    err = run.stderr.splitlines()
    assert not [line for line in err if line.startswith("INFO ")] and not _lines(run.stderr, SUMMARY), err
    assert any(line.startswith("ERROR ") and "led_03.png" in line for line in err), err  # the failure, as it came
    assert "1 solved, 0 skipped (identical result), 1 failed" in err, err  # the counts: a failure among them
    in_log = log.read_text(encoding="utf-8")
    assert len(_lines(in_log, SUMMARY)) == 1 and "1 solved, 0 skipped" in in_log, in_log


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_failed_press_of_a_folder_says_its_error_once(presses, tmp_path, workers):
    """`nlips solve FOLDER` printed each failed press's error twice: as it happened (ERROR), then again under the
    closing counts. Now the counts name the failed presses, their errors said once above; exit 1 still."""
    folder, log = tmp_path / "presses", tmp_path / "run.log"
    run = _solve_with_a_failing_press(presses, folder, log, workers, "--no-progress")
    assert run.returncode == 1 and run.stdout == f"{folder / 'press_a' / 'nlips'}\n", run
    err = run.stderr.splitlines()
    assert len(_lines(run.stderr, "led_03.png")) == 1, err  # the error, once
    assert "1 solved, 0 skipped (identical result), 1 failed" in err, err
    assert "  failed, each said above: press_b" in err, err
    assert len(_lines(log.read_text(encoding="utf-8"), "led_03.png")) == 1  # the log file holds it once too


def _copy(src: Path, dst: Path) -> None:
    import shutil

    shutil.copytree(src, dst)


@pytest.fixture
def command_stderr(monkeypatch):
    """A function that empties the root logger's handlers as in a process of its own (pytest adds its own after
    the fixtures), so the command adds its stderr handler; pytest's come back after the test."""
    import logging

    from nlipscalib import progress

    yield lambda: monkeypatch.setattr(logging.getLogger(), "handlers", [])
    monkeypatch.undo()
    progress.configure(progress=True)


@pytest.mark.parametrize(
    ("argv", "shown"),
    [
        (["eval", "missing"], {"detail", "summary", "warning"}),  # not a batch: every line
        (["experiment", "q1", "--plan"], {"warning"}),  # the task bar and the report say how the presses went
        (["-v", "experiment", "q1", "--plan"], {"detail", "summary", "warning"}),
        (["demo", "--solve-workers", "-1"], {"summary", "warning"}),  # its table says the rest
    ],
)
def test_experiments_say_nothing_per_press_unless_verbose(command_stderr, tmp_path, capsys, argv, shown):
    import logging

    from nlipscalib.cli import main
    from nlipscalib.progress import PRESS_DETAIL, PRESS_SUMMARY

    command_stderr()
    main([*argv, "--out", str(tmp_path)] if argv[-1] != "missing" else [*argv[:-1], str(tmp_path / "missing")])
    log = logging.getLogger("nlipscalib.solver.press")
    log.info("detail", extra=PRESS_DETAIL)
    log.info("summary", extra=PRESS_SUMMARY)
    log.warning("warning")
    err = capsys.readouterr().err
    assert {word for word in ("detail", "summary", "warning") if f" {word}\n" in err} == shown, err


@pytest.mark.parametrize("verbose", [False, True])
def test_a_local_dask_cluster_logs_as_the_command_says(tmp_path, verbose):
    """Dask workers set up only dask.distributed's loggers: their presses' lines reached neither the --log-file nor,
    with -v, stderr. Now they follow the command's choice (none on stderr in an experiment, all with -v)."""
    pytest.importorskip("distributed")
    log = tmp_path / "run.log"
    flags = ["-v"] if verbose else []
    args = ["--log-file", str(log), *flags, "experiment", "q1", "--scheduler", "local:1", "--out", str(tmp_path / "w")]
    err = _nlips(*args, "--solver-option", "max_iters=2")
    in_log = log.read_text(encoding="utf-8")
    assert len(_lines(in_log, SUMMARY)) == 4 and len(_lines(in_log, *DETAILS)) == 4, in_log
    assert len(_lines(err, SUMMARY)) == (4 if verbose else 0), err


def _solve_with_a_failing_press(presses, folder, log, workers: str, flag: str) -> subprocess.CompletedProcess:
    """`nlips FLAG --log-file LOG solve FOLDER --workers N` in a process of its own, FOLDER holding press_a and a
    press_b whose led_03.png is cut short (it fails: an ERROR line and the summary's count)."""
    for name in ("press_a", "press_b"):
        _copy(presses / name, folder / name)
    led = folder / "press_b" / "led_03.png"
    led.write_bytes(led.read_bytes()[:100])
    return subprocess.run(
        [sys.executable, "-m", "nlipscalib", flag, "--log-file", str(log), "solve", str(folder)]
        + ["--workers", workers, "--config", str(presses / "solver.toml")],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
