"""The experiments' design and calibrated rows take the LED model ``nlips solve --led-model auto`` takes for the
design: disks of its declared size on the flat pad (its point LEDs miss them unevenly), points on the hemisphere."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from nlipscalib.cli import main

CONFIG = """
shapes = ["nlipstac", "flat"]
leds = ["true", "design", "calibrated"]

[twin]
width = 96
height = 72
spp = 4
bounces = 1

[presses]
polar_deg = [15.0]
azimuth_deg = [30.0]

[[presses.indenters]]
kind = "sphere"
size = 6.0
"""
RADIUS = 1.8
"""Half the shipped designs' declared 3.6 mm (scenes/*.toml ``leds.emitter_diameter``)."""


@pytest.fixture(scope="module")
def rows(tmp_path_factory) -> dict[tuple[str, str], dict]:
    """Q3 of the hemisphere and the flat pad at 96x72, one sphere press each, kept whole: per (shape, leds) its
    evaluation with the solve's recorded solver keywords (``keywords``) and, for calibrated rows, its calibration's
    result."""
    pytest.importorskip("mitsuba")
    tmp = tmp_path_factory.mktemp("rows")
    config = tmp / "q3.toml"
    config.write_text(CONFIG, encoding="utf-8")
    out = tmp / "work"
    argv = ["--no-progress", "experiment", "q3", "--config", str(config), "--out", str(out), "--keep-presses"]
    assert main([*argv, "--report", str(tmp / "report")]) == 0
    work = out / "q3-custom"
    found = {}
    for path in (work / "tasks").glob("*.json"):
        task = json.loads(path.read_text(encoding="utf-8"))
        for ev in task.get("evaluations", ()):
            solves = work / "presses" / task["id"] / "solves"
            (report,) = [
                json.loads(p.read_text(encoding="utf-8")) for p in solves.glob("*/report.json") if _solved_with(p, ev)
            ]
            ev["keywords"] = report["provenance"]["settings"]["solver_keywords"]
            ev["scene_key"] = task["scene_key"]
            found[ev["labels"]["shape"], ev["labels"]["leds"]] = ev
    for shape in ("nlipstac", "flat"):  # each shape's calibration, by its scene's key (tasks.calibration_id)
        (path,) = (work / "tasks").glob(f"cal-{found[shape, 'true']['scene_key']}-*.json")
        found[shape, "calibrated"]["calibration"] = json.loads(path.read_text(encoding="utf-8"))
    return found


def _solved_with(report: Path, ev: dict) -> bool:
    """Whether the solve folder of ``report`` is the one of evaluation ``ev`` (its variant's hash)."""
    from nlipscalib.experiments.tasks import digest

    return report.parent.name == digest(ev["solve"])


def test_the_design_row_takes_the_designs_disks_where_auto_does_and_points_on_the_hemisphere(rows):
    """The design row without a CAD error gives the solver the true LEDs: it solves what the true row's plain solve
    does, bit for bit, as disks on the flat pad and as points on the hemisphere."""
    for shape in ("nlipstac", "flat"):
        design, true = rows[shape, "design"], rows[shape, "true"]
        assert design["metrics"] == true["metrics"], shape
        assert design["keywords"].get("led_radius") == true["keywords"].get("led_radius"), shape
    assert rows["flat", "design"]["keywords"]["led_radius"] == RADIUS
    assert rows["flat", "design"]["keywords"]["emitters"] is None  # the given LEDs are the disks' centres
    assert "led_radius" not in rows["nlipstac", "design"]["keywords"]


def test_the_calibration_fits_the_disks_auto_takes_and_the_calibrated_row_solves_with_them(rows):
    """On the flat pad the calibration fits the LEDs as the design's disks too (recorded as an LED file's
    ``emitters``) and the calibrated row solves with them; on the hemisphere it fits points only, solved as points."""
    flat = rows["flat", "calibrated"]
    emitters = flat["calibration"]["emitters"]
    assert emitters["radius_mm"] == RADIUS and len(emitters["leds"]) == len(flat["calibration"]["leds"]) == 12
    assert flat["keywords"]["led_radius"] == RADIUS and flat["keywords"]["emitters"] == emitters["leds"]
    hemisphere = rows["nlipstac", "calibrated"]
    assert "emitters" not in hemisphere["calibration"] and "led_radius" not in hemisphere["keywords"]
    assert all("metrics" in rows[key] for key in rows), {k: v.get("error") for k, v in rows.items()}
