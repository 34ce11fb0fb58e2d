"""A press folder's checksums.json (core.press_checksums): written with every press, and what a rerun finds with
it that a file's ends do not show (a file damaged inside, another whole image copied over it)."""

import json
import zlib

import numpy as np
import pytest

from nlipscalib.core import press_checksums
from nlipscalib.core.imageio import write_png16
from nlipscalib.core.press_checksums import (
    CHECKSUMS_FILE,
    press_file_problems,
    read_checksums,
    write_checksums,
)
from nlipscalib.core.press_meta import listed_files, read_meta

from .test_capture import _press


def _names(folder):
    return listed_files(read_meta(folder))


def _flip_inside(path):
    """One byte in the middle of ``path`` changed: the file keeps its size and its ends (a bad block, a bad copy)."""
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def test_every_press_written_records_each_listed_file_with_its_size_and_crc32(tmp_path):
    folder = _press(tmp_path / "p")
    names = _names(folder)
    assert names == ["dark.png", "tricolor.png", "led_01.png", "led_02.png", "led_03.png", "reference.npz", "gt.npz"]
    record = json.loads((folder / CHECKSUMS_FILE).read_bytes())
    assert record["format"] == "nlipscalib.checksums" and list(record["files"]) == names
    for name in names:
        data = (folder / name).read_bytes()
        assert record["files"][name] == {"bytes": len(data), "crc32": f"{zlib.crc32(data):08x}"}
    assert press_file_problems(folder, names) == {} and press_file_problems(folder, names, verify=True) == {}


def test_another_whole_image_copied_over_one_is_found_by_its_size_without_reading_it(tmp_path, monkeypatch):
    folder = _press(tmp_path / "p")
    write_png16(folder / "led_02.png", np.zeros((12, 16, 3), np.uint16))  # whole, at its ends: another image
    monkeypatch.setattr(press_checksums, "file_crc32", lambda path: pytest.fail("read without --verify"))
    problems = press_file_problems(folder, _names(folder))
    recorded = read_checksums(folder)["led_02.png"]["bytes"]
    size = (folder / "led_02.png").stat().st_size
    assert problems == {"led_02.png": f"changed since it was written ({size} bytes, checksums.json records {recorded})"}


def test_a_file_damaged_inside_at_its_size_is_found_only_when_verified(tmp_path):
    folder = _press(tmp_path / "p")
    names = _names(folder)
    _flip_inside(folder / "gt.npz")
    assert press_file_problems(folder, names) == {}  # ends and size as written: a rerun reads no more than that
    said = "changed since it was written (its CRC-32 is not the one checksums.json records)"
    assert press_file_problems(folder, names, verify=True) == {"gt.npz": said}


@pytest.mark.parametrize("cut", ["truncated", "deleted"])
def test_a_file_cut_short_or_deleted_is_named_by_its_ends_before_its_record(tmp_path, cut):
    folder = _press(tmp_path / "p")
    path = folder / "led_03.png"
    if cut == "truncated":
        path.write_bytes(path.read_bytes()[:100])
    else:
        path.unlink()
    said = "cut short (no PNG end chunk)" if cut == "truncated" else "missing"
    assert press_file_problems(folder, _names(folder)) == {"led_03.png": said}


@pytest.mark.parametrize("record", ["none", "torn", "other format"])
def test_a_folder_without_a_readable_record_is_judged_as_before_and_verified_by_the_formats_own_checksums(
    tmp_path, record
):
    """A press of an older nlipscalib (no checksums.json), or whose record is damaged, is trusted as before: its
    files' ends; ``verify`` reads each file's own CRC-32s (a PNG's chunks, an .npz's members) instead."""
    folder = _press(tmp_path / "p")
    names = _names(folder)
    path = folder / CHECKSUMS_FILE
    if record == "none":
        path.unlink()
    elif record == "torn":
        path.write_bytes(path.read_bytes()[:40])
    else:
        path.write_text(json.dumps({"format": "something else", "files": {}}), encoding="utf-8")
    assert read_checksums(folder) == {}
    write_png16(folder / "led_01.png", np.zeros((12, 16, 3), np.uint16))  # another whole image: not seen
    _flip_inside(folder / "led_02.png")
    assert press_file_problems(folder, names) == {}
    problems = press_file_problems(folder, names, verify=True)
    assert list(problems) == ["led_02.png"] and problems["led_02.png"].startswith("damaged inside (chunk ")


def test_a_record_written_again_follows_the_files(tmp_path):
    folder = _press(tmp_path / "p")
    names = _names(folder)
    _flip_inside(folder / "dark.png")
    write_checksums(folder, names)
    assert press_file_problems(folder, names, verify=True) == {}
