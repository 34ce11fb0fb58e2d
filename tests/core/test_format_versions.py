"""A file of a format version this code does not read: one line naming the file, its version, the versions read
and what to do (upgrade nlipscalib for a newer one, remake it for any), built here as the format's docs describe."""

from __future__ import annotations

import json

import pytest

from nlipscalib.core import load_press
from nlipscalib.core.errors import CaptureError
from nlipscalib.core.formatfile import read_format_json


def _write(path, version, **extra):
    path.write_text(json.dumps({"format": "nlipscalib.example", "format_version": version} | extra), encoding="utf-8")
    return path


def test_a_newer_version_says_upgrade_and_an_unread_older_one_what_remakes_it(tmp_path):
    path = _write(tmp_path / "index.json", 3, made_by="nlips experiment")
    remake = lambda data: f"remake it ({data['made_by']})"  # noqa: E731 - the callable form the dataset uses
    with pytest.raises(CaptureError) as newer:
        read_format_json(path, "nlipscalib.example", (1, 2), remake=remake)
    assert str(newer.value) == (
        f"{path}: format_version 3 is not supported (expected 1 or 2); written by a newer nlipscalib: upgrade "
        "nlipscalib to read it, or remake it (nlips experiment)"
    )
    _write(path, 0)
    with pytest.raises(CaptureError) as older:
        read_format_json(path, "nlipscalib.example", (1, 2), remake="run `nlips calibrate` again")
    assert (
        str(older.value) == f"{path}: format_version 0 is not supported (expected 1 or 2); run `nlips calibrate` again"
    )
    assert read_format_json(_write(path, 2), "nlipscalib.example", (1, 2))["format_version"] == 2


def test_a_capture_of_a_newer_format_asks_for_a_newer_nlipscalib(tmp_path):
    press = tmp_path / "press_0001"
    press.mkdir()
    meta = {"format": "nlipscalib.press", "format_version": 4, "camera": {}, "leds": [], "sensor": {}, "images": {}}
    (press / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    newer = r"meta\.json: format_version 4 is not supported \(expected 1, 2 or 3\); written by a newer nlipscalib"
    with pytest.raises(CaptureError, match=newer + ": upgrade nlipscalib to read it$"):
        load_press(press)
