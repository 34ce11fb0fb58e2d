"""The solve names the consecutive LEDs a lag between which its lag-band check cannot see (LEDs in close pairs):
one INFO line, once per command, and report.json ``lag_blind_pairs`` (s36-lagcost). Exact-data presses (96x72)
of the default ring and of its LEDs in six pairs 0.5 mm apart."""

import logging
import math

from nlipscalib.core import Led, load_press, said_once
from nlipscalib.solver import SolverOptions, solve_press

from . import synth


def _paired_leds(apart: float = 0.5) -> tuple[Led, ...]:
    """The ring's 12 LEDs in six pairs ``apart`` mm apart along the 9 mm ring (each turned 20 deg to the axis)."""
    ring = synth.ring_leds()
    leds = []
    for g in range(6):
        for k in range(2):
            a = math.pi * g / 3 + (k - 0.5) * apart / 9.0
            t = math.radians(20.0)
            direction = (-math.sin(t) * math.cos(a), -math.sin(t) * math.sin(a), math.cos(t))
            leds.append(Led((9 * math.cos(a), 9 * math.sin(a), ring[0].position[2]), direction))
    return tuple(leds)


def test_leds_in_close_pairs_are_named_once_and_in_each_report_and_a_ring_is_not(tmp_path, caplog):
    options = SolverOptions(max_iters=2)
    paired = [load_press(synth.make_press(tmp_path / f"p{k}", "sphere", leds=_paired_leds())) for k in range(2)]
    ring = load_press(synth.make_press(tmp_path / "ring", "sphere"))
    with said_once.scope(), caplog.at_level(logging.INFO):
        reports = [solve_press(press, options=options).report for press in paired]
        clean = solve_press(ring, options=options).report
    said = [record.getMessage() for record in caplog.records if "lag-band check cannot see" in record.getMessage()]
    assert len(said) == 1 and said[0].startswith(f"{paired[0].folder}: ") and "LEDs 1 to 2 (0.5 mm apart" in said[0]
    for report in reports:
        assert [entry["leds"] for entry in report["lag_blind_pairs"]] == [[k, k + 1] for k in range(0, 12, 2)]
        assert all(entry["unseen"] >= 0.2 and entry["apart_mm"] == 0.5 for entry in report["lag_blind_pairs"])
        assert not any("cannot see" in note for note in report.get("warnings", []))
    assert "lag_blind_pairs" not in clean
