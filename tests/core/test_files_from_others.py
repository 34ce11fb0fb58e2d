"""Files from others: a press folder, an LED file or an image received by e-mail or on a USB stick may be damaged
or made to harm (docs/formats.md, "Files from others"). Each case here did harm before it was refused: read a file
outside the folder the user named, wrote outside it, inflated gigabytes, or forged lines of the command's output.

Small crafted files only: a bomb is its header (the size it declares), never its gigabytes.
"""

from __future__ import annotations

import io
import json
import zipfile
import zlib

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core import load_press
from nlipscalib.core.errors import CaptureError, ConfigError
from nlipscalib.core.imageio import PNG_SIGNATURE, read_image, read_png16
from nlipscalib.core.ledfile import read_led_file
from nlipscalib.core.reconstruction import reconstruction_dir
from nlipscalib.core.tolerances import MAX_IMAGE_PIXELS
from tests.core.test_capture import H, W, _edit_meta, _press


# ---------------------------------------------------------------------- names in meta.json
@pytest.mark.parametrize(
    "name",
    [
        "{other}/dark.png",  # an absolute path: another press's image (it was read, and the press solved with it)
        "../other/dark.png",  # out of the folder by '..'
        "dark.png\nnlips solve: done",  # a newline: forged a line of the command's error
    ],
)
def test_an_image_name_that_is_a_path_is_refused(tmp_path, name):
    folder, other = _press(tmp_path / "p"), _press(tmp_path / "other")
    _edit_meta(folder, lambda m: m["images"].update(dark=name.format(other=other)))
    with pytest.raises(CaptureError, match=r"meta.json: 'images.dark' must be the name of a file in the press folder"):
        load_press(folder)


def test_a_reference_name_that_is_a_path_is_refused(tmp_path):
    folder, other = _press(tmp_path / "p"), _press(tmp_path / "other")
    _edit_meta(folder, lambda m: m.update(reference=str(other / "reference.npz")))
    with pytest.raises(CaptureError, match="'reference' must be the name of a file in the press folder"):
        load_press(folder)


# ---------------------------------------------------------------------- npz bombs
def _npy(shape: tuple, data: bytes = b"", dtype: str = "<f4") -> bytes:
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": dtype, "fortran_order": False, "shape": shape})
    return head.getvalue() + data


def _array_bytes(array: np.ndarray) -> bytes:
    f = io.BytesIO()
    np.lib.format.write_array(f, array)
    return f.getvalue()


def test_a_reference_declaring_a_huge_array_is_refused_from_its_header(tmp_path):
    """The header is read first: an array declared far larger than the camera's images is never allocated (a few
    bytes could declare 37 GiB, which numpy tried to allocate, and a deflated run of zeros would fill it)."""
    folder = _press(tmp_path / "p")
    normals = np.tile(np.float32([0, 0, -1]), (H, W, 1))
    with zipfile.ZipFile(folder / "reference.npz", "w") as z:
        z.writestr("depth.npy", _npy((100_000, 100_000)))  # its data: none
        z.writestr("normals.npy", _array_bytes(normals))
    with pytest.raises(CaptureError, match=rf"reference.npz: reference arrays do not match the camera size \({H}, {W}"):
        load_press(folder)


def test_a_reference_inflates_its_two_arrays_only(tmp_path):
    """A member beside depth and normals (a deflated gigabyte of zeros) is never inflated: here its deflated data
    is damaged, which reading it would find."""
    folder = _press(tmp_path / "p")
    with np.load(folder / "reference.npz") as d:
        arrays = {k: d[k] for k in ("depth", "normals")}
    with zipfile.ZipFile(folder / "reference.npz", "w", zipfile.ZIP_DEFLATED) as z:
        for key, array in arrays.items():
            z.writestr(f"{key}.npy", _array_bytes(array))
        z.writestr("extra.npy", _npy((1 << 28,)) + zlib.compress(bytes(1 << 16))[:64])
    np.testing.assert_array_equal(load_press(folder).reference.depth, arrays["depth"])


# ---------------------------------------------------------------------- PNG bombs
def _png_header_only(width: int, height: int) -> bytes:
    """A PNG declaring width x height 16-bit RGB pixels, with one empty IDAT: what a bomb's first bytes say."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")

    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([16, 2, 0, 0, 0])
    return PNG_SIGNATURE + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b"")


@pytest.mark.parametrize("side", [60_000, 30_000])
def test_an_image_declaring_too_many_pixels_is_refused_before_decoding(tmp_path, side):
    """60000 x 60000 is above OpenCV's own limit (an assertion: a traceback); 30000 x 30000 below it (OpenCV would
    allocate its 5.4 GB, and 840 KB of deflated zeros filled 12000 x 12000 in 10 s)."""
    path = tmp_path / "bomb.png"
    path.write_bytes(_png_header_only(side, side))
    for reader in (read_image, read_png16):
        with pytest.raises(CaptureError, match=rf"bomb.png: image is {side}x{side} pixels, more than the"):
            reader(path)


def test_a_camera_of_too_many_pixels_is_refused(tmp_path):
    """A meta.json whose camera matches the bombs' size passed the check of each image against the camera."""
    folder = _press(tmp_path / "p")
    side = int(MAX_IMAGE_PIXELS**0.5) + 1
    _edit_meta(folder, lambda m: m["camera"].update(width=side, height=side))
    with pytest.raises(CaptureError, match=rf"camera size {side}x{side}: more than the {MAX_IMAGE_PIXELS} pixels"):
        load_press(folder)


# ---------------------------------------------------------------------- values no sensor has
BAD_LEDS = [
    ({"position": [1e30, 0, 3]}, "led.position is 1e[+]30 mm from the camera, more than 1000 mm"),
    ({"position": [9, 0, 3], "mu": 1e9}, "led.mu is 1e[+]09, more than 1000"),
    ({"position": [9, 0, 3], "intensity": [1e30, 1, 1]}, "led.intensity is 1e[+]30, more than 1e[+]06"),
]


@pytest.mark.parametrize("led,message", BAD_LEDS)
def test_an_led_no_sensor_has_is_named_in_meta_json(tmp_path, led, message):
    """Each solved to "--roi auto found no contact" (a whole frame: to a surface), naming nothing."""
    folder = _press(tmp_path / "p")
    _edit_meta(folder, lambda m: m["leds"].__setitem__(1, led))
    with pytest.raises(CaptureError, match=rf"meta.json: leds\[1\]: {message}"):
        load_press(folder)


@pytest.mark.parametrize("led,message", BAD_LEDS)
def test_an_led_no_sensor_has_is_named_in_an_led_file(tmp_path, led, message):
    path = tmp_path / "leds.json"
    path.write_text(json.dumps({"leds": [{"position": [9, 0, 3]}, led]}), encoding="utf-8")
    with pytest.raises(CaptureError, match=rf"leds.json: not a valid LED file \({message}\)"):
        read_led_file(path)


def test_leds_a_sensor_has_are_still_read():
    from nlipscalib.core.leds import Led

    led = Led.from_dict({"position": [0, 0, 999], "mu": 1000, "intensity": [1e6, 0, 1]})
    assert led.mu == 1000 and led.intensity == (1e6, 0.0, 1.0)
    with pytest.raises(ConfigError):
        Led.from_dict({"position": [0, 0, 1001]})


# ---------------------------------------------------------------------- writes stay inside
def test_a_result_folder_linked_out_of_the_press_is_refused(tmp_path):
    """A press folder's nlips/ linking elsewhere: a solve wrote where it pointed, replacing what was there (the
    reconstruction of another press); a link inside the press, and a folder the user names, are written."""
    folder = _press(tmp_path / "p")
    elsewhere = tmp_path / "other_press_nlips"
    elsewhere.mkdir()
    (folder / "nlips").symlink_to(elsewhere)
    with pytest.raises(CaptureError, match=r"p/nlips: a symbolic link to .*other_press_nlips, outside the press"):
        reconstruction_dir(folder)
    assert reconstruction_dir(folder, elsewhere) == elsewhere  # named by the user: written where it points
    (folder / "nlips").unlink()
    (folder / "kept").mkdir()
    (folder / "nlips").symlink_to(folder / "kept")
    assert reconstruction_dir(folder) == folder / "nlips"


# ---------------------------------------------------------------------- names in messages
def test_a_newline_in_a_file_name_stays_inside_the_one_error_line(tmp_path, capsys):
    folder = tmp_path / "press\nnlips solve: done, 0 problems"
    folder.mkdir()
    assert main(["solve", str(folder)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and "press\\nnlips solve: done" in err[0], err


# ---------------------------------------------------------------------- paths in an experiment's results
@pytest.mark.parametrize("where", ["absolute", "up"])
def test_an_error_map_named_outside_the_experiments_folder_is_refused(tmp_path, where):
    """results.json names each evaluation's error map; one of a report folder from elsewhere naming a path out of
    it was read (and drawn into the figures)."""
    from nlipscalib.experiments.common import map_rows

    out, elsewhere = tmp_path / "work", tmp_path / "elsewhere.npz"
    out.mkdir()
    np.savez(elsewhere, true=np.zeros((2, 2, 3)), estimate=np.zeros((2, 2, 3)), error=np.zeros((2, 2)))
    name = str(elsewhere) if where == "absolute" else "../elsewhere.npz"
    rows = [{"method": "nlips", "press": "p1", "map": name, "aae_deg": 1.0}]
    with pytest.raises(ConfigError, match="error map .* is not a file inside the experiment's folder"):
        map_rows(rows, out, ("method",))
    (out / "maps").mkdir()
    np.savez(out / "maps" / "m.npz", true=np.zeros((2, 2, 3)), estimate=np.zeros((2, 2, 3)), error=np.ones((2, 2)))
    [(_, _, _, error)] = map_rows([rows[0] | {"map": "maps/m.npz"}], out, ("method",))
    assert error.sum() == 4


# ---------------------------------------------------------------------- a calibration dataset's shards
def _shard_with_extra_member(path, samples: int = 4):
    from nlipscalib.learn.dataset import write_shard

    arrays = {
        "pixel": np.zeros((samples, 2), np.int16),
        "rgb": np.full((samples, 3), 0.5, np.float32),
        "normal": np.tile(np.float32([0, 0, -1]), (samples, 1)),
        "true_normal": np.full((samples, 3), np.nan, np.float32),
        "contact": np.zeros(samples, bool),
        "source": np.zeros(samples, np.uint8),
    }
    write_shard(path, arrays, {"name": "p1", "samples": samples, "stamp": "s"})
    with zipfile.ZipFile(path, "a", zipfile.ZIP_DEFLATED) as z:  # a gigabyte of zeros, here damaged: never read
        z.writestr("extra.npy", _npy((1 << 28,)) + zlib.compress(bytes(1 << 16))[:64])
    return arrays


def test_a_shard_inflates_its_own_arrays_only(tmp_path):
    from nlipscalib.learn.dataset import shard_entry

    _shard_with_extra_member(tmp_path / "p1.npz")
    assert shard_entry(tmp_path / "p1.npz") == ({"name": "p1", "samples": 4, "stamp": "s"}, 4)


def test_a_shard_declaring_more_samples_than_it_holds_is_refused_from_its_headers(tmp_path):
    """rgb declaring 2^28 samples (no data) beside 4 of everything else: refused before the 3 GiB are allocated."""
    from nlipscalib.learn.dataset import shard_entry, write_shard

    arrays = _shard_with_extra_member(tmp_path / "p1.npz")
    write_shard(tmp_path / "p1.npz", {k: v for k, v in arrays.items() if k != "rgb"})
    with zipfile.ZipFile(tmp_path / "p1.npz", "a") as z:
        z.writestr("rgb.npy", _npy((1 << 28, 3)))
    with pytest.raises(CaptureError, match=r"p1.npz: array 'pixel' has shape \(4, 2\), inconsistent with 268435456"):
        shard_entry(tmp_path / "p1.npz")


def test_a_result_inflates_the_formats_arrays_only(tmp_path):
    """`nlips eval PRESS --result FOLDER` of a result from elsewhere: a member beside the format's arrays (here
    damaged, which reading it would find) is never inflated."""
    from nlipscalib.core.reconstruction import load_reconstruction, save_reconstruction
    from tests.core.test_reconstruction import _rec

    save_reconstruction(_rec(), tmp_path / "nlips")
    with zipfile.ZipFile(tmp_path / "nlips" / "result.npz", "a", zipfile.ZIP_DEFLATED) as z:
        z.writestr("extra.npy", _npy((1 << 28,)) + zlib.compress(bytes(1 << 16))[:64])
    np.testing.assert_array_equal(load_reconstruction(tmp_path / "nlips", shape=(4, 5)).depth, _rec().depth)
