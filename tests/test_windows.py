"""Windows' behaviour, taken away or imitated on Linux: a file held open by another program, log lines of several
processes in one file, Ctrl-Break, the 260-character path limit (README "Platforms")."""

from __future__ import annotations

import errno
import os
import sys

import pytest

from nlipscalib.cli import describe_os_error
from nlipscalib.core import atomic


def _held_open_until(monkeypatch, held: list[str], refusals: int) -> list[float]:
    """``os.replace``/``os.rename`` refused as Windows refuses them while another program holds the target open,
    (or a file in a folder being moved), ``refusals`` times; returns the list the waits between tries go to."""
    real_replace, real_rename, waits = os.replace, os.rename, []

    def refused(real):
        def call(source, target, *args, **kwargs):
            if {os.fspath(source), os.fspath(target)} & set(held) and len(waits) < refusals:
                raise PermissionError(errno.EACCES, "Access is denied", os.fspath(source), None, os.fspath(target))
            return real(source, target, *args, **kwargs)

        return call

    monkeypatch.setattr(sys, "platform", "win32")
    monkeypatch.setattr(os, "replace", refused(real_replace))
    monkeypatch.setattr(os, "rename", refused(real_rename))
    monkeypatch.setattr(atomic.time, "sleep", waits.append)
    return waits


def test_a_file_held_open_for_a_moment_on_windows_is_replaced_after_a_wait(tmp_path, monkeypatch):
    target = tmp_path / "result.csv"
    target.write_text("old", encoding="utf-8")
    waits = _held_open_until(monkeypatch, [str(target)], refusals=2)  # an antivirus scan
    atomic.write_text(target, "new")
    assert target.read_text(encoding="utf-8") == "new"
    assert waits == list(atomic.HELD_OPEN_WAITS_S[:2])
    assert [p.name for p in tmp_path.iterdir()] == ["result.csv"]


def test_a_file_held_open_on_windows_fails_after_about_a_second_naming_it(tmp_path, monkeypatch):
    target = tmp_path / "result.csv"
    target.write_text("old", encoding="utf-8")
    waits = _held_open_until(monkeypatch, [str(target)], refusals=100)  # Excel
    with pytest.raises(PermissionError) as info:
        atomic.write_text(target, "new")
    assert 0.5 <= sum(waits) <= 1.5
    assert describe_os_error(info.value) == f"{target}: {atomic.HELD_OPEN}"
    assert target.read_text(encoding="utf-8") == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["result.csv"]


def test_a_folder_with_a_file_held_open_on_windows_is_swapped_after_a_wait(tmp_path, monkeypatch):
    report = tmp_path / "report"
    report.mkdir()
    (report / "results.json").write_text("old", encoding="utf-8")
    waits = _held_open_until(monkeypatch, [str(report)], refusals=1)  # a viewer closing its figure
    with atomic.whole_dir(report, "results.json") as tmp:
        (tmp / "results.json").write_text("new", encoding="utf-8")
    assert (report / "results.json").read_text(encoding="utf-8") == "new"
    assert waits == [atomic.HELD_OPEN_WAITS_S[0]]


def test_a_permission_error_on_linux_is_raised_at_once(tmp_path, monkeypatch):
    target = tmp_path / "result.csv"
    waits = _held_open_until(monkeypatch, [str(target)], refusals=100)
    monkeypatch.setattr(sys, "platform", "linux")
    with pytest.raises(PermissionError) as info:
        atomic.write_text(target, "new")
    assert waits == [] and info.value.errno == errno.EACCES
