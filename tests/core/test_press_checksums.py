"""A press folder's checksums.json (core.press_checksums): written with every press, and what a rerun finds with
it that a file's ends do not show (a file damaged inside, another whole image copied over it)."""

import json
import zlib

import numpy as np
import pytest

from nlipscalib.core import press_checksums
from nlipscalib.core.errors import CaptureError
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


# ---------------------------------------------------------------------- the commands that read presses (s34)
def test_changed_files_finds_another_whole_file_copied_over_one_and_leaves_cut_short_ones_to_the_reader(tmp_path):
    """What solve, calibrate and train refuse: a whole file of another size. A file cut short or gone is named by
    the press's reader as before (a batch fails that press alone), so it is not counted here."""
    folder = _press(tmp_path / "p")
    assert press_checksums.changed_files(folder) == {}
    write_png16(folder / "led_02.png", np.zeros((12, 16, 3), np.uint16))
    (folder / "led_03.png").write_bytes((folder / "led_03.png").read_bytes()[:100])
    (folder / "dark.png").unlink()
    size, recorded = (folder / "led_02.png").stat().st_size, read_checksums(folder)["led_02.png"]["bytes"]
    said = f"changed since it was written ({size} bytes, checksums.json records {recorded})"
    assert press_checksums.changed_files(folder) == {"led_02.png": said}
    (folder / CHECKSUMS_FILE).unlink()  # written before the record: nothing to compare with
    assert press_checksums.changed_files(folder) == {}


def test_check_unchanged_names_the_first_changed_file_the_other_presses_and_the_option(tmp_path):
    folders = [_press(tmp_path / f"p{i}") for i in range(3)]
    press_checksums.check_unchanged(folders)  # every one as written: nothing said
    for folder in folders[1:]:
        write_png16(folder / "tricolor.png", np.zeros((12, 16, 3), np.uint16))
    write_png16(folders[2] / "led_01.png", np.zeros((12, 16, 3), np.uint16))
    with pytest.raises(CaptureError) as caught:
        press_checksums.check_unchanged(folders)
    line = str(caught.value)
    assert line.startswith(f"{folders[1] / 'tricolor.png'}: changed since it was written (")
    assert f"; 1 other press changed too ({folders[2]})" in line and "--allow-edited" in line
    assert "\n" not in line


def test_files_as_read_and_changed_since_tell_a_press_written_anew_or_copied_over_after_it_was_sampled(tmp_path):
    folder = _press(tmp_path / "p")
    names = _names(folder)
    recorded = read_checksums(folder)
    files = press_checksums.files_as_read(folder, names)
    assert files == {name: {"bytes": recorded[name]["bytes"], "crc32": recorded[name]["crc32"]} for name in names}
    assert press_checksums.changed_since(folder, files) == {}
    # the press written anew at the same sizes (a capture again): its new record's CRC-32 differs
    record = json.loads((folder / CHECKSUMS_FILE).read_bytes())
    record["files"]["led_01.png"]["crc32"] = "00000000"
    (folder / CHECKSUMS_FILE).write_text(json.dumps(record), encoding="utf-8")
    said = "written anew since it was sampled (its checksums.json records another CRC-32)"
    assert press_checksums.changed_since(folder, files) == {"led_01.png": said}
    # another image copied over one, and one deleted
    write_png16(folder / "led_02.png", np.zeros((12, 16, 3), np.uint16))
    (folder / "gt.npz").unlink()
    changed = press_checksums.changed_since(folder, files)
    size = (folder / "led_02.png").stat().st_size
    assert changed["led_02.png"] == f"changed since it was sampled ({size} bytes, {files['led_02.png']['bytes']} then)"
    assert changed["gt.npz"] == "missing (there when it was sampled)"


def test_a_file_edited_on_purpose_is_recorded_by_its_size_alone(tmp_path):
    """Sampled with --allow-edited: the press's record no longer vouches for the file, so no CRC-32 is kept."""
    folder = _press(tmp_path / "p")
    write_png16(folder / "led_02.png", np.zeros((12, 16, 3), np.uint16))
    files = press_checksums.files_as_read(folder, _names(folder))
    assert files["led_02.png"] == {"bytes": (folder / "led_02.png").stat().st_size} and "crc32" in files["led_01.png"]


# ---------------------------------------------------------------------- a record for older folders (s34)
def _older(folder):
    """``folder`` as an nlipscalib before 2026-12-06 left it: no checksums.json."""
    (folder / CHECKSUMS_FILE).unlink()
    return folder


def test_record_checksums_gives_a_whole_older_press_the_record_a_new_press_gets(tmp_path):
    folder = _press(tmp_path / "p")
    written = (folder / CHECKSUMS_FILE).read_bytes()
    _older(folder)
    assert press_checksums.record_checksums(folder) == press_checksums.RECORDED
    assert json.loads((folder / CHECKSUMS_FILE).read_bytes()) == json.loads(written)
    assert press_checksums.record_checksums(folder) == press_checksums.HAD_ONE
    assert not [p for p in folder.iterdir() if p.name.startswith(".tmp-")]


def test_record_checksums_records_nothing_for_a_damaged_press(tmp_path):
    folder = _older(_press(tmp_path / "p"))
    _flip_inside(folder / "led_02.png")
    said = press_checksums.record_checksums(folder)
    assert said.startswith("led_02.png damaged inside (chunk ") and not (folder / CHECKSUMS_FILE).exists()
    folder = _older(_press(tmp_path / "q"))
    write_png16(folder / "led_01.png", np.zeros((6, 8, 3), np.uint16))  # whole, of another camera's size
    said = press_checksums.record_checksums(folder)
    assert "led_01.png" in said and "16x12" in said.replace(" x ", "x") and not (folder / CHECKSUMS_FILE).exists()


def test_record_checksums_keeps_a_record_another_process_wrote_meanwhile(tmp_path, monkeypatch):
    """A press written anew by `nlips dataset --overwrite` (or another verify) while this one read the files: its
    record stays, never replaced by one of the files read before."""
    folder = _older(_press(tmp_path / "p"))
    theirs = b'{"format": "theirs"}\n'
    crc = press_checksums.file_crc32

    def other_writes_meanwhile(path):
        if not (folder / CHECKSUMS_FILE).exists():
            (folder / CHECKSUMS_FILE).write_bytes(theirs)
        return crc(path)

    monkeypatch.setattr(press_checksums, "file_crc32", other_writes_meanwhile)
    assert press_checksums.record_checksums(folder) == press_checksums.HAD_ONE
    assert (folder / CHECKSUMS_FILE).read_bytes() == theirs


def test_record_checksums_records_nothing_when_a_file_changes_while_it_is_read(tmp_path, monkeypatch):
    folder = _older(_press(tmp_path / "p"))
    crc = press_checksums.file_crc32

    def rewritten_meanwhile(path):
        if path.name == "led_03.png":
            write_png16(folder / "led_01.png", np.zeros((12, 16, 3), np.uint16))
        return crc(path)

    monkeypatch.setattr(press_checksums, "file_crc32", rewritten_meanwhile)
    assert "changed while they were read" in press_checksums.record_checksums(folder)
    assert not (folder / CHECKSUMS_FILE).exists()


def test_write_new_never_replaces_a_file(tmp_path):
    from nlipscalib.core.atomic import write_new

    path = tmp_path / "x.json"
    assert write_new(path, b"one") and path.read_bytes() == b"one"
    assert not write_new(path, b"two") and path.read_bytes() == b"one"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.json"]
