import numpy as np
import pytest

from nlipscalib.core.errors import CaptureError
from nlipscalib.core.imageio import read_npz, save_npz
from tests.core.test_reconstruction import _spoil_deflated_member


def test_a_damaged_deflated_array_is_one_error_naming_the_file(tmp_path):
    path = save_npz(tmp_path / "a.npz", {"a": np.zeros((40, 50), np.float32)}, compress=True)
    _spoil_deflated_member(path, "a.npy")  # zlib fails ("invalid block type") before the zip CRC check
    with pytest.raises(CaptureError, match=r"a\.npz: damaged or truncated \.npz \(compressed data damaged: ") as caught:
        read_npz(path)
    assert str(path) in str(caught.value)


def test_a_path_that_is_not_utf8_is_read_and_refused_by_opencv_in_one_line(tmp_path):
    """OpenCV crashes the process (segfault) on a str path holding surrogates (a file name that is not UTF-8):
    images are read from memory instead, and a video path is refused in one line."""
    import os

    from nlipscalib.core.imageio import opencv_path, read_png16, write_png16

    folder = tmp_path / os.fsdecode(b"caf\xe9")  # Latin-1 bytes: not UTF-8
    folder.mkdir()
    image = np.arange(4 * 5 * 3, dtype=np.uint16).reshape(4, 5, 3) * 1000
    write_png16(folder / "led_01.png", image)
    np.testing.assert_array_equal(read_png16(folder / "led_01.png"), image)
    with pytest.raises(CaptureError, match="not valid UTF-8"):
        opencv_path(folder / "video.avi")
    assert opencv_path(tmp_path / "café.avi") == str(tmp_path / "café.avi")


def test_a_truncated_png_read_as_a_frame_is_named_before_libpng_speaks(tmp_path, capfd):
    """`nlips live --camera FOLDER` printed "libpng error: Read Error" before its own line."""
    from nlipscalib.core.imageio import read_image, write_png16

    whole = write_png16(tmp_path / "a.png", np.zeros((8, 8, 3), np.uint16))
    cut = tmp_path / "b.png"
    cut.write_bytes(whole.read_bytes()[:60])
    assert read_image(whole).shape == (8, 8, 3)
    with pytest.raises(CaptureError, match="b.png: truncated PNG image"):
        read_image(cut)
    assert "libpng" not in capfd.readouterr().err


def _png_row_filters(data: bytes, row_bytes: int) -> set[int]:
    """The filter type byte of every row of a non-interlaced PNG (its IDAT chunks inflated)."""
    import struct
    import zlib

    idat, pos = b"", 8
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        if data[pos + 4 : pos + 8] == b"IDAT":
            idat += data[pos + 8 : pos + 8 + length]
        pos += 12 + length
    raw = zlib.decompress(idat)
    return set(raw[:: row_bytes + 1])


def test_a_noisy_capture_image_is_written_losslessly_with_every_row_sub_filtered(tmp_path):
    """A capture's noisy 16-bit images gain nothing from libpng trying every filter on each row, which took ~3x the
    CPU time of one fixed filter and run-length deflate (the twin's 640x480 images, benchmarks/RESULTS.md, s18-j)."""
    import cv2

    from nlipscalib.core.imageio import read_png16, write_png16

    rng = np.random.default_rng(0)
    smooth = np.linspace(0, 40000, 64 * 48).reshape(48, 64, 1) * np.array([1.0, 0.8, 0.6])
    image = (np.clip(smooth + rng.normal(0, 300, smooth.shape), 0, 65535).astype(np.uint16) >> 4) << 4
    path = write_png16(tmp_path / "led_01.png", image)
    np.testing.assert_array_equal(read_png16(path), image)
    if hasattr(cv2, "IMWRITE_PNG_FILTER"):
        assert _png_row_filters(path.read_bytes(), 64 * 3 * 2) == {1}  # PNG filter type 1: SUB


def test_a_full_disk_while_an_npz_is_written_names_the_file_inside_the_press(tmp_path, monkeypatch):
    """`nlips render --out OUT/press` on a full disk said "OUT/press: No space left on device" when gt.npz or
    reference.npz filled it (s25 walk): the error of a write into the open zip names no file."""
    import errno
    import os

    from nlipscalib.cli import describe_os_error
    from nlipscalib.core.atomic import tmp_prefix

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(np.lib.format, "write_array", full)
    staged = tmp_path / (tmp_prefix("press") + "abc")
    staged.mkdir()
    with pytest.raises(OSError) as caught:
        save_npz(staged / "gt.npz", {"depth": np.zeros((4, 4))})
    assert describe_os_error(caught.value).startswith(f"{tmp_path / 'press' / 'gt.npz'}: No space left on device")


def test_a_png_damaged_inside_is_named_by_its_chunk_not_as_unreadable(tmp_path):
    """A 16-bit PNG of whole length with bytes flipped inside: libpng fails mid-decode, and the reader said only
    "not a readable PNG image"; now the chunk whose CRC-32 fails is named, for read_png16 and read_image alike."""
    from nlipscalib.core.imageio import read_image, read_png16, write_png16

    path = write_png16(tmp_path / "led_01.png", np.random.default_rng(1).integers(0, 65535, (48, 64, 3), np.uint16))
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid : mid + 4] = bytes(b ^ 0xFF for b in data[mid : mid + 4])
    path.write_bytes(bytes(data))
    for read in (read_png16, read_image):
        with pytest.raises(CaptureError) as info:
            read(path)
        message = str(info.value)
        assert message.startswith(f"{path}: damaged inside (chunk IDAT at byte "), message
        assert message.endswith("fails its CRC-32 check): copy or capture it again"), message
