"""`nlips live` on the emulated sensor as a user runs it: no terminal, no window, a stream that ends."""

import numpy as np
import pytest

pytest.importorskip("mitsuba")
cv2 = pytest.importorskip("cv2")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.device.virtual_board import find_board  # noqa: E402

PREDICTOR = ["--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
SMALL = ["--width", "64", "--height", "48", "--frames-per-press", "2"]


def _saved_depth(folder):
    """The saved depth maps, in frame order."""
    return [np.load(f)["depth"] for f in sorted(folder.glob("frame_*.npz"))]


def test_live_on_nlipsemu_port_streams_the_emulated_script_once(tmp_path, capsys):
    """--port nlipsemu://ID with no board in the process and no --camera: the emulated sensor, its board at
    that URL lit in the tri-colour pattern; without a window the stream ends after the script (dome + 3 presses)."""
    url = "nlipsemu://live-cli"
    maps = tmp_path / "maps"
    predictor = ["--predictor", "tests.device.fakes:green_predictor", "--no-window"]
    assert main(["live", "--port", url, *predictor, *SMALL, "--save", str(maps)]) == 0
    captured = capsys.readouterr()
    assert f"{url}: starting the emulated sensor of nlipstac" in captured.err and "Traceback" not in captured.err
    assert "\n8 frames in" in captured.err and captured.out == f"{maps}\n"
    green = _saved_depth(maps)  # each frame's green channel / 1000
    assert len(green) == 8 and min(g.mean() for g in green) > 1.0  # every frame lit by the tri-colour LEDs

    # each scripted surface in its own 2 frames, though the camera delivers a frame one read late (the stream
    # showed each press first in its second frame: frames 0-2 the dome): a press's frames alike up to noise, each
    # press denting the gel where the one before did not, far beyond the noise (5x5 box blurred)
    def change(g, h):
        return np.abs(cv2.blur(g - h, (5, 5))).max()

    noise = change(green[1], green[0])
    assert noise < 1.0 and all(change(green[2 * k + 1], green[2 * k]) < 1.0 for k in range(4))
    assert all(change(green[2 * k], green[2 * k - 2]) > 3 * noise for k in range(1, 4))
    assert find_board(url) is None


def test_live_emulated_with_a_frame_limit_loops_the_script(tmp_path, capsys):
    maps = tmp_path / "maps"
    args = ["live", "--emulate", "nlipstac", *PREDICTOR, *SMALL, "--frames", "11", "--save", str(maps)]
    assert main(args) == 0
    assert "11 frames in" in capsys.readouterr().err
    assert len(_saved_depth(maps)) == 11


def test_live_on_nlipsemu_port_with_recorded_frames_starts_the_board_alone(tmp_path, capsys):
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(3):
        cv2.imwrite(str(frames / f"f{k:02d}.png"), np.full((12, 16, 3), 1000 * (k + 1), np.uint16))
    url = "nlipsemu://live-board"
    assert main(["live", "--port", url, "--camera", str(frames), *PREDICTOR, "--save", str(tmp_path / "m")]) == 0
    captured = capsys.readouterr()
    assert "3 frames in" in captured.err and "emulated" not in captured.err
    assert find_board(url) is None


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--port", "nlipsemu://"], "nlipsemu:// needs a board id"),
        (["--emulate", "nlipstac", "--port", "/dev/ttyACM0"], "--port is not used with --emulate"),
        (["--emulate", "nlipstac", "--camera", "0"], "--camera is not used with --emulate"),
        (["--emulate", "nlipstac", "--adalight", "12"], "--adalight is not used with --emulate"),
        (["--camera", "0", "--width", "64"], "--width is only used with --emulate SCENE"),
        (["--emulate", "nlipstac", "--width", "64"], "--width 64 without --height: the images would be 64x480 pixels"),
        (["--port", "nlipsemu://4", "--frames", "0"], "--max-frames: must be an integer >= 1"),  # --frames: old name
    ],
)
def test_live_source_mistakes_are_one_line(tmp_path, capsys, extra, message):
    assert main(["live", *PREDICTOR, *extra, "--save", str(tmp_path / "m")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("nlips live: error: ") and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "m").exists()


RESET_AT = {}
"""``url``, ``frame``: the emulated sensor's board :func:`resetting_green_predictor` resets as it takes that frame."""


def resetting_green_predictor(shape):
    """``tests.device.fakes:green_predictor`` that resets the emulated sensor's board at ``RESET_AT["frame"]``."""
    from tests.device.fakes import green_predictor

    predict, calls = green_predictor(shape), [0]

    def resetting(frame):
        calls[0] += 1
        if calls[0] == RESET_AT["frame"]:
            find_board(RESET_AT["url"]).reset()
        return predict(frame)

    return resetting


def test_a_reset_of_the_emulated_sensors_board_is_watched_as_a_real_boards(tmp_path, capsys, monkeypatch, caplog):
    """The emulated sensor's in-process board was not watched: after its reset the twin's frames were dark (it
    renders what the board latched) and their maps were saved without a word, exit 0. Now as a real board: one
    warning, the pattern relit, the dark frames dropped and counted, every saved frame lit."""
    import logging

    caplog.set_level(logging.WARNING)
    url = "nlipsemu://live-reset"
    monkeypatch.setitem(RESET_AT, "url", url)
    monkeypatch.setitem(RESET_AT, "frame", 3)
    maps = tmp_path / "maps"
    predictor = ["--predictor", "tests.device.test_live_emulated:resetting_green_predictor", "--no-window"]
    assert main(["live", "--port", url, *predictor, *SMALL, "--save", str(maps)]) == 0
    err = capsys.readouterr().err
    ours = [r.getMessage() for r in caplog.records if "reset during the stream" in r.getMessage()]
    assert len(ours) == 1 and ours[0].startswith(f"{url}: the LED board reset during the stream ("), ours
    (summary,) = [line for line in err.splitlines() if line.startswith("8 frames in")]
    assert summary.endswith("; 2 more dropped, read while the LED board had reset"), summary  # the camera's latency
    green = _saved_depth(maps)
    assert len(green) == 8 and min(g.mean() for g in green) > 1.0  # every frame lit by the tri-colour LEDs
