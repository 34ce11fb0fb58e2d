"""`nlips calibrate FOLDER` when a press cannot be solved: its cause said once, the press named at the end."""

import json
import logging

from nlipscalib.cli import main
from tests.solver import synth


def _presses(tmp_path, kinds, damaged):
    """A reference and one synthetic press per kind (64x48), press_0001's image ``damaged`` cut to 300 bytes;
    (the presses' folder, the damaged file)."""
    root = tmp_path / "presses"
    synth.make_press(root / "reference", "none", size=(64, 48))
    for i, kind in enumerate(kinds, 1):
        synth.make_press(root / f"press_{i:04d}", kind, size=(64, 48))
    png = root / "press_0001" / damaged
    png.write_bytes(png.read_bytes()[:300])
    return root, png


def test_a_damaged_press_is_reported_once(tmp_path, capsys, caplog):
    """A truncated PNG printed `ERROR press_0001: ...` and then `ERROR press_0001: failed: ...`."""
    caplog.set_level(logging.INFO)
    root, _ = _presses(tmp_path, ("sphere", "cube"), "led_03.png")
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 1
    out, err = capsys.readouterr()
    logged = caplog.text + err  # pytest's handler receives the log; stderr has it when none is installed
    errors = [line for line in logged.splitlines() if "press_0001" in line and "truncated PNG" in line]
    assert len(errors) == 1 and "failed:" not in errors[0], errors
    assert "1 press failed to solve: press_0001" in err and out == f"{root / 'calibration'}\n"


def test_a_damaged_tricolour_image_fails_its_press_only(tmp_path, capsys, caplog):
    """A truncated tricolor.png stopped the whole build after the solves (exit 2), where a damaged LED image
    fails only its press."""
    caplog.set_level(logging.INFO)
    root, png = _presses(tmp_path, ("sphere", "cube"), "tricolor.png")
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 1
    out, err = capsys.readouterr()
    logged = caplog.text + err
    errors = [line for line in logged.splitlines() if "tricolor.png" in line and "truncated PNG" in line]
    assert len(errors) == 1 and str(png) in errors[0], errors
    assert "calibration: 1 press, " in err
    assert "1 press left out of the dataset (not sampled): press_0001" in err
    index = json.loads((root / "calibration" / "index.json").read_text(encoding="utf-8"))
    assert [entry["name"] for entry in index["presses"]] == ["press_0002"]


def test_every_press_unsampled_fails_the_run(tmp_path, capsys):
    root, _ = _presses(tmp_path, ("sphere",), "tricolor.png")
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "no press could be sampled" in err and "Traceback" not in err
