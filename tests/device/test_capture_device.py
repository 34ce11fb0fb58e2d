"""`nlips capture` on the real-sensor path (LED port + camera) when things go wrong: the board lost or silent
mid-session, recorded frames that are black or saturated, an LED file or camera calibration of another sensor.

The board is the in-process virtual board (faults injected), the camera a folder of recorded frames."""

from __future__ import annotations

import json

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.device import virtual_board  # noqa: E402
from nlipscalib.device.controller import LedController  # noqa: E402
from nlipscalib.device.virtual_board import VirtualBoard  # noqa: E402
from tests.device.fakes import errors_only  # noqa: E402

W, H = 64, 48
SEQUENCE = 15
"""Frames of one press with the design's 12 LEDs: tri-colour, dark, LED 1..12, the tri-colour again."""
DARK = 40
"""The recorded frames' dark level, their camera's own black level (pedestal): declared by :func:`capture_args`
(``--black-level``), as a lab must (a dark frame evenly above the declared black level is refused at the
reference)."""


def camera_file(tmp_path):
    from nlipscalib.core import Camera

    path = tmp_path / "camera.json"
    path.write_text(
        json.dumps({"camera": Camera.from_fov(W, H, 100.0, "fisheye", (0.0,) * 4).to_dict()}), encoding="utf-8"
    )
    return path


def frames_folder(tmp_path, presses: int, value=None, name: str = "frames"):
    """Recorded 8-bit frames for the reference and ``presses`` presses: ``value(k)`` is frame k's grey level
    within its sequence (default: well exposed, the dark frame at the camera's black level :data:`DARK`, LED k at
    60 + 10 k, the check frame the tri-colour one's 150)."""
    value = value or (lambda k: DARK if k == 1 else 150 if k in (0, SEQUENCE - 1) else 60 + 10 * k)
    folder = tmp_path / name
    folder.mkdir()
    for i in range(SEQUENCE * (presses + 1)):
        cv2.imwrite(str(folder / f"{i:04d}.png"), np.full((H, W, 3), value(i % SEQUENCE), np.uint8))
    return folder


def capture_args(board_url, frames, camera, out, presses: int, black_level: int = DARK):
    """The capture of recorded ``frames``, with the camera's black level declared (``--black-level``, DN)."""
    args = ["capture", "--port", board_url, "--camera", str(frames), "--camera-calibration", str(camera), "--yes"]
    return args + ["--black-level", str(black_level), "--presses", str(presses), "--out", str(out)]


def errors(err: str) -> list[str]:
    return errors_only(err)  # the operator's instructions are on stderr too


@pytest.fixture
def impatient(monkeypatch):
    """LedController.open with a short reply timeout and reconnect wait (the command opens it with the
    defaults: 1 s per try, 5 s for an unplugged board to come back)."""
    real = LedController.open.__func__

    def open_quickly(cls, url, **kwargs):
        return real(cls, url, **{**kwargs, "timeout": 0.2, "reconnect_s": 0.3})

    monkeypatch.setattr(LedController, "open", classmethod(open_quickly))


def fault_on_all(monkeypatch, number: int, fault):
    """Run ``fault(board)`` as the board executes its ``number``-th ALL (its reply still goes out)."""
    seen = []
    real = virtual_board._COMMANDS["ALL"]

    def all_command(board, args):
        seen.append(1)
        if len(seen) == number:
            fault(board)
        return real(board, args)

    monkeypatch.setitem(virtual_board._COMMANDS, "ALL", all_command)


def test_a_board_unplugged_mid_capture_is_reported_as_such(tmp_path, capsys, monkeypatch, impatient):
    """Reported as "the LED controller is closed": the clean-up's lights-off failed on the port the failed
    reconnect had closed, and its error replaced the real one."""
    board = VirtualBoard(12)
    fault_on_all(monkeypatch, SEQUENCE + 4, lambda b: b.unplug())  # mid-way through press 1
    out = tmp_path / "s"
    assert main(capture_args(board.url, frames_folder(tmp_path, 1), camera_file(tmp_path), out, 1)) == 2
    err = capsys.readouterr().err
    assert len(errors(err)) == 1, err
    assert errors(err)[0].startswith(f"nlips capture: error: {board.url}: the board disconnected (")
    assert "did not come back within 0.3 s" in err and "closed" not in err
    assert (out / "reference").is_dir() and not (out / "press_0001").exists()


def test_a_board_lost_mid_session_says_what_is_kept_and_the_same_command_resumes(
    tmp_path, capsys, monkeypatch, impatient
):
    """The board unplugged at press 2 of 2: the error line ended at "did not come back within 5 s", saying nothing
    of the reference and press 1 kept nor that the same command, run again once the board is back, goes on."""
    board = VirtualBoard(12)
    fault_on_all(monkeypatch, 2 * SEQUENCE + 4, lambda b: b.unplug())  # mid-way through press 2
    out, camera = tmp_path / "s", camera_file(tmp_path)
    assert main(capture_args(board.url, frames_folder(tmp_path, 2), camera, out, 2)) == 2
    (line,) = errors(capsys.readouterr().err)
    assert line.startswith(f"nlips capture: error: {board.url}: the board disconnected (")
    assert line.endswith(
        f"; session {out}: 2 of 3 folders captured (reference, press_0001); run again to resume from press_0002"
    )
    monkeypatch.undo()  # the board back, as plugged in again
    again = VirtualBoard(12)
    assert main(capture_args(again.url, frames_folder(tmp_path, 0, name="later"), camera, out, 2)) == 0
    err = capsys.readouterr().err
    assert "reference: kept" in err and "press_0001: kept" in err and "press_0002: captured" in err
    assert (out / "press_0002" / "meta.json").is_file()


def test_a_camera_that_runs_out_of_frames_mid_session_says_what_is_kept_and_the_same_command_resumes(tmp_path, capsys):
    """A folder of frames that ran out at press 2 (as a camera that stops sending) ended with "FOLDER: ran out of
    images after 30 frames" alone: nothing of the reference and press 1 kept, nor that a run again goes on."""
    board = VirtualBoard(12)
    frames, out, camera = frames_folder(tmp_path, 1), tmp_path / "s", camera_file(tmp_path)
    assert main(capture_args(board.url, frames, camera, out, 2)) == 2
    assert errors(capsys.readouterr().err) == [
        f"nlips capture: error: {frames}: ran out of images after {2 * SEQUENCE} frames; session {out}: 2 of 3 "
        "folders captured (reference, press_0001); run again to resume from press_0002"
    ]
    assert sorted(p.name for p in out.iterdir()) == ["press_0001", "reference", "session.json"]
    assert main(capture_args(board.url, frames_folder(tmp_path, 0, name="more"), camera, out, 2)) == 0
    err = capsys.readouterr().err
    assert "reference: kept" in err and "press_0001: kept" in err and "press_0002: captured" in err


def test_a_press_that_kept_moving_says_what_is_kept(tmp_path, capsys):
    """The session's line added to "PRESS: the object kept moving ...", as to a board's error."""
    board = VirtualBoard(12)
    moving = lambda k: 200 if k == SEQUENCE - 1 else DARK if k == 1 else 150 if k == 0 else 60 + 10 * k  # noqa: E731
    frames = tmp_path / "frames"
    frames_folder(tmp_path, 0, name="frames")
    for i in range(SEQUENCE, 2 * SEQUENCE):  # press 1, its one attempt: the check frame brighter (moved)
        cv2.imwrite(str(frames / f"{i:04d}.png"), np.full((H, W, 3), moving(i % SEQUENCE), np.uint8))
    out = tmp_path / "s"
    args = capture_args(board.url, frames, camera_file(tmp_path), out, 1) + ["--max-retakes", "0"]
    assert main(args) == 2
    (line,) = errors(capsys.readouterr().err)
    assert line.startswith(f"nlips capture: error: {out / 'press_0001'}: the object kept moving (") and line.endswith(
        f"; session {out}: 1 of 2 folders captured (reference); run again to resume from press_0001"
    ), line


def test_a_board_silent_mid_capture_is_named_by_the_command_that_failed(tmp_path, capsys, monkeypatch, impatient):
    """Reported as "no valid answer to OFF after 4 tries of 1 s each" after 8.9 s: the clean-up's OFF waited its
    own 4 tries after ALL had failed."""
    board = VirtualBoard(12)
    fault_on_all(monkeypatch, SEQUENCE + 4, lambda b: b.mute(10**6))
    args = capture_args(board.url, frames_folder(tmp_path, 1), camera_file(tmp_path), tmp_path / "s", 1)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert errors(err) == [
        f"nlips capture: error: {board.url}: no valid answer to ALL after 4 tries of 0.2 s each; session "
        f"{tmp_path / 's'}: 1 of 2 folders captured (reference); run again to resume from press_0001"
    ]


def _led_file(path, leds, camera_path):
    """An LED file as `nlips calibrate-leds` writes it: the LEDs and the sensor they were calibrated on (the
    camera of ``camera_path`` with ``leds`` as its design LEDs)."""
    from nlipscalib.core import Camera, SensorResponse
    from nlipscalib.core.ledfile import save_leds
    from nlipscalib.core.sensor_record import describe_sensor

    camera = Camera.from_dict(json.loads(camera_path.read_text(encoding="utf-8"))["camera"])
    return save_leds(path, leds, {"sensor": describe_sensor(camera, leds, SensorResponse())})


def test_an_led_file_of_another_sensor_is_refused_as_solve_refuses_it(tmp_path, capsys):
    """`nlips capture --leds FILE` took LEDs calibrated on another sensor (fingertip's, for an nlipstac capture)
    and wrote them into every press, which `nlips solve` then used; `nlips solve --leds FILE` refuses that file."""
    import dataclasses

    from nlipscalib.core import load_press
    from nlipscalib.sim.scene import load_scene

    camera = camera_file(tmp_path)
    other = _led_file(tmp_path / "fingertip_leds.json", load_scene("fingertip").led_models(), camera)
    board = VirtualBoard(12)
    frames = frames_folder(tmp_path, 0)
    out = tmp_path / "s"
    assert main([*capture_args(board.url, frames, camera, out, 0), "--leds", str(other)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(
        f"nlips capture: error: {other}: calibrated on another sensor than the one captured here, the design "
        f"nlipstac with the camera of {camera} (LED 1 is 1.50 mm and 10.0 deg from its counterpart)"
    )
    assert err.count("\n") == 1 and not out.exists() and not board.executed  # refused before the board is opened
    # a calibration of this sensor (its LEDs 0.2 mm from the design's) is taken, and recorded in the capture
    design = load_scene("nlipstac").led_models()
    moved = tuple(dataclasses.replace(led, position=tuple(led.position + np.array([0.2, 0, 0]))) for led in design)
    ours = _led_file(tmp_path / "our_leds.json", design, camera)
    ours.write_text(
        json.dumps(json.loads(ours.read_text(encoding="utf-8")) | {"leds": [led.to_dict() for led in moved]}),
        encoding="utf-8",
    )
    assert main([*capture_args(board.url, frames, camera, out, 0), "--leds", str(ours)]) == 0
    capsys.readouterr()
    np.testing.assert_allclose(load_press(out / "reference").leds[0].position, moved[0].position, atol=1e-6)


def test_frames_of_another_size_than_the_calibration_name_the_camera_and_where_the_calibration_came_from(
    tmp_path, capsys
):
    """ "the camera gives 64x48 frames but its calibration is 640x480" named neither the camera nor the design
    whose camera it was."""
    board = VirtualBoard(12)
    frames = frames_folder(tmp_path, 0)
    args = ["capture", "--port", board.url, "--camera", str(frames), "--yes", "--presses", "0"]
    assert main([*args, "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"nlips capture: error: {frames} gives 64x48 frames but the camera of the design nlipstac (no "
        "--camera-calibration) is 640x480: calibrate this camera at 64x48 (`nlips calibrate-camera`, then "
        "--camera-calibration), or capture at 640x480\n"
    )


def test_a_black_reference_is_refused_and_can_be_captured_again_at_another_exposure(tmp_path, capsys):
    """A session of black frames (LEDs off, a lens cap) was captured without a word, and every later command
    failed with "no usable pixel to fit the interreflection term on"."""
    board = VirtualBoard(12)
    camera, out = camera_file(tmp_path), tmp_path / "s"
    black = frames_folder(tmp_path, 1, value=lambda k: DARK, name="black")  # a lens cap: the black level
    assert main(capture_args(board.url, black, camera, out, 1)) == 2
    err = capsys.readouterr().err
    (line,) = errors(err)
    assert line.startswith(f"nlips capture: error: {out / 'reference'}: the reference is black: no LED frame shows ")
    assert err.count("nlips capture: error") == 1 and not (out / "reference").exists() and board.latched.sum() == 0
    # nothing was captured, so the session is not bound to its settings yet: another exposure is taken
    good = frames_folder(tmp_path, 1)
    assert main([*capture_args(board.url, good, camera, out, 1), "--exposure-ms", "5"]) == 0
    assert "press_0001: captured" in capsys.readouterr().err


def test_an_over_exposed_press_is_captured_with_a_warning_naming_the_file(tmp_path, capsys, caplog):
    """53 % of an LED frame clipped at the white level was captured silently; its light is lost to every fit."""
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(2 * SEQUENCE):  # the reference well exposed; press 1's LED 3 clipped over the top half
        k = i % SEQUENCE
        image = np.full((H, W, 3), DARK if k == 1 else 150 if k in (0, SEQUENCE - 1) else 60 + 10 * k, np.uint8)
        if i == SEQUENCE + 4:  # press 1, LED 3
            image[: H // 2] = 255
        cv2.imwrite(str(frames / f"{i:04d}.png"), image)
    board = VirtualBoard(12)
    out = tmp_path / "s"
    assert main(capture_args(board.url, frames, camera_file(tmp_path), out, 1)) == 0
    captured = capsys.readouterr()
    assert "press_0001: captured" in captured.err
    warnings = [r.getMessage() for r in caplog.records if "saturated" in r.getMessage()]
    assert warnings == [
        f"{out / 'press_0001' / 'led_03.png'}: 50 % of the gel saturated: saturated pixels are left out of every fit; "
        "lower --exposure-ms or the LED level"
    ]
    assert not [r for r in caplog.records if "reference" in r.getMessage()]  # the reference was well exposed


def test_a_reference_whose_dark_frame_is_a_pedestal_is_refused_naming_the_black_level(tmp_path, capsys):
    """Recorded frames of a camera with a black level of its own (dark frame evenly at 40 DN), captured at the
    default --black-level 0, were captured whole without a word; `nlips solve` then refused every press, naming
    --black-level 40 only after the lab's session (s36 device walk)."""
    board = VirtualBoard(12)
    camera, out = camera_file(tmp_path), tmp_path / "s"
    frames = frames_folder(tmp_path, 1)
    assert main(capture_args(board.url, frames, camera, out, 1, black_level=0)) == 2
    (line,) = errors(capsys.readouterr().err)
    assert line.startswith(
        f"nlips capture: error: {out / 'reference' / 'dark.png'}: not a dark frame of the black level 0 "
        "(--black-level): the median of the gel, 40 in the camera's 8-bit values, is 15.7 % of full scale above it "
        "and even, as a camera's own black level (pedestal) is, and `nlips solve` would refuse every press: capture "
        "again with it declared (`--black-level 40`);"
    )
    assert not (out / "reference").exists() and not (out / "press_0001").exists()
    # declared, the same frames are a session (nothing was captured, so the session is not bound to black level 0)
    assert main(capture_args(board.url, frames_folder(tmp_path, 1, name="again"), camera, out, 1)) == 0
    assert "press_0001: captured" in capsys.readouterr().err


def test_a_dark_frame_lit_unevenly_is_not_named_a_pedestal_at_capture(tmp_path, capsys):
    """Light falling off across the dome (a lamp, an LED left lit) is no black level to declare: the capture does
    not send the lab to --black-level (the solve names the stray light)."""
    frames = tmp_path / "frames"
    frames.mkdir()
    ramp = np.linspace(0, 80, W).astype(np.uint8)  # the dark frame: room light from one side
    for i in range(SEQUENCE):
        image = np.full((H, W, 3), 150 if i in (0, SEQUENCE - 1) else 100 + 10 * i, np.uint8)
        if i == 1:
            image[:] = ramp[None, :, None]
        cv2.imwrite(str(frames / f"{i:04d}.png"), image)
    board = VirtualBoard(12)
    assert main(capture_args(board.url, frames, camera_file(tmp_path), tmp_path / "s", 0, black_level=0)) == 0
    assert "--black-level" not in capsys.readouterr().err


def tagged_recording(tmp_path, tags, name: str = "recording"):
    """Recorded 8-bit frames, one sequence of :data:`SEQUENCE` per tag in ``tags``: the frames of
    :func:`frames_folder` with both tri-colour frames at 150 + 2 * tag (their press's number, told from the stored
    tri-colour image); a tag of None: a sequence whose object moved (its check frame at 200, the press retaken)."""
    folder = tmp_path / name
    folder.mkdir()
    for s, tag in enumerate(tags):
        for k in range(SEQUENCE):
            tri = 150 + 2 * (tag or 0) if tag is not None or k == 0 else 200
            value = DARK if k == 1 else tri if k in (0, SEQUENCE - 1) else 60 + 10 * k
            cv2.imwrite(str(folder / f"{s * SEQUENCE + k:04d}.png"), np.full((H, W, 3), value, np.uint8))
    return folder


def tag_of(press) -> int:
    """The tag of the recorded sequence a captured folder's tri-colour image came from (:func:`tagged_recording`)."""
    tri = cv2.imread(str(press / "tricolor.png"), cv2.IMREAD_UNCHANGED)
    return (int(np.median(tri)) >> 8) - 150 >> 1


def recorded(press) -> dict:
    return json.loads((press / "meta.json").read_text(encoding="utf-8"))["provenance"]["recording"]


def test_a_capture_resumed_on_its_recording_continues_it_where_the_kept_folders_stopped(
    tmp_path, capsys, monkeypatch, impatient, caplog
):
    """A folder of frames given as --camera was read from its first frame on every run: a session interrupted after
    press 1 and resumed took the reference's frames (1-15) for press 2. Now press 2 holds the recording's frames
    31-45, those it holds for press 2 (reference 1-15, press 1 16-30), though the interrupted run had read 3 of them:
    the attempt cut short was not kept, so its frames are read again; the session is the uninterrupted one's."""
    import logging

    board = VirtualBoard(12)
    fault_on_all(monkeypatch, 2 * SEQUENCE + 4, lambda b: b.unplug())  # mid-way through press 2
    frames, out, camera = tagged_recording(tmp_path, [0, 1, 2, 3]), tmp_path / "s", camera_file(tmp_path)
    assert main(capture_args(board.url, frames, camera, out, 3)) == 2
    assert "run again to resume from press_0002" in capsys.readouterr().err
    monkeypatch.undo()  # the board back
    caplog.set_level(logging.WARNING)
    assert main(capture_args(VirtualBoard(12).url, frames, camera, out, 3)) == 0
    assert not [r for r in caplog.records if str(frames) in r.getMessage()]  # nothing to say: the same recording
    assert [tag_of(out / n) for n in ("reference", "press_0001", "press_0002", "press_0003")] == [0, 1, 2, 3]
    spans = [(recorded(out / n)["from_frame"], recorded(out / n)["frames_read"]) for n in ("press_0002", "press_0003")]
    assert spans == [(2 * SEQUENCE, SEQUENCE), (3 * SEQUENCE, SEQUENCE)]
    assert recorded(out / "reference") | {"from_frame": 0} == {
        "path": str(frames.resolve()),
        "frames": 4 * SEQUENCE,
        "first_frame": recorded(out / "press_0003")["first_frame"],
        "from_frame": 0,
        "frames_read": SEQUENCE,
    }


def test_a_retaken_press_counts_every_attempts_frames_when_the_session_is_resumed(tmp_path, capsys):
    """Press 1 moved in its first attempt and was retaken (frames 16-45): a second run with more --presses continues
    the recording at frame 46, press 2's, not after press 1's kept attempt alone."""
    board = VirtualBoard(12)
    frames, out, camera = tagged_recording(tmp_path, [0, None, 1, 2]), tmp_path / "s", camera_file(tmp_path)
    assert main(capture_args(board.url, frames, camera, out, 1)) == 0
    assert recorded(out / "press_0001") | {"path": None} == {
        "path": None,
        "frames": 4 * SEQUENCE,
        "first_frame": recorded(out / "reference")["first_frame"],
        "from_frame": SEQUENCE,
        "frames_read": 2 * SEQUENCE,
    }
    assert main(capture_args(board.url, frames, camera, out, 2)) == 0
    assert "press_0002: captured" in capsys.readouterr().err
    assert [tag_of(out / n) for n in ("reference", "press_0001", "press_0002")] == [0, 1, 2]


def test_another_recording_given_on_resume_is_read_from_its_first_frame_with_one_warning(tmp_path, capsys, caplog):
    """The rest of the session recorded apart (the way to resume until 2026-12-07) is read from its first frame, and
    said: the user who meant to give the first recording again learns it."""
    import logging

    board = VirtualBoard(12)
    first, out, camera = tagged_recording(tmp_path, [0, 1]), tmp_path / "s", camera_file(tmp_path)
    assert main(capture_args(board.url, first, camera, out, 3)) == 2  # ran out of frames at press 2
    rest = tagged_recording(tmp_path, [2, 3], name="rest")
    caplog.set_level(logging.WARNING)
    assert main(capture_args(board.url, rest, camera, out, 3)) == 0
    said = [r.getMessage() for r in caplog.records if str(rest) in r.getMessage()]
    assert said == [
        f"{rest}: another recording than the one {out / 'press_0001'} read ({first.resolve()}, up to its frame 30): "
        "read from its first frame for press_0002"
    ]
    assert [tag_of(out / n) for n in ("press_0001", "press_0002", "press_0003")] == [1, 2, 3]
    assert recorded(out / "press_0003")["from_frame"] == SEQUENCE


def test_a_recording_read_to_its_end_is_one_line_and_goes_on_once_frames_are_added(tmp_path, capsys):
    """Resumed with the recording it had read to its end: one line saying so (not the reference's frames taken again
    for press 2); the frames of the rest added to it, the same command goes on."""
    board = VirtualBoard(12)
    frames, out, camera = tagged_recording(tmp_path, [0, 1]), tmp_path / "s", camera_file(tmp_path)
    assert main(capture_args(board.url, frames, camera, out, 2)) == 2
    capsys.readouterr()
    assert main(capture_args(board.url, frames, camera, out, 2)) == 2
    assert errors(capsys.readouterr().err) == [
        f"nlips capture: error: {frames}: no frame left for press_0002: the session's folders up to press_0001 read "
        f"its frames 1-30 and it holds 30; give a recording with more frames (the same first ones), or one that "
        f"begins at press_0002 (another recording is read from its first frame); session {out}: 2 of 3 folders "
        "captured (reference, press_0001); run again to resume from press_0002"
    ]
    for k, path in enumerate(sorted(tagged_recording(tmp_path, [0, 1, 2], name="longer").iterdir())):
        if k >= 2 * SEQUENCE:
            path.rename(frames / path.name)
    assert main(capture_args(board.url, frames, camera, out, 2)) == 0
    assert tag_of(out / "press_0002") == 2
