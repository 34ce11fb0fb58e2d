"""`nlips calibrate-leds` as a user runs it on a faulty capture of the undeformed dome."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

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
    written = json.loads(out.read_text(encoding="utf-8"))
    assert written["not_fitted"] == [4] and written["warnings"] == [warning]
    assert (
        written["leds"][4]["position"]
        == json.loads((folder / "meta.json").read_text(encoding="utf-8"))["leds"][4]["position"]
    )
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


@pytest.fixture(scope="module")
def twin_captures(tmp_path_factory):
    """Undeformed captures of the twin (160x120, one bounce, 16 spp, sensor noise) under three noise seeds, the
    second's copy with the red tri-colour group (LEDs 1-4) aged to 0.9 and one with every LED at 0.9, and the first's
    LED file: (folder, file)."""
    pytest.importorskip("mitsuba")
    from nlipscalib.core import load_press
    from nlipscalib.sim.press import render_press
    from nlipscalib.sim.scene import load_scene
    from tests.solver.twin_helpers import dimmed_copy

    root = tmp_path_factory.mktemp("previous")
    scene = load_scene("nlipstac").replace(render={"bounces": 1, "spp": 16}, camera={"width": 160, "height": 120})
    for seed in (7, 8, 9):
        render_press(scene, None, root / f"seed{seed}", seed=seed)
    dimmed_copy(load_press(root / "seed8"), root / "seed8_aged", np.where(np.arange(12) < 4, 0.9, 1.0))
    dimmed_copy(load_press(root / "seed8"), root / "seed8_all_dimmed", 0.9)
    first = root / "seed7.json"
    assert main(["--no-progress", "calibrate-leds", str(root / "seed7"), "--out", str(first)]) == 0
    return root, first


def _calibrated_against(capture, previous, out, caplog):
    """`nlips calibrate-leds CAPTURE --previous PREVIOUS --out OUT` (exit 0): its warnings and the written file."""
    caplog.clear()
    assert main(["--no-progress", "calibrate-leds", str(capture), "--out", str(out), "--previous", str(previous)]) == 0
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    return warnings, json.loads(out.read_text(encoding="utf-8"))


def test_an_aged_led_group_is_named_against_the_previous_calibration(twin_captures, tmp_path, capsys, caplog):
    """LEDs 1-4 aged to 0.9 since the earlier calibration (another noise seed of the same dome): the calibration
    measured the group (0.90 of the others) and said nothing, taking no earlier file. With --previous one warning
    names the group, the table gives each LED's ratio, and the file records the comparison."""
    root, first = twin_captures
    warnings, written = _calibrated_against(root / "seed8_aged", first, tmp_path / "aged.json", caplog)
    (change,) = written["previous"]["changes"]
    assert warnings == [change]
    assert change.startswith("LEDs 1-4 (the red tri-colour group) give 0.9") and str(first) in change, change
    ratio = np.asarray(written["previous"]["brightness"])
    assert np.allclose(ratio[:4], 0.9, atol=0.03) and np.allclose(ratio[4:], 1.0, atol=0.03), ratio
    assert written["previous"]["file"] == str(first)
    rows = [line.split() for line in capsys.readouterr().err.splitlines()]
    header = next(row for row in rows if row[:1] == ["LED"])
    assert header[-3:] == ["prev", "moved(mm)", "turned(deg)"]
    led1 = next(row for row in rows if row[:1] == ["1"] and row[1] != "centre")  # not LED 1's disk
    assert len(led1) == 11  # LED, 3 Psi, mu, 3 uncertainties and the 3 columns against the earlier file
    assert abs(float(led1[-3]) - 0.9) < 0.03


def test_clean_captures_against_an_earlier_calibration_raise_no_alarm(twin_captures, tmp_path, caplog):
    """The same sensor, unchanged, under other noise seeds: no LED nor group beyond the tolerances (set from the
    calibration's repeatability), nothing warned; the comparison is still recorded. The earlier file may be the one
    --out replaces (a lab's leds.json, calibrated again in place)."""
    root, first = twin_captures
    replaced = tmp_path / "leds.json"  # --previous the very file --out replaces: read before the fit
    replaced.write_bytes(first.read_bytes())
    for seed, out, previous in ((8, tmp_path / "8.json", first), (9, replaced, replaced)):
        warnings, written = _calibrated_against(root / f"seed{seed}", previous, out, caplog)
        assert warnings == [] and written["previous"]["changes"] == [], warnings
        assert written["previous"]["file"] == str(previous)
        assert np.nanmax(np.abs(np.log(written["previous"]["brightness"]))) < 0.04
        assert abs(written["previous"]["overall_brightness"] - 1) < 0.01  # the twin's seeds: within 0.23 %
        assert written["previous"]["not_compared"] == [] and written["previous"]["places"] == "disks"
    assert (
        json.loads(replaced.read_text(encoding="utf-8"))["leds"]
        != json.loads(first.read_text(encoding="utf-8"))["leds"]
    )  # seed 9's, replaced


def test_every_led_dimmed_alike_is_named_against_the_previous_calibration(twin_captures, tmp_path, capsys, caplog):
    """Every LED at 0.9 since the earlier calibration (aged alike, or the exposure shortened unrecorded): each LED's
    share of the light is unchanged and both files are gauged to mean Psi = 1, so without the light level recorded
    nothing was said. Now one warning names it, no group nor LED, and the closing line gives the ratio."""
    root, first = twin_captures
    assert len(json.loads(first.read_text(encoding="utf-8"))["light_level"]["gel_median"]) == 12
    warnings, written = _calibrated_against(root / "seed8_all_dimmed", first, tmp_path / "dim.json", caplog)
    (change,) = written["previous"]["changes"]
    assert warnings == [change]
    assert change.startswith(f"all LEDs together give 0.90 times the light they gave in {first}"), change
    assert "every LED aged alike" in change
    assert abs(written["previous"]["overall_brightness"] - 0.9) < 0.01
    assert f"against {first}: all LEDs together x0.9" in capsys.readouterr().err


def test_an_earlier_led_file_of_another_sensor_is_refused_before_the_fit(twin_captures, tmp_path, capsys, monkeypatch):
    """--previous with another sensor's LED file (a 48x36 camera), one that records no sensor, or none at all: one
    line naming the option and the file, exit 2, before the fit, nothing written."""
    from nlipscalib import solver

    root, first = twin_captures
    other = tmp_path / "other.json"
    small = synth.make_press(tmp_path / "small", "none", size=(48, 36))
    assert main(["--no-progress", "calibrate-leds", str(small), "--out", str(other), "--stride", "2"]) == 0
    unrecorded = tmp_path / "unrecorded.json"
    unrecorded.write_text(
        json.dumps({k: v for k, v in json.loads(first.read_text(encoding="utf-8")).items() if k != "sensor"}),
        encoding="utf-8",
    )
    monkeypatch.setattr(solver, "calibrate_leds", lambda *a, **k: pytest.fail("the fit ran"))
    capsys.readouterr()
    refusals = [(other, "calibrated on another sensor"), (unrecorded, "records no sensor")]
    for previous, why in refusals + [(tmp_path / "gone.json", "no such LED file")]:
        out = tmp_path / "new.json"
        args = ["--no-progress", "calibrate-leds", str(root / "seed8"), "--out", str(out), "--previous", str(previous)]
        assert main(args) == 2
        lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
        assert len(lines) == 1 and f"--previous {previous}: {why}" in lines[0], lines
        assert not out.exists()


def test_a_twin_capture_with_two_led_images_exchanged_is_refused_naming_them(twin_captures, tmp_path, capsys, caplog):
    """led_03.png and led_04.png exchanged (the wiring, or the capture's order): neighbours, so the images' own check
    does not see it; the command calibrated LED 3 at LED 4's place and back, "reliable", and wrote the file without a
    word. Now one line names both images, exit 2, nothing written; --keep-led-order writes them as captured with that
    line as a warning. The clean captures of the fixture and the other tests calibrate without it."""
    import shutil

    from tests.solver.twin_helpers import recorded_anew

    root, first = twin_captures
    swapped = tmp_path / "swapped"
    shutil.copytree(root / "seed7", swapped)
    (swapped / "led_03.png").rename(swapped / "x.png")
    (swapped / "led_04.png").rename(swapped / "led_03.png")
    (swapped / "x.png").rename(swapped / "led_04.png")
    recorded_anew(swapped)  # as the capture with the wiring exchanged would have recorded it
    out = tmp_path / "leds.json"
    capsys.readouterr()
    assert main(["--no-progress", "calibrate-leds", str(swapped), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{swapped}: led_03.png and led_04.png look exchanged (fitted LED 3 0." in err, err
    assert "captured in each other's place" in err and "--keep-led-order" in err and not out.exists()
    caplog.clear()
    assert main(["--no-progress", "calibrate-leds", str(swapped), "--out", str(out), "--keep-led-order"]) == 0
    (said,) = [r.getMessage() for r in caplog.records if "look exchanged" in r.getMessage()]
    assert said.endswith("right only for captures taken in this order") and "--keep-led-order" in said
    assert said in json.loads(out.read_text(encoding="utf-8"))["warnings"]
    assert "exchanged" not in first.read_text(encoding="utf-8")


def test_an_earlier_file_without_light_level_or_disks_says_what_was_not_compared(twin_captures, tmp_path, capsys):
    """An LED file written before light_level (2026-12-06) and without disks: the command said "no LED changed beyond
    the tolerances" as if every LED's light together had been judged. Now the closing line and the file say what
    was not compared, and the places are the point LEDs'."""
    root, first = twin_captures
    old = json.loads(first.read_text(encoding="utf-8"))
    for key in ("light_level", "emitters", "reflectance_profile"):
        old.pop(key, None)
    older = tmp_path / "older.json"
    older.write_text(json.dumps(old), encoding="utf-8")
    out = tmp_path / "new.json"
    capsys.readouterr()
    assert (
        main(["--no-progress", "calibrate-leds", str(root / "seed8"), "--out", str(out), "--previous", str(older)]) == 0
    )
    (closing,) = [line for line in capsys.readouterr().err.splitlines() if line.startswith(f"against {older}")]
    assert closing == (
        f"against {older}: no LED changed beyond the tolerances; not compared: all LEDs' light together ({older} "
        "records no light_level: written before 2026-12-06); the LED disks (only this calibration holds them: the "
        "places compared as point LEDs)"
    )
    previous = json.loads(out.read_text(encoding="utf-8"))["previous"]
    assert previous["places"] == "points" and len(previous["not_compared"]) == 2
    assert previous["overall_brightness"] is None


def _close_pairs_scene():
    """The twin (160x120, one bounce, 16 spp) with its 12 LEDs in six pairs 0.8 mm apart along the 9 mm ring, small
    point-like emitters (no package), each turned 20 deg toward the axis: a design whose neighbours are too close for
    a fixed 1 mm margin (s35-exchange's scene copy)."""
    from nlipscalib.sim.scene import load_scene

    angles = [math.pi * g / 3 + (k - 0.5) * 0.8 / 9.0 for g in range(6) for k in range(2)]
    tilt = math.radians(20.0)
    places = [(9.0 * math.cos(a), 9.0 * math.sin(a), 0.0) for a in angles]
    axes = [(-math.sin(tilt) * math.cos(a), -math.sin(tilt) * math.sin(a), math.cos(tilt)) for a in angles]
    return load_scene("nlipstac").replace(
        render={"bounces": 1, "spp": 16},
        camera={"width": 160, "height": 120},
        leds={"positions": places, "directions": axes, "emitter_diameter": 0.0},
        led_package={"enabled": False},
    )


def test_a_twin_capture_of_leds_designed_under_a_millimetre_apart_with_two_exchanged_is_refused(
    tmp_path, capsys, caplog
):
    """LEDs in pairs 0.8 mm apart, led_01.png and led_02.png exchanged: the command fitted LED 1 at LED 2's place and
    back (0.8 mm from their own, a few hundredths from each other's) and wrote the file without a word, the fixed
    1 mm margin of s33-ledswap out of reach. Now one line names both, exit 2, nothing written; the clean capture
    of the same design calibrates with no such line."""
    pytest.importorskip("mitsuba")
    import shutil

    from nlipscalib.sim.press import render_press
    from tests.solver.twin_helpers import recorded_anew

    clean = render_press(_close_pairs_scene(), None, tmp_path / "clean", seed=3)
    swapped = tmp_path / "swapped"
    shutil.copytree(clean, swapped)
    (swapped / "led_01.png").rename(swapped / "x.png")
    (swapped / "led_02.png").rename(swapped / "led_01.png")
    (swapped / "x.png").rename(swapped / "led_02.png")
    recorded_anew(swapped)
    out = tmp_path / "leds.json"
    capsys.readouterr()
    assert main(["--no-progress", "calibrate-leds", str(swapped), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{swapped}: led_01.png and led_02.png look exchanged (fitted LED 1 0.0" in err, err
    assert "mm from theirs, median" in err and not out.exists()
    caplog.clear()
    assert main(["--no-progress", "calibrate-leds", str(clean), "--out", str(out)]) == 0
    assert not [r for r in caplog.records if "exchanged" in r.getMessage()]
    # nor a lag band: far from a pair its two LEDs light the gel alike by design (s35-pairband: "led_02.png's
    # columns 0-19 (left) show led_01.png's light", those columns left out of LED 2's fit)
    assert not [r for r in caplog.records if "switched while the camera read" in r.getMessage()]
