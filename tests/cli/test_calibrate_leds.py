"""`nlips calibrate-leds` as a user runs it on a faulty capture of the undeformed dome."""

from __future__ import annotations

import json
import math

from nlipscalib.cli import main
from tests.solver import synth


def test_a_stale_led_frame_is_left_out_and_its_led_kept_at_its_start_in_the_table_and_the_file(
    tmp_path, capsys, caplog
):
    """A camera that handed out a stale frame (led_05.png a copy of led_04.png): the command refused the capture
    (exit 2) while `nlips solve` leaves that LED out. Now it writes the LED file (exit 0) with one warning, the LED's
    table row "not fitted", and the file's ``not_fitted`` and ``warnings``."""

    def lag(lin):
        lin = lin.copy()
        lin[4] = lin[3]
        return lin

    folder = synth.make_press(tmp_path / "stale", "none", size=(48, 36), lin_hook=lag)
    out = tmp_path / "leds.json"
    assert main(["--no-progress", "calibrate-leds", str(folder), "--out", str(out), "--stride", "2"]) == 0
    err = capsys.readouterr().err
    (warning,) = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert "led_05.png repeats led_04.png" in warning and "LED 5 not fitted" in warning, warning
    assert any(line.split()[:1] == ["5"] and line.endswith("not fitted: starting values") for line in err.splitlines())
    written = json.loads(out.read_text())
    assert written["not_fitted"] == [4] and written["warnings"] == [warning]
    assert written["leds"][4]["position"] == json.loads((folder / "meta.json").read_text())["leds"][4]["position"]
    assert math.isnan(written["rms"][4]) and not math.isnan(written["rms"][3])


def test_solving_with_an_led_file_that_holds_a_not_fitted_led_says_so_once(tmp_path, caplog):
    """The LED file of a stale-frame calibration keeps LED 5 at its starting values; `nlips solve --leds FILE` took
    it silently for a calibrated LED. Now one warning names the file, the LED and the fix."""

    def lag(lin):
        lin = lin.copy()
        lin[4] = lin[3]
        return lin

    reference = synth.make_press(tmp_path / "stale", "none", size=(48, 36), lin_hook=lag)
    press = synth.make_press(tmp_path / "press", "sphere", size=(48, 36))
    leds = tmp_path / "leds.json"
    assert main(["--no-progress", "calibrate-leds", str(reference), "--out", str(leds), "--stride", "2"]) == 0
    caplog.clear()
    assert main(["--no-progress", "solve", str(press), "--leds", str(leds), "--out", str(tmp_path / "out")]) == 0
    said = [r.getMessage() for r in caplog.records if "not fitted by its calibration" in r.getMessage()]
    assert said == [
        f"{leds}: LED 5 not fitted by its calibration (kept at the starting values); capture the undeformed dome "
        "again and re-run `nlips calibrate-leds` to calibrate it"
    ]
