"""`nlips capture` checks each press's tri-colour frame against its LED frames as it is captured, and `nlips
calibrate-leds` its undeformed capture (``core.tricolor_check``): two LED frames of different colour groups captured in
each other's place are said at once, before the other presses are taken (only `nlips solve` said it, after the
session)."""

import shutil

import pytest

from nlipscalib.cli import main
from nlipscalib.device import session

pytest.importorskip("mitsuba")

SMALL = ["--emulate", "nlipstac", "--width", "80", "--height", "60", "--spp", "4", "--presses", "1"]
MISFIT = "tricolor.png does not hold the light of the LED images"


def _exchanging(first: str, second: str):
    """:func:`session.frame_sequence` with the LED states of frames ``first`` and ``second`` exchanged: each frame
    captured with the other LED lit (the controller's LED order or the images' order wrong), the tri-colour pattern
    as designed."""
    designed = session.frame_sequence

    def sequence(n_leds, cfg):
        seq = designed(n_leds, cfg)
        names = [name for name, _ in seq]
        a, b = names.index(first), names.index(second)
        seq[a], seq[b] = (first, seq[b][1]), (second, seq[a][1])
        return seq

    return sequence


def _misfits(caplog) -> list[str]:
    """The warnings said since the last call (each a line)."""
    lines = [r.getMessage() for r in caplog.records if MISFIT in r.getMessage()]
    caplog.clear()
    return lines


def test_frames_of_two_colour_groups_exchanged_are_named_at_capture_for_each_press(tmp_path, caplog, monkeypatch):
    monkeypatch.setattr(session, "frame_sequence", _exchanging("led_01", "led_09"))
    out = tmp_path / "s"
    assert main(["capture", *SMALL, "--out", str(out)]) == 0  # warned, not refused: the solve warns too
    lines = _misfits(caplog)
    assert len(lines) == 2, lines
    for line, folder in zip(lines, ("reference", "press_0001"), strict=True):
        assert str(out / folder) in line
        assert "with led_01.png (red group) and led_09.png (blue) exchanged it fits" in line
    # calibrate-leds --keep-led-order: the exchange check names the pair, the tri-colour check does not again
    assert main(["calibrate-leds", str(out / "reference"), "--keep-led-order", "--out", str(tmp_path / "l.json")]) == 0
    assert any("led_01.png and led_09.png look exchanged" in r.getMessage() for r in caplog.records)
    assert not _misfits(caplog)


def test_a_clean_capture_is_not_warned_and_calibrate_leds_names_a_tricolor_frame_of_another_press(tmp_path, caplog):
    out = tmp_path / "s"
    assert main(["capture", *SMALL, "--out", str(out)]) == 0
    assert not _misfits(caplog)
    reference = tmp_path / "reference"
    shutil.copytree(out / "reference", reference)
    shutil.copy(out / "press_0001" / "tricolor.png", reference / "tricolor.png")
    args = ["calibrate-leds", str(reference), "--allow-edited", "--out", str(tmp_path / "l.json")]
    assert main(args) == 0  # warned, not refused: the LED calibration does not read the tri-colour frame
    lines = _misfits(caplog)
    assert len(lines) == 1 and lines[0].startswith(f"{reference}: ")
    assert "a tri-colour frame of another press" in lines[0]
