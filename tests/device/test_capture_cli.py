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
