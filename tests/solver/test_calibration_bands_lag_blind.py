"""``nlips calibrate-leds``' lag-band check (:func:`.calibration_bands.without_lagged_bands`) names the consecutive
LEDs a lag between which it cannot see (LEDs designed in close pairs), once per command; none of their lines is
left out (s36-lagcost). Exact-data presses (96x72) of the default ring's LEDs in six pairs 0.5 mm apart."""

import logging

from nlipscalib.core import load_press, said_once
from nlipscalib.solver.calibration_bands import without_lagged_bands

from . import synth
from .test_lag_blind_report import _paired_leds


def test_a_calibrations_captures_of_close_pairs_name_them_once_and_leave_nothing_out(tmp_path, caplog):
    captures = [load_press(synth.make_press(tmp_path / f"u{k}", "none", leds=_paired_leds())) for k in range(2)]
    with said_once.scope(), caplog.at_level(logging.INFO, logger="nlipscalib"):
        kept, notes = without_lagged_bands(captures)
    assert notes == [] and all(a is b for a, b in zip(kept, captures, strict=True))
    said = [record.getMessage() for record in caplog.records if "lag-band check cannot see" in record.getMessage()]
    assert len(said) == 1 and said[0].startswith(f"{captures[0].folder}: ") and "11 to 12 (0.5 mm, " in said[0]
