"""Commands that light the LEDs leave them dark when they stop: at the end, on an error, Ctrl-C or SIGTERM.

The LEDs keep the last frame they latched when nothing drives them any more, so a capture or a live stream
stopped halfway used to leave the sensor lit (SIGTERM ends an ``nlips`` process with ``os._exit``, which
runs no ``finally``; ``nlips live`` never switched them off at all).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.device.controller import LedController, lights_out_on_exit
from nlipscalib.device.virtual_board import VirtualBoard
from tests.device.fakes import errors_only
from tests.processes import terminate_once_started

from .ledboards import SimavrUnderTest, firmware_build

TERMINATED = re.compile(
    r"nlips capture: terminated; session (?P<out>.+): (?P<kept>\d+) of 10 folders captured \(reference.*\); run again "
    r"to resume from press_\d{4}"
)
"""The line of a capture of 9 presses stopped by SIGTERM after its reference: how far it got (cli.capture)."""


@pytest.fixture
def previous_sigterm():
    """A stand-in for the nlips command's SIGTERM handler, recording what the LEDs showed when it ran."""
    seen = []
    old = signal.signal(signal.SIGTERM, lambda signum, frame: seen.append(signum))
    yield seen
    signal.signal(signal.SIGTERM, old)


def test_sigterm_in_the_block_switches_the_leds_off_then_hands_the_signal_on(previous_sigterm):
    board = VirtualBoard(4)
    handler = signal.getsignal(signal.SIGTERM)
    with LedController.open(board.url) as leds, lights_out_on_exit(leds):
        leds.set_all(np.full((4, 3), 200, np.uint8))
        assert signal.getsignal(signal.SIGTERM) is not handler  # chained in front for the block
        signal.raise_signal(signal.SIGTERM)
        assert previous_sigterm == [signal.SIGTERM]  # the previous handler ran (the command's: exit 143) ...
        assert board.latched.sum() == 0  # ... after the LEDs went dark
        leds.set_all(np.full((4, 3), 9, np.uint8))
    assert signal.getsignal(signal.SIGTERM) is handler  # put back
    assert board.latched.sum() == 0  # and dark at the end of the block too


def test_an_error_in_the_block_switches_the_leds_off_and_is_the_one_reported():
    board = VirtualBoard(3)
    with pytest.raises(KeyboardInterrupt), LedController.open(board.url) as leds, lights_out_on_exit(leds):
        leds.set_led(1, (255, 255, 255))
        raise KeyboardInterrupt
    assert board.latched.sum() == 0


def test_ctrl_c_during_leds_test_leaves_no_led_lit(monkeypatch, capsys):
    board = VirtualBoard(12)
    naps = []

    def sleep(seconds):  # Ctrl-C while the third LED is lit
        naps.append(seconds)
        if len(naps) == 3:
            raise KeyboardInterrupt

    monkeypatch.setattr(time, "sleep", sleep)
    assert main(["leds", board.url, "test"]) == 130
    assert "LED 3: lit" in capsys.readouterr().out
    assert board.latched.sum() == 0


def _grey_frames(cv2, folder, count: int):
    """A folder of ``count`` grey 16x12 PNG frames, named in stream order."""
    folder.mkdir()
    for k in range(count):
        cv2.imwrite(str(folder / f"{k:03d}.png"), np.full((12, 16, 3), 90, np.uint8))
    return folder


def test_live_switches_the_leds_off_when_the_stream_ends(tmp_path, monkeypatch, capsys):
    cv2 = pytest.importorskip("cv2")
    from tests.device import fakes

    frames = _grey_frames(cv2, tmp_path / "frames", 3)
    board = VirtualBoard(12)
    lit = []

    def lit_predictor(shape):  # records what the LEDs showed while each frame was predicted
        predict = fakes.flat_predictor(shape)
        return lambda frame: (lit.append(int(board.latched.sum())), predict(frame))[1]

    monkeypatch.setattr(fakes, "lit_predictor", lit_predictor, raising=False)
    args = ["live", "--camera", str(frames), "--port", board.url, "--no-window", "--save", str(tmp_path / "s")]
    assert main(args + ["--predictor", "tests.device.fakes:lit_predictor"]) == 0
    assert len(lit) >= 3 and min(lit) > 0  # lit (tri-colour) while streaming
    assert board.latched.sum() == 0  # dark afterwards


def test_sigterm_mid_capture_on_the_firmware_leaves_the_leds_dark_and_no_partial_press(tmp_path):
    """`kill` of `nlips capture` on the real host path (the firmware in simavr, recorded frames) mid-press."""
    cv2 = pytest.importorskip("cv2")
    from nlipscalib.core import Camera, find_presses, load_press

    camera = Camera.from_fov(160, 120, 100.0, "fisheye", (0.05, -0.01, 0.0, 0.0))
    (tmp_path / "camera.json").write_text(json.dumps({"camera": camera.to_dict()}), encoding="utf-8")
    video = cv2.VideoWriter(str(tmp_path / "v.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 30, (160, 120))
    for i in range(4000):  # ~0.5 s of decoding per press at --average 100: the session outlasts the kill
        # each image: --flush 2 + --average 100 frames; the dark one (second of 15) darker, so the LEDs show light
        video.write(np.full((120, 160, 3), 40 if (i // 102) % 15 == 1 else 150, np.uint8))
    video.release()
    board = SimavrUnderTest(*firmware_build(), tmp_path / "tty")
    command = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
    argv = [sys.executable, "-c", command, "--no-progress", "capture", "--port", board.url, "--yes"]
    argv += ["--camera", str(tmp_path / "v.avi"), "--camera-calibration", str(tmp_path / "camera.json")]
    argv += ["--average", "100", "--presses", "9", "--out", str(tmp_path / "s")]
    argv += ["--black-level", "40"]  # the dark frame's level, the camera's own: declared (a pedestal is refused)
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while proc.poll() is None and time.monotonic() < deadline:
            if (tmp_path / "s" / "reference").is_dir() and board.latched().sum() > 0:
                break  # a press is being captured under one of its lights
            time.sleep(0.01)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(proc.pid, signal.SIGKILL)
    try:
        assert proc.returncode == 128 + signal.SIGTERM, err
        said = errors_only(err)  # the operator's instructions are on stderr too
        assert len(said) == 1 and (stopped := TERMINATED.fullmatch(said[0])), err
        assert board.latched().sum() == 0  # was lit when the signal came
    finally:
        board.close()
    presses = find_presses(tmp_path / "s")
    assert len(presses) < 10  # stopped mid-session
    assert stopped["out"] == str(tmp_path / "s") and int(stopped["kept"]) == len(presses)  # as the line said
    for press in presses:  # whatever looks complete is complete
        assert load_press(press).led_images.shape == (12, 120, 160, 3)


def test_live_summarises_its_frames_when_the_board_is_lost_before_the_lights_off(tmp_path, monkeypatch, capsys):
    """The board killed while `nlips live --port` streamed: the stream ended normally, then the final lights-off
    failed, and its error replaced the frame summary (never printed). Now the summary, then the one error line
    saying the board is gone, exit 2. Since s37 the board is asked at every frame (device.live_leds.ResetWatch): the
    stream ends at the read after the unplug (1 frame, not 3 with the LEDs dark)."""
    cv2 = pytest.importorskip("cv2")
    from tests.device import fakes

    frames = _grey_frames(cv2, tmp_path / "frames", 3)
    board = VirtualBoard(12)
    real_open = LedController.open.__func__
    monkeypatch.setattr(  # the command waits 5 s for an unplugged board to come back
        LedController, "open", classmethod(lambda cls, url, **kw: real_open(cls, url, **{**kw, "reconnect_s": 0.3}))
    )

    def unplugging_predictor(shape):  # the board is pulled while the first frame is predicted
        predict = fakes.flat_predictor(shape)
        return lambda frame: (board.unplug(), predict(frame))[1]

    monkeypatch.setattr(fakes, "unplugging_predictor", unplugging_predictor, raising=False)
    args = ["live", "--camera", str(frames), "--port", board.url, "--no-window", "--save", str(tmp_path / "s")]
    assert main(args + ["--predictor", "tests.device.fakes:unplugging_predictor"]) == 2
    captured = capsys.readouterr()  # stdout: the maps' folder; on stderr the summary, then the error, last
    said = captured.err.splitlines()
    assert captured.out == f"{tmp_path / 's'}\n" and any(line.startswith("1 frames in ") for line in said), said
    lines = [line for line in said if line.startswith("nlips ")]
    assert (
        said[-1] == lines[0]
        and len(lines) == 1
        and lines[0].startswith(f"nlips live: error: {board.url}: the board disconnected (")
    ), lines
    assert len(list((tmp_path / "s").glob("*_normals.png"))) == 1


def test_sigterm_of_live_says_the_stream_stopped_not_run_again_to_resume(tmp_path):
    """A live stream cannot resume: "finished work is kept, run again to resume" promised what it cannot do.
    SIGTERM ends it as Ctrl-C does (its summary, every saved frame whole), then that line, exit 143: it ended at
    once with the line alone, the frame count and rate lost (s25-soak)."""
    cv2 = pytest.importorskip("cv2")
    frames = _grey_frames(cv2, tmp_path / "frames", 200)
    started = tmp_path / "started"
    code = (
        "import os, sys, time; from tests.device import fakes; from nlipscalib.cli import main\n"
        "def slow(shape):\n"
        "    predict = fakes.flat_predictor(shape)\n"
        "    def run(frame):\n"
        f"        open({str(started)!r}, 'w').close(); time.sleep(0.05); return predict(frame)\n"
        "    return run\n"
        "fakes.slow = slow\n"
        "sys.exit(main(sys.argv[1:]))"
    )
    saved = tmp_path / "saved"
    argv = [sys.executable, "-c", code, "live", "--camera", str(frames), "--no-window", "--out", str(saved)]
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    returncode, out, err = terminate_once_started(argv + ["--predictor", "tests.device.fakes:slow"], started, env, 60)
    assert returncode == 128 + signal.SIGTERM, err
    assert err.splitlines()[-1] == (
        "nlips live: terminated; the stream stopped (a live stream does not resume; maps already saved with --out "
        "are kept)"
    )
    assert out == f"{saved}\n"  # stdout: the maps' folder alone; the summary and where, on stderr before the line
    summary, where = [line for line in err.splitlines() if not line.startswith(("INFO ", "WARNING "))][-3:-1]
    n = int(summary.split()[0])
    assert 1 <= n < 200 and summary.startswith(f"{n} frames in "), out
    assert where.startswith(f"saved: {n} of {n} frames' "), out
    # each frame the summary counts is saved whole (its picture and its arrays), and no other
    assert sorted(p.name for p in saved.glob("*.npz")) == [f"frame_{i:06d}.npz" for i in range(n)]
    assert len(list(saved.glob("*_normals.png"))) == n
