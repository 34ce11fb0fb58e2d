"""`nlips capture`'s reference checks that are the solve's (cli/capture_checks.py wires them into the session):
a gamma-encoding camera is told its tone curve, not a black level, from recorded frames of the twin."""

from __future__ import annotations

import json

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.device.virtual_board import VirtualBoard  # noqa: E402
from tests.device.fakes import errors_only  # noqa: E402

DARK_LIGHT = 0.003
"""The recorded camera's dark frame: light at this fraction of full scale, evenly (its black clamp a little off);
linear, 0.8 of one 8-bit step: below the solve's dark-frame limit (tolerances.DARK_FRAME_OFFSET)."""


@pytest.fixture(scope="module")
def undeformed(tmp_path_factory):
    """The one-bounce twin's undeformed nlipstac capture at 160x120 (interreflection as a real dome has: the
    emulator's zero-bounce renders let the check's fitted indirect term absorb part of a curve)."""
    pytest.importorskip("mitsuba")
    from nlipscalib.sim.press import render_press
    from nlipscalib.sim.scene import load_scene

    scene = load_scene("nlipstac").replace(render={"bounces": 1, "spp": 4}, camera={"width": 160, "height": 120})
    return load_press(render_press(scene, None, tmp_path_factory.mktemp("twin") / "reference", seed=5))


def recorded(press, folder, encode, dark_light: float = DARK_LIGHT) -> None:
    """``press``'s sequence (tri-colour, dark, LED 1..12, tri-colour) as an 8-bit camera's recorded frames, each
    frame's light (fraction of full scale, plus ``dark_light``) through ``encode`` to [0, 1]; and the camera's
    calibration beside them (``folder``.json)."""
    folder.mkdir()
    black, white = press.response.black_level, press.response.white_level
    for k, image in enumerate([press.tricolor, press.dark, *press.led_images, press.tricolor]):
        light = np.clip((image.astype(np.float64) - black) / (white - black) + dark_light, 0, 1)
        frame = np.rint(255 * np.clip(encode(light), 0, 1)).astype(np.uint8)
        cv2.imwrite(str(folder / f"{k:04d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    folder.with_suffix(".json").write_text(json.dumps({"camera": press.camera.to_dict()}), encoding="utf-8")


def capture(frames, out) -> list[str]:
    board = VirtualBoard(12)
    args = ["capture", "--port", board.url, "--camera", str(frames), "--camera-calibration", str(frames) + ".json"]
    return main([*args, "--yes", "--presses", "0", "--out", str(out)])


def test_a_gamma_camera_whose_dark_frame_it_lifted_is_told_its_tone_curve_not_a_black_level(
    tmp_path, capsys, undeformed
):
    """A gamma-2.2 webcam, its dark frame's 0.3 % of light lifted evenly to 7.8 % (20 of 255) by the curve, was told
    `--black-level 20`; captured so, `nlips solve` called the LED images not linear (power 0.53) and refused the press
    as another sensor's (s37). The reference is refused naming the tone curve; the same light through a camera with
    a black level of its own (20 of 255, linear) is still told `--black-level 20`."""
    recorded(undeformed, tmp_path / "gamma", lambda light: light ** (1 / 2.2))
    assert capture(tmp_path / "gamma", tmp_path / "s1") == 2
    (line,) = errors_only(capsys.readouterr().err)
    assert line.startswith(
        f"nlips capture: error: {tmp_path / 's1' / 'reference'}: the LED frames are not linear in the light: each "
        "pixel's value grows as the LED model's light to the power 0.5"
    )
    assert "dark.png sits evenly above the black level 0 (--black-level), its median of the gel 20 in the " in line
    assert "--camera-response srgb" in line and "calibrate-camera-response" in line
    assert "--black-level 20" not in line and not (tmp_path / "s1" / "reference").exists()

    recorded(undeformed, tmp_path / "pedestal", lambda light: light - DARK_LIGHT + 20 / 255)
    assert capture(tmp_path / "pedestal", tmp_path / "s2") == 2
    (line,) = errors_only(capsys.readouterr().err)
    assert "not a dark frame of the black level 0" in line and "(`--black-level 20`)" in line
    assert "not linear" not in line


def test_a_gamma_camera_whose_dark_frame_is_at_the_black_level_is_warned_about_at_its_reference(
    tmp_path, caplog, undeformed
):
    """The same gamma-2.2 webcam without a dark offset was captured without a word (s37): the reference is written
    and warned about first, the session to be captured again; the linear camera's is not."""
    import logging

    recorded(undeformed, tmp_path / "gamma", lambda light: light ** (1 / 2.2), dark_light=0.0)
    with caplog.at_level(logging.WARNING):
        assert capture(tmp_path / "gamma", tmp_path / "s1") == 0
    said = [r.getMessage() for r in caplog.records if "not linear in the light" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith(f"{tmp_path / 's1' / 'reference'}: the LED frames are"), said
    assert "power 0.5" in said[0] and "capture it again into a new folder" in said[0]

    caplog.clear()
    recorded(undeformed, tmp_path / "linear", lambda light: light, dark_light=0.0)
    with caplog.at_level(logging.WARNING):
        assert capture(tmp_path / "linear", tmp_path / "s2") == 0
    assert not [r for r in caplog.records if "not linear" in r.getMessage()]
