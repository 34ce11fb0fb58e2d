"""`nlips calibrate FOLDER` when a press cannot be solved: its cause said once, the press named at the end."""

import logging

from nlipscalib.cli import main
from tests.solver import synth


def test_a_damaged_press_is_reported_once(tmp_path, capsys, caplog):
    """A truncated PNG printed `ERROR press_0001: ...` and then `ERROR press_0001: failed: ...`."""
    caplog.set_level(logging.INFO)
    root = tmp_path / "presses"
    synth.make_press(root / "reference", "none", size=(64, 48))
    synth.make_press(root / "press_0001", "sphere", size=(64, 48))
    synth.make_press(root / "press_0002", "cube", size=(64, 48))
    png = root / "press_0001" / "led_03.png"
    png.write_bytes(png.read_bytes()[:300])
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 1
    out, err = capsys.readouterr()
    logged = caplog.text + err  # pytest's handler receives the log; stderr has it when none is installed
    errors = [line for line in logged.splitlines() if "press_0001" in line and "truncated PNG" in line]
    assert len(errors) == 1 and "failed:" not in errors[0], errors
    assert "1 press failed to solve: press_0001" in out
