"""An LED image dark (read while its LED was off) over more than half its rows or columns: the solve's LED check
names the band and leaves only it out for that LED, as a smaller band's (s36-lagcost). Over half dark, the LED's
median light sat at the dark frame's noise and every ratio to it said lit: rows were called "weak LED? (0.00 times the
light the LED model expects)" and the LED left out whole, columns "does not show that LED's light ... check the
wiring" and solved with the dark columns in (s35-leftovers' "bands over half the frame are not found as bands")."""

import pytest

from nlipscalib.core import load_press, tolerances
from nlipscalib.solver import SolverOptions, solve_press
from nlipscalib.solver.led_checks import led_check_measured
from nlipscalib.solver.press import _live_leds

from . import synth


def _dark_from_edge(led: int, stop: int, axis: str):
    """A hook darkening LED ``led``'s (0-based) rows (``axis``: columns) 0..stop-1 to the dark frame's level (0)."""

    def hook(lin):
        lin = lin.copy()
        if axis == "rows":
            lin[led, :stop] = 0.0
        else:
            lin[led, :, :stop] = 0.0
        return lin

    return hook


@pytest.mark.parametrize(("axis", "stop"), [("rows", 47), ("columns", 62), ("rows", 57)])
def test_a_band_over_most_of_an_led_image_is_found_as_a_band_not_a_weak_or_misplaced_led(tmp_path, axis, stop):
    press = load_press(synth.make_press(tmp_path / "p", "sphere", lin_hook=_dark_from_edge(4, stop, axis)))
    found = led_check_measured(press, press.leds, _live_leds(press, None))
    assert [(band.index, band.axis, band.rows) for band in found.bands] == [(4, axis, (0, stop))]
    assert found.left_out == [] and found.misplaced == []
    assert len(found.notes) == 1 and f"led_05.png's {axis} 0-{stop - 1} (" in found.notes[0]
    assert "are dark" in found.notes[0] and "weak" not in found.notes[0]


def test_the_solve_leaves_out_only_the_band_of_an_led_dark_over_two_thirds_of_its_rows(tmp_path):
    press = load_press(synth.make_press(tmp_path / "p", "sphere", lin_hook=_dark_from_edge(4, 48, "rows")))
    report = solve_press(press, options=SolverOptions(max_iters=2)).report
    assert report["dark_bands_left_out"] == [{"led": 4, "rows": [0, 48], "margin": tolerances.DARK_BAND_MARGIN}]
    assert "leds_left_out" not in report and 4 in report["leds_used"]
    assert not any("weak" in note or "does not show" in note for note in report["warnings"])
