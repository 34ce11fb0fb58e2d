"""A press's identity by what was captured (core.press_identity): the same images and sensor record are the same press
wherever the folder lies and whatever meta.json's times say; an edited image or sensor record is another press; the
tri-colour digest is of the decoded pixels, so a lossless copy in another encoding matches. Exact-data presses, 64x48:
under a second."""

import hashlib
import json
import os
import shutil

import cv2
import numpy as np
import pytest

from nlipscalib.core.errors import CaptureError
from nlipscalib.core.imageio import read_png16, write_png16
from nlipscalib.core.press_identity import IDENTITY_RULE, frame_identity, is_identity, pixels_digest, press_identity
from nlipscalib.pipeline import capture_identity
from tests.solver import synth


@pytest.fixture(scope="module")
def press(tmp_path_factory):
    return synth.make_press(tmp_path_factory.mktemp("identity") / "press", "sphere", size=(64, 48))


def _copy(press, to):
    shutil.copytree(press, to)
    return to


def _edit_meta(folder, edit):
    meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
    edit(meta)
    (folder / "meta.json").write_text(json.dumps(meta, indent=2), encoding="utf-8")


def test_the_pixels_digest_is_the_sha256_of_dtype_shape_and_bytes():
    image = np.arange(2 * 3 * 3, dtype=np.uint16).reshape(2, 3, 3)
    expected = hashlib.sha256(b"<u2:(2, 3, 3):" + image.tobytes()).hexdigest()
    assert pixels_digest(image) == expected
    assert pixels_digest(np.asfortranarray(image)) == expected  # the values in C order, whatever the layout
    assert pixels_digest(image.astype(np.uint8)) != expected  # an 8-bit copy is other stored values


def test_a_copy_elsewhere_with_other_times_and_versions_in_its_meta_json_is_the_same_press(press, tmp_path):
    first = press_identity(press)
    assert first["rule"] == IDENTITY_RULE and is_identity(first) and is_identity(first, "tricolor")
    copy = _copy(press, tmp_path / "elsewhere" / "renamed")

    def restamped(meta):  # as the same task rendered in another work folder, by another release
        meta["provenance"]["render_seconds"] = 12.5
        meta["provenance"]["captured_at"] = "2026-12-08T01:00:00+0000"
        meta["software_version"] = "9.9.9"

    _edit_meta(copy, restamped)
    assert press_identity(copy) == first
    assert capture_identity(copy) != capture_identity(press)  # the solve's identity hashes meta.json's bytes


@pytest.mark.parametrize("edit", ["tricolor", "led", "dark", "sensor"])
def test_an_edited_image_or_sensor_record_is_another_press(press, tmp_path, edit):
    first = press_identity(press)
    copy = _copy(press, tmp_path / "edited")
    if edit == "sensor":
        _edit_meta(copy, lambda meta: meta["sensor"].update(black_level=meta["sensor"]["black_level"] + 16))
    else:
        name = {"tricolor": "tricolor.png", "led": "led_05.png", "dark": "dark.png"}[edit]
        image = read_png16(copy / name)
        image[10, 20, 1] ^= 1  # one stored value, its lowest bit
        write_png16(copy / name, image)
    second = press_identity(copy)
    assert second["press"] != first["press"]
    assert (second["tricolor"] != first["tricolor"]) == (edit == "tricolor")  # the network's input: its pixels


def test_an_image_replaced_in_place_is_noticed_by_the_cached_identity(press, tmp_path):
    copy = _copy(press, tmp_path / "replaced")
    first = press_identity(copy)
    stat = (copy / "led_01.png").stat()
    shutil.copyfile(copy / "led_02.png", copy / "led_01.png")
    os.utime(copy / "led_01.png", ns=(stat.st_atime_ns, stat.st_mtime_ns))  # its time kept: the change time is not
    assert press_identity(copy)["press"] != first["press"]


def test_the_tri_colour_frame_re_encoded_losslessly_is_told_by_its_pixels(press, tmp_path):
    tricolor = read_png16(press / "tricolor.png")
    tiff = tmp_path / "frame.tiff"  # another format, another encoder: other bytes, the same pixels
    assert cv2.imwrite(str(tiff), cv2.cvtColor(tricolor, cv2.COLOR_RGB2BGR))
    decoded = cv2.cvtColor(cv2.imread(str(tiff), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGR2RGB)
    assert tiff.read_bytes() != (press / "tricolor.png").read_bytes()
    frame = frame_identity(decoded)
    assert frame == {"rule": IDENTITY_RULE, "tricolor": press_identity(press)["tricolor"]}
    assert is_identity(frame, "tricolor") and not is_identity(frame)  # a frame's record has no press digest
    with pytest.raises(ValueError, match="must be"):
        frame_identity(decoded[..., 0])


def test_a_missing_image_is_named(press, tmp_path):
    copy = _copy(press, tmp_path / "missing")
    (copy / "led_03.png").unlink()
    with pytest.raises(CaptureError, match="led_03.png: listed in meta.json but missing"):
        press_identity(copy)
    with pytest.raises(CaptureError, match="meta.json"):
        press_identity(tmp_path / "nothing")


def test_records_of_another_rule_or_shape_are_not_identities():
    good = {"rule": IDENTITY_RULE, "press": "a" * 64, "tricolor": "b" * 64}
    assert is_identity(good)
    assert not is_identity(good | {"rule": IDENTITY_RULE + 1})
    assert not is_identity(good | {"press": "a" * 16})
    assert not is_identity(None) and not is_identity("a" * 64)
