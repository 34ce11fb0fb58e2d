"""core.file_checks: a finished file judged whole or torn from the bytes at its ends, or damaged inside from all of
its bytes."""

from __future__ import annotations

import io
import json
import zipfile

import cv2
import numpy as np
import pytest

from nlipscalib.core.file_checks import damage_inside, described_problems, file_problem, unusable_files


def _whole(suffix: str) -> bytes:
    if suffix == ".png":
        rng = np.random.default_rng(0)
        return cv2.imencode(".png", rng.integers(0, 65535, (48, 64), dtype=np.uint16))[1].tobytes()
    if suffix == ".json":
        return json.dumps({"images": {"dark": "dark.png"}, "n": [1, 2, 3]}).encode()
    buf = io.BytesIO()
    np.savez_compressed(buf, depth=np.linspace(0.0, 1.0, 3000), mask=np.ones((40, 30), bool))
    return buf.getvalue()


@pytest.mark.parametrize("suffix", [".png", ".npz", ".json"])
def test_a_whole_file_passes_and_every_cut_of_it_is_named(tmp_path, suffix):
    """A power cut after a file was published leaves it empty or cut short at any length: each cut is caught (a
    PNG loses its IEND chunk, an .npz its end record, a JSON text its closing brace)."""
    path = tmp_path / f"f{suffix}"
    whole = _whole(suffix)
    path.write_bytes(whole)
    assert file_problem(path) is None
    for length in sorted({0, 1, 2, 8, 12, len(whole) // 3, len(whole) // 2, len(whole) - 12, len(whole) - 1}):
        path.write_bytes(whole[:length])
        problem = file_problem(path)
        assert problem is not None, length
        assert problem == "empty" if length == 0 else "cut short" in problem or "damaged" in problem, (length, problem)


def test_zeros_at_the_start_missing_files_and_folders_are_named(tmp_path):
    """A power cut can also leave a file's first block zeros (its length already on the disk, not its data)."""
    path = tmp_path / "led_01.png"
    whole = _whole(".png")
    path.write_bytes(bytes(8) + whole[8:])
    assert file_problem(path) == "damaged (no PNG signature at its start)"
    assert file_problem(tmp_path / "gone.png") == "missing"
    (tmp_path / "dir.npz").mkdir()
    assert file_problem(tmp_path / "dir.npz") == "missing"


def test_an_archive_with_a_comment_is_whole(tmp_path):
    """NumPy's .npz has no comment (its end record is the last 22 bytes); another zip writer's may: the standard
    library's search of the file's last 64 KiB finds its record."""
    path = tmp_path / "a.npz"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("a.npy", b"x" * 100)
        zf.comment = b"made elsewhere"
    assert file_problem(path) is None
    path.write_bytes(path.read_bytes()[:-30])
    assert file_problem(path) == "cut short (no zip end record)"


def test_other_files_are_judged_by_being_there_and_not_empty(tmp_path):
    (tmp_path / "notes.txt").write_bytes(b"x")
    (tmp_path / "empty.txt").write_bytes(b"")
    (tmp_path / "a.png").write_bytes(_whole(".png")[:50])
    names = ["notes.txt", "empty.txt", "a.png", "gone.npz"]
    assert unusable_files(tmp_path, names) == ["empty.txt", "a.png", "gone.npz"]
    said = described_problems(tmp_path, unusable_files(tmp_path, names), most=2)
    assert said == "empty.txt empty, a.png cut short (no PNG end chunk) and 1 more"


def _flipped(data: bytes, at: int) -> bytes:
    """``data`` with 4 bytes inverted from ``at``: whole length, both ends as written."""
    return data[:at] + bytes(b ^ 0xFF for b in data[at : at + 4]) + data[at + 4 :]


def test_damage_inside_a_whole_length_png_is_named_by_its_chunk(tmp_path):
    """Bytes flipped inside a PNG (a bad disk block) pass every check at its ends; the chunk's CRC-32 names it."""
    path = tmp_path / "led_01.png"
    whole = _whole(".png")
    path.write_bytes(whole)
    assert damage_inside(path) is None
    path.write_bytes(_flipped(whole, len(whole) // 2))
    assert file_problem(path) is None  # its ends are whole
    assert damage_inside(path) == "damaged inside (chunk IDAT at byte 33 fails its CRC-32 check)"
    path.write_bytes(whole[:-40] + whole[-12:])  # the end chunk kept, the last IDAT short of its length
    assert "runs past the end of the file" in damage_inside(path)


def test_damage_inside_an_npz_is_named_by_its_member_and_only_members_asked_for_are_read(tmp_path):
    path = tmp_path / "gt.npz"
    whole = _whole(".npz")
    path.write_bytes(whole)
    assert damage_inside(path) is None
    with zipfile.ZipFile(path) as archive:
        depth = archive.getinfo("depth.npy")
        start = depth.header_offset + 30 + len(depth.filename) + len(depth.extra)
    path.write_bytes(_flipped(whole, start + depth.compress_size // 2))
    assert file_problem(path) is None
    assert damage_inside(path).startswith("damaged inside (member depth.npy: ")
    assert damage_inside(path, ("mask.npy",)) is None  # the damaged member is not one a reader takes
    assert damage_inside(tmp_path / "gone.npz") == "missing" and damage_inside(tmp_path / "x.txt") is None
