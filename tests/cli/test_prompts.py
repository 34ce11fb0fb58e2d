"""A command waiting for the person at the terminal (``nlips capture`` at a sensor: Enter before the reference and
each press) writes its prompts on stderr: stdout holds the result paths alone, also when it is redirected
(``session=$(nlips capture --port ...)``)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pty = pytest.importorskip("pty", reason="a pseudo-terminal (POSIX) stands in for the operator's keyboard")


def test_interactive_capture_with_stdout_redirected_prints_only_the_session_folder(tmp_path):
    """stdin a terminal (so the session waits for Enter), stdout a pipe: Python's input() wrote each prompt
    ("Do not touch the sensor: ... [Enter] ") on stdout, ahead of the folder, so a script read no usable path.
    The board is virtual (nlipsemu://), the camera a folder of frames: the device path a lab runs."""
    import cv2
    import numpy as np

    from nlipscalib.core import Camera

    camera = Camera.from_fov(64, 48, 100.0, "fisheye", (0.05, -0.01, 0.0, 0.0))
    (tmp_path / "camera.json").write_text(json.dumps({"camera": camera.to_dict()}), encoding="utf-8")
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(2 * 15):  # reference + one press, 15 images each; the check frame repeats the first
        cv2.imwrite(str(frames / f"{k:03d}.png"), np.full((48, 64, 3), 100 + (k % 15) * (k % 15 != 14), np.uint8))
    out = tmp_path / "s"
    argv = ["capture", "--port", "nlipsemu://prompts", "--camera", str(frames), "--design", "nlipstac"]
    argv += ["--camera-calibration", str(tmp_path / "camera.json"), "--presses", "1", "--out", str(out)]
    argv += ["--black-level", "101"]  # the frames' dark level (k = 1), their camera's own black level: declared
    keyboard, terminal = pty.openpty()
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "nlipscalib", *argv],
            stdin=terminal,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=os.environ | {"PYTHONPATH": str(Path(__file__).resolve().parents[2])},
        )
        os.close(terminal)
        terminal = None
        os.write(keyboard, b"\n\n")  # Enter for the reference, Enter for press 1 (the terminal holds both lines)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        os.close(keyboard)
        if terminal is not None:
            os.close(terminal)
    assert proc.returncode == 0, stderr
    assert stdout == f"{out}\n", stdout  # the folder alone: no prompt ahead of it
    assert "Do not touch the sensor: capturing the undeformed reference. [Enter] " in stderr
    assert "Press 1/1: press the object now, hold still. [Enter] " in stderr and "Traceback" not in stderr
    assert (out / "press_0001" / "meta.json").is_file()
