"""`nlips capture --emulate`: the whole hardware path (virtual LED board, host driver, session) from the CLI."""

import json

import pytest

pytest.importorskip("mitsuba")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core import find_presses, load_press  # noqa: E402


def test_emulated_session_from_the_cli_resumes(tmp_path, capsys):
    args = ["capture", "--emulate", "nlipstac", "--width", "64", "--height", "48", "--spp", "1", "--out"]
    assert main(args + [str(tmp_path / "s"), "--presses", "1", "--move-press", "1"]) == 0
    out = capsys.readouterr().out
    assert "press_0001: captured" in out and "2 attempt(s)" in out
    assert main(args + [str(tmp_path / "s"), "--presses", "2"]) == 0
    out = capsys.readouterr().out
    assert "reference: kept" in out and "press_0001: kept" in out and "press_0002: captured" in out
    presses = find_presses(tmp_path / "s")
    assert [p.name for p in presses] == ["press_0001", "press_0002", "reference"]
    p = load_press(presses[0])
    assert p.reference is not None and p.led_images.shape == (12, 48, 64, 3)
    assert p.meta["provenance"]["device"] == "emulator" and p.meta["provenance"]["attempts"] == 2
    assert json.loads((tmp_path / "s" / "session.json").read_text())["n_leds"] == 12


def test_device_path_without_port_is_one_clear_error(tmp_path, capsys):
    assert main(["capture", "--out", str(tmp_path / "s")]) == 2
    assert "--port" in capsys.readouterr().err


def test_device_path_with_virtual_board_and_recorded_frames(tmp_path, capsys):
    """The real-sensor wiring: LED port, camera (a folder of frames), design, calibrated camera JSON."""
    import cv2
    import numpy as np

    from nlipscalib.core import Camera
    from nlipscalib.device.virtual_board import VirtualBoard

    camera = Camera.from_fov(64, 48, 100.0, "fisheye", (0.05, -0.01, 0.0, 0.0))
    (tmp_path / "camera.json").write_text(json.dumps({"camera": camera.to_dict()}))
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(2 * 15):  # reference + one press, 15 images each; the check frame repeats the first
        value = 100 + (k % 15) * (k % 15 != 14)
        cv2.imwrite(str(frames / f"{k:03d}.png"), np.full((48, 64, 3), value, np.uint8))
    board = VirtualBoard(12)
    args = ["capture", "--port", board.url, "--camera", str(frames), "--design", "nlipstac", "--yes"]
    args += ["--camera-calibration", str(tmp_path / "camera.json"), "--presses", "1", "--out", str(tmp_path / "s")]
    assert main(args) == 0
    assert "press_0001: captured" in capsys.readouterr().out
    p = load_press(tmp_path / "s" / "press_0001")
    assert p.camera == camera and p.response.bit_depth == 8 and p.response.white_level == 255 << 8
    assert p.meta["provenance"]["device"]["firmware"] and np.isfinite(p.reference.depth).all()
    # frames 15..29 in capture order: tri-colour, dark, LED 1..12, check
    assert p.tricolor[0, 0, 0] == 100 << 8 and p.dark[0, 0, 0] == 101 << 8 and p.led_images[11, 0, 0, 0] == 113 << 8
    assert board.latched.sum() == 0
