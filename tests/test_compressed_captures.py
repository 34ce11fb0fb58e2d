"""LED images that went through JPEG (a webcam streaming MJPEG) are named, on a small twin capture; frames never
compressed, 12-bit or 8-bit, are not.

Why: the one-bounce twin's 8-bit linear captures through JPEG quality 85 solved to a contact AAE of 1.21 / 0.98
deg (sphere / cube) instead of 0.47 / 0.46, silently (s27 QA walk, webcam-grade camera).
"""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

pytest.importorskip("mitsuba")
cv2 = pytest.importorskip("cv2")

from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.core.compression import blockiness  # noqa: E402
from nlipscalib.core.tolerances import JPEG_BLOCKINESS  # noqa: E402
from nlipscalib.device.exposure import check_exposure  # noqa: E402
from nlipscalib.sim.press import render_press  # noqa: E402
from nlipscalib.sim.scene import load_scene  # noqa: E402
from nlipscalib.solver.calibrate import _check_lit  # noqa: E402
from nlipscalib.solver.led_checks import led_mismatch_notes  # noqa: E402

LED_FILES = [f"led_{i:02d}.png" for i in range(1, 13)]


@pytest.fixture(scope="module")
def twin(tmp_path_factory):
    """The twin's undeformed dome at 96x72 (direct light, 4 spp, with its sensor noise), 12-bit as rendered."""
    scene = load_scene().replace(
        noise={"enabled": True}, render={"bounces": 0, "spp": 4}, camera={"width": 96, "height": 72}
    )
    return render_press(scene, None, tmp_path_factory.mktemp("twin") / "reference", seed=3)


def _webcam(source, folder, quality=None):
    """``source`` stored as an 8-bit camera gives it (black level 0, as `nlips capture --black-level 0` records),
    each image through OpenCV's JPEG encoder at ``quality`` when given (an MJPEG stream)."""
    folder.mkdir()
    meta = json.loads((source / "meta.json").read_text(encoding="utf-8"))
    black, white = meta["sensor"]["black_level"], meta["sensor"]["white_level"]
    for path in source.iterdir():
        if path.suffix != ".png":
            (folder / path.name).write_bytes(path.read_bytes())
            continue
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.float64)
        eight = np.clip(np.rint((raw - black) / (white - black) * 255), 0, 255).astype(np.uint8)
        if quality is not None:
            ok, coded = cv2.imencode(".jpg", eight, [cv2.IMWRITE_JPEG_QUALITY, quality])
            assert ok
            eight = cv2.imdecode(coded, cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(folder / path.name), eight.astype(np.uint16) << 8)
    meta["sensor"].update(bit_depth=8, black_level=0.0, white_level=float(255 << 8))
    (folder / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    return folder


def _said(notes):
    return [note for note in notes if "JPEG compression blocks" in note]


def test_jpeg_compressed_led_images_are_named_with_the_fix_and_clean_ones_are_not(twin, tmp_path, caplog):
    clean12 = load_press(twin)
    clean8 = load_press(_webcam(twin, tmp_path / "eight"))
    mjpeg = load_press(_webcam(twin, tmp_path / "mjpeg", quality=85))
    gel = np.isfinite(clean12.reference.depth)
    values = {name: blockiness(p.led_images, gel) for name, p in (("12", clean12), ("8", clean8), ("q85", mjpeg))}
    assert values["12"] < JPEG_BLOCKINESS and values["8"] < JPEG_BLOCKINESS < values["q85"], values

    for press in (clean12, clean8):
        assert _said(led_mismatch_notes(press, press.leds, range(12))) == []
    said = _said(led_mismatch_notes(mjpeg, mjpeg.leds, range(12)))
    assert len(said) == 1 and str(mjpeg.folder) in said[0] and "CAP_PROP_FOURCC" in said[0] and "MJPEG" in said[0]

    # the LED calibration warns alike (it fits the blocks as shading and calls itself reliable)
    with caplog.at_level(logging.WARNING):
        _check_lit(mjpeg)
    assert "JPEG compression blocks" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        _check_lit(clean8)
    assert "JPEG" not in caplog.text


def test_the_capture_check_names_mjpeg_frames_while_the_press_can_be_taken_again(twin, tmp_path):
    clean = load_press(_webcam(twin, tmp_path / "eight"))
    mjpeg = load_press(_webcam(twin, tmp_path / "mjpeg", quality=85))
    gel = np.isfinite(clean.reference.depth)

    def frames(press):
        return {"dark": press.dark, "tricolor": press.tricolor} | {
            name[:-4]: image for name, image in zip(LED_FILES, press.led_images)
        }

    assert _said(check_exposure(frames(clean), clean.response, tmp_path / "press_0001", gel=gel)) == []
    said = _said(check_exposure(frames(mjpeg), mjpeg.response, tmp_path / "press_0001", gel=gel))
    assert len(said) == 1 and "the LED frames show" in said[0] and "press_0001" in said[0]


def test_a_grid_shifted_by_a_crop_is_still_found(twin, tmp_path):
    """A frame cut out at a column and a row that are not multiples of 8 keeps its blocks at another phase."""
    mjpeg = load_press(_webcam(twin, tmp_path / "mjpeg", quality=85))
    gel = np.isfinite(mjpeg.reference.depth)
    assert blockiness(mjpeg.led_images[:, 3:, 5:], gel[3:, 5:]) > JPEG_BLOCKINESS
    assert blockiness(mjpeg.led_images[:, :, :6], gel[:, :6]) is None  # too few pairs: no verdict
