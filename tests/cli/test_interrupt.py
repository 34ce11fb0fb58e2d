"""Ctrl-C during a command: one line, exit 130, whatever exception the interrupted code turned it into."""

from __future__ import annotations

import os
import signal

import pytest

from nlipscalib import cli
from nlipscalib.cli import cache, main


@pytest.fixture
def default_sigint():
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # as a command-line process has it
    yield
    signal.signal(signal.SIGINT, previous)


def _interrupted_inside_a_native_library(args):
    try:
        os.kill(os.getpid(), signal.SIGINT)
        raise AssertionError("the interrupt did not arrive")
    except KeyboardInterrupt as exc:  # what drjit does with it: its own exception
        raise RuntimeError("drjit.custom(...): error while performing a custom differentiable operation") from exc


def test_ctrl_c_turned_into_another_exception_still_reads_as_an_interruption(monkeypatch, capsys, default_sigint):
    monkeypatch.setattr(cache, "run", _interrupted_inside_a_native_library)
    assert main(["cache"]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "Traceback" not in err and "drjit" not in err
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handler is put back


def test_the_same_exception_without_ctrl_c_is_not_hidden(monkeypatch, default_sigint):
    def fails(args):
        raise RuntimeError("a real bug")

    monkeypatch.setattr(cache, "run", fails)
    with pytest.raises(RuntimeError, match="a real bug"):
        main(["cache"])
    assert not cli._INTERRUPTED
