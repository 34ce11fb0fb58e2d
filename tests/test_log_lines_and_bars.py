"""Log lines and live bars on one terminal: each log line on its own line, the bar drawn again below it; the
capture's and the twin's bars made by the shared helpers (quiet when stderr is not a terminal, closed on Ctrl-C)."""

from __future__ import annotations

import io
import logging
import re
import sys
import types

import pytest

from nlipscalib import progress
from tests.device.test_session import _quiet, _rig
from tests.solver import synth
from tests.test_notebook import _interrupted, _InterruptedWhileWriting, _open_bars


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def _screen(text: str) -> list[str]:
    """What a terminal shows after ``text``: a carriage return goes back to the line's start, later characters
    overwrite earlier ones (a bar's redraws, the spaces that clear it), ``ESC [A`` moves up a line (a nested
    bar's way back to the line above)."""
    rows: list[list[str]] = [[]]
    row = column = 0
    for part in _CURSOR_UP.split(text):
        if part == _UP:
            row = max(row - 1, 0)
            continue
        for char in part:
            if char == "\n":
                row, column = row + 1, 0
                rows.extend([] for _ in range(row + 1 - len(rows)))
            elif char == "\r":
                column = 0
            else:
                line = rows[row]
                line.extend(" " for _ in range(column + 1 - len(line)))
                line[column] = char
                column += 1
    return ["".join(line).rstrip() for line in rows]


_UP = "\x1b[A"
_CURSOR_UP = re.compile("(" + re.escape(_UP) + ")")


@pytest.fixture
def terminal(monkeypatch):
    """stderr a terminal, bars on, and a logger whose only handler is the one :func:`progress.configure` installs
    on stderr (pytest's own handlers stay on the root logger). Each test sets ``sys.stderr`` to the screen itself:
    pytest's capture sets it again between a fixture and the test."""
    screen = _Terminal()
    monkeypatch.setattr(progress, "_enabled", True)
    handler = progress.AboveTheBarsHandler(screen)
    handler.setFormatter(logging.Formatter(progress.STDERR_FORMAT))
    logger = logging.getLogger("nlipscalib.test_bars")
    logger.addHandler(handler)
    monkeypatch.setattr(logger, "propagate", False)
    monkeypatch.setattr(logger, "level", logging.INFO)
    yield screen, logger, handler
    logger.removeHandler(handler)


def test_a_line_logged_under_a_live_bar_gets_its_own_line_and_the_bar_is_drawn_below(terminal, monkeypatch):
    """``nlips -v solve FOLDER --workers 1`` wrote "presses:   0%|   | 0/3 [00:00<?, ?press/s]INFO ..." on one line."""
    screen, logger, _ = terminal
    monkeypatch.setattr("sys.stderr", screen)
    with progress.progress_bar(3, desc="presses", unit="press") as bar:
        logger.info("coin1: anchored 10 of 57 pixels")
        bar.update()
        logger.info("cube1: anchored 31 of 118 pixels")
        shown = _screen(screen.getvalue())
        assert shown[:2] == ["INFO coin1: anchored 10 of 57 pixels", "INFO cube1: anchored 31 of 118 pixels"]
        assert shown[2].startswith("presses:  33%") and len(shown) == 3  # the bar, below the lines, drawn again


def test_nested_bars_are_both_cleared_and_drawn_again_below_a_line(terminal, monkeypatch):
    """The solver's line under a batch's bar (position 1): both go below the log line."""
    screen, logger, _ = terminal
    monkeypatch.setattr("sys.stderr", screen)
    with progress.progress_bar(2, desc="presses") as outer, progress.progress_bar(5, desc="NLiPs", leave=False):
        logger.warning("a warning")
        shown = _screen(screen.getvalue())
        assert shown[0] == "WARNING a warning", shown
        assert any(line.startswith("presses:") for line in shown[1:]) and "NLiPs" in screen.getvalue()
        outer.update()


def test_without_a_bar_a_line_is_written_as_it_is(terminal, monkeypatch):
    screen, logger, _ = terminal
    monkeypatch.setattr("sys.stderr", screen)
    logger.info("no bar here")
    assert screen.getvalue() == "INFO no bar here\n"


def test_a_workers_line_blanks_the_terminal_line_where_the_parents_bar_is(terminal, monkeypatch):
    """A worker process of ``solve FOLDER`` (2 workers) cannot reach the parent's bar: its line starts by blanking
    the terminal's line, so it does not land after the bar's text."""
    screen, logger, handler = terminal
    monkeypatch.setattr("sys.stderr", screen)
    screen.write("\rpresses:   0%|          | 0/3 [00:00<?, ?press/s]")  # the parent's bar, as tqdm leaves it
    handler.blank_first = True
    logger.info("coin1: 57120/57120 pixels reconstructed")
    assert _screen(screen.getvalue()) == ["INFO coin1: 57120/57120 pixels reconstructed", ""]


def test_a_workers_line_to_a_log_file_or_pipe_is_not_blanked(monkeypatch):
    """No carriage returns in a log: blanking is for terminals only."""
    pipe = io.StringIO()
    handler = progress.AboveTheBarsHandler(pipe)
    handler.blank_first = True
    handler.setFormatter(logging.Formatter(progress.STDERR_FORMAT))
    handler.handle(logging.LogRecord("nlipscalib", logging.INFO, __file__, 0, "a line", None, None))
    assert pipe.getvalue() == "INFO a line\n"


def test_configure_installs_the_bar_aware_handler_on_stderr_and_workers_blank_first(monkeypatch):
    root = logging.getLogger()
    monkeypatch.setattr(root, "handlers", [])  # as in a command: no handler before configure
    monkeypatch.setattr(root, "level", root.level)
    progress.configure(progress=True)
    assert [type(h) for h in root.handlers] == [progress.AboveTheBarsHandler]
    assert not root.handlers[0].blank_first
    progress.configure_worker(logging.INFO)
    assert [h.blank_first for h in root.handlers] == [True]
    progress.configure(progress=True)  # the switch configure_worker turned off, back on


def test_a_batch_solve_logs_each_line_on_its_own_line_above_its_bar(terminal, monkeypatch, tmp_path):
    """The whole path of ``nlips -v solve FOLDER --workers 1``: every press line starts a line of its own."""
    from nlipscalib.pipeline import solve_presses

    screen, logger, handler = terminal
    monkeypatch.setattr("sys.stderr", screen)
    root = logging.getLogger()
    root.addHandler(handler)
    monkeypatch.setattr(root, "level", logging.DEBUG)  # -v: every press line
    for name in ("a", "b"):
        synth.make_press(tmp_path / name, "sphere", size=(64, 48))
    try:
        solve_presses([tmp_path / "a", tmp_path / "b"], progress=True, figures=False)
    finally:
        root.removeHandler(handler)
    shown = [line for line in _screen(screen.getvalue()) if line]
    logged = [line for line in shown if "INFO" in line or "WARNING" in line]
    assert len(logged) >= 2 and all(line.startswith(("INFO ", "WARNING ")) for line in logged), shown
    assert shown[-1].startswith("presses: 100%"), shown


def _emulated_sensor(rendered: list) -> object:
    from nlipscalib.emulator import EmulatedSensor

    script = [types.SimpleNamespace(press="press 1", moved=None), types.SimpleNamespace(press="press 2", moved="m")]
    renders = types.SimpleNamespace(images=rendered.append)
    return EmulatedSensor(
        rig=None,
        operator=types.SimpleNamespace(script=script),
        camera=types.SimpleNamespace(renders=renders),
        board=None,
        tricolor_level=1,
    )


def test_rendering_the_twin_is_quiet_when_stderr_is_not_a_terminal(monkeypatch):
    """It drew with tqdm itself, asked for by ``nlips capture`` with the twin: carriage-return bars in a log."""
    log = io.StringIO()
    monkeypatch.setattr("sys.stderr", log)
    monkeypatch.setattr(progress, "_enabled", True)
    rendered: list = []
    _emulated_sensor(rendered).prerender(progress=True)
    assert rendered == [None, "press 1", "press 2", "m"] and log.getvalue() == ""
    monkeypatch.setattr("sys.stderr", _Terminal())
    _emulated_sensor(rendered).prerender(progress=True)
    assert _screen(sys.stderr.getvalue())[-2].startswith("rendering the twin: 100%")  # on a terminal: the bar


def test_rendering_the_twin_interrupted_in_its_bars_first_draw_leaves_no_bar_open(monkeypatch):
    monkeypatch.setattr(progress, "_enabled", True)
    monkeypatch.setattr("sys.stderr", _InterruptedWhileWriting())
    before = _open_bars()
    kept = _interrupted(lambda: _emulated_sensor([]).prerender(progress=True))
    assert _open_bars() == before
    del kept


def test_a_capture_session_is_quiet_when_stderr_is_not_a_terminal(monkeypatch, tmp_path):
    from nlipscalib.device.session import SessionConfig, run_session

    log = io.StringIO()
    monkeypatch.setattr("sys.stderr", log)
    monkeypatch.setattr(progress, "_enabled", True)
    rig, _ = _rig()
    status = run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0], progress=True)
    assert (
        sorted(status) == ["press_0001", "reference"] and "\r" not in log.getvalue() and "capture" not in log.getvalue()
    )


def test_a_capture_session_interrupted_in_its_bars_first_draw_leaves_no_bar_open(monkeypatch, tmp_path):
    from nlipscalib.device.session import SessionConfig, run_session

    monkeypatch.setattr(progress, "_enabled", True)
    monkeypatch.setattr("sys.stderr", _InterruptedWhileWriting())
    rig, _ = _rig()
    before = _open_bars()
    kept = _interrupted(lambda: run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0], progress=True))
    assert _open_bars() == before
    assert not (tmp_path / "s" / "press_0001").exists()  # stopped before anything was captured
    del kept


def test_no_module_of_the_package_makes_a_tqdm_bar_itself():
    """One way to make a bar: :mod:`nlipscalib.progress`'s helpers (terminal/notebook rules, drawn outside tqdm's
    constructor)."""
    from pathlib import Path

    import nlipscalib

    root = Path(nlipscalib.__file__).parent
    direct = [
        f"{path.relative_to(root)}:{n}"
        for path in sorted(root.rglob("*.py"))
        if path.name != "progress.py" or path.parent != root
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if re.search(r"\b(tqdm|trange)\(", line.split("#")[0])
    ]
    assert direct == []


@pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX's")
def test_a_workers_blanking_spans_its_own_terminals_width_not_stdouts(monkeypatch):
    """With stdout redirected (``nlips solve FOLDER > summary.txt``) the terminal's width asked of stdout is 80
    columns: a wider bar's end stayed after a short line."""
    import fcntl
    import os
    import struct
    import termios

    parent, child = os.openpty()
    fcntl.ioctl(child, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 132, 0, 0))
    monkeypatch.setattr("sys.stdout", io.StringIO())
    with open(child, "w", encoding="utf-8") as stream:
        blank = progress._blank_line(stream)
    os.close(parent)
    assert blank == "\r" + " " * 131 + "\r"


def test_a_threads_line_does_not_wait_forever_on_a_bar_lock_an_interrupted_draw_kept(terminal, monkeypatch):
    """tqdm's ``refresh`` keeps its write lock held when Ctrl-C stops its draw (no ``finally``): a log line of
    another thread (a claim's heartbeat) then waited on that lock for good, hanging the command's end."""
    import threading

    from tqdm import tqdm

    screen, logger, _ = terminal
    monkeypatch.setattr("sys.stderr", screen)
    monkeypatch.setattr(progress, "BAR_LOCK_WAIT_S", 0.05)
    with progress.progress_bar(3, desc="presses"):
        lock = tqdm.get_lock()
        lock.acquire()  # as the interrupted draw left it, in this (the main) thread
        try:
            heartbeat = threading.Thread(target=logger.warning, args=("claim renewed late",), daemon=True)
            heartbeat.start()
            heartbeat.join(timeout=30)
            assert not heartbeat.is_alive()
        finally:
            lock.release()
    assert "WARNING claim renewed late" in _screen(screen.getvalue())
