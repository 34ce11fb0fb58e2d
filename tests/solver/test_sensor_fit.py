"""A press whose meta.json and reference.npz describe another sensor than the one that took its images is refused.

Before (s26-mismatch): the default dome's press with the fingertip design's files solved silently (exit 0) to a
wrong surface; the images carry no sensor identity, but their LED falloff over the gel does not fit the described
dome and LEDs (nlipscalib.solver.sensor_fit).
"""

import math
import shutil

import numpy as np
import pytest

from nlipscalib.core import load_press, tolerances
from nlipscalib.core.errors import CaptureError
from nlipscalib.core.leds import Led
from nlipscalib.solver import SolverOptions, solve_press
from nlipscalib.solver.light_and_contact import Sources, light_and_contact

from . import synth

QUICK = SolverOptions(max_iters=2)


def _other_ring(count=12, radius=7.5, tilt_deg=10.0, start_deg=15.0):
    """The LEDs of another design: a ring of 7.5 mm tilted 10 deg (the fingertip's), its first LED 15 deg round
    (the synthetic sensor's: 9 mm, 20 deg, at 0 deg). On the same dome, a ring that differs only in radius and tilt
    misses by 2.5-7 % (below the threshold: the dome's shape is most of a design's evidence); turned, 15.5 %."""
    leds = []
    for k in range(count):
        a, t = 2 * math.pi * k / count + math.radians(start_deg), math.radians(tilt_deg)
        d = (-math.sin(t) * math.cos(a), -math.sin(t) * math.sin(a), math.cos(t))
        leds.append(Led((radius * math.cos(a), radius * math.sin(a), synth.BASE_Z), d, 1.0, (1.0, 1.0, 1.0)))
    return tuple(leds)


def _sensor_fit(press):
    """(share, best share, floor) of the press's contact classification against its own description (the solve's)."""
    sources = Sources(press, tuple(press.leds), None, None, None, "auto", 1)
    return light_and_contact(sources, tolerances.LIT_LEVEL).cmap.sensor_fit


def test_images_of_another_led_ring_than_meta_json_describes_are_refused_in_one_line(tmp_path):
    """Images lit by another design's LED ring, meta.json with the synthetic sensor's: the solve refuses, naming the
    press, the misfit and what to do (before: solved without a word)."""
    cam = synth.camera()
    _, pts, normals, _ = synth.surface(cam, "sphere", 1.5)
    other = synth.render(cam, _other_ring(), pts, normals)
    folder = synth.make_press(tmp_path / "copied_meta", "sphere", lin_hook=lambda lin: other)
    with pytest.raises(CaptureError) as err:
        solve_press(load_press(folder), options=QUICK)
    line = str(err.value)
    assert "\n" not in line and line.startswith(str(folder))
    assert "not taken with the sensor that its meta.json and reference.npz describe" in line
    assert "nlips calibrate-leds" in line


def test_a_sensor_whose_leds_differ_in_power_from_its_design_is_not_refused(tmp_path):
    """LED powers 15 % off the design (a real ring's spread) are the sensor's own: the gain per LED absorbs them,
    where the plain model misfit (s26-falsealarm's floor) is far above noise."""
    gains = 1 + 0.15 * np.where(np.arange(12) % 2, 1.0, -1.0)
    folder = synth.make_press(tmp_path / "spread", "sphere", lin_hook=lambda lin: lin * gains[:, None, None, None])
    press = load_press(folder)
    share, _, _ = _sensor_fit(press)
    assert share < 0.01
    result = solve_press(press, options=QUICK)  # (--roi auto: "found no contact", the LED model misfit of s26)
    assert result.reconstructed.any()


def test_a_press_with_its_own_description_fits_it(sphere_press):
    share, _, _ = _sensor_fit(sphere_press)
    assert share < 0.01 and share < tolerances.SENSOR_MISFIT_SHARE / 8


def test_the_twin_default_dome_with_the_fingertip_designs_files_is_refused_and_with_its_own_solved(tmp_path):
    """The digital twin: the default dome's press solved with the fingertip design's meta.json and reference.npz
    (the s26-mismatch walk's case) is refused; the same press with its own files, and the fingertip's undeformed
    capture with its own, are not (one bounce, noise on, 96x72)."""
    pytest.importorskip("mitsuba")
    from nlipscalib.sim.indent import PressConfig
    from nlipscalib.sim.indenters import IndenterConfig
    from nlipscalib.sim.press import render_press
    from nlipscalib.sim.scene import load_scene

    def scene(name):
        return load_scene(name).replace(render={"bounces": 1, "spp": 4}, camera={"width": 96, "height": 72})

    dent = PressConfig(IndenterConfig(kind="sphere", size=6.0), polar_deg=15, azimuth_deg=30, depth=1.5)
    press = render_press(scene("nlipstac"), dent, tmp_path / "nlipstac_press", seed=1)
    fingertip = render_press(scene("fingertip"), None, tmp_path / "fingertip_reference", seed=2)

    copied = tmp_path / "copied"
    shutil.copytree(press, copied)
    for name in ("meta.json", "reference.npz"):
        shutil.copy(fingertip / name, copied / name)
    with pytest.raises(CaptureError, match="not taken with the sensor"):
        solve_press(load_press(copied), options=QUICK)

    for own in (press, fingertip):
        share, _, _ = _sensor_fit(load_press(own))
        assert share < tolerances.SENSOR_MISFIT_SHARE / 2
    assert solve_press(load_press(press), options=QUICK).reconstructed.any()


def test_the_refusal_names_its_override_and_the_override_solves_and_says_so_in_the_report(tmp_path, capsys, caplog):
    """A dome built a few percent off its description, or one its lab knows better: `nlips solve
    --allow-sensor-misfit` solves what is refused by default, and report.json says what was overridden (the
    warning and ``sensor_check``) and records the setting (``check_sensor`` false in the provenance's settings)."""
    import json

    from nlipscalib.cli import main

    cam = synth.camera()
    _, pts, normals, _ = synth.surface(cam, "sphere", 1.5)
    other = synth.render(cam, _other_ring(), pts, normals)
    folder = synth.make_press(tmp_path / "copied_meta", "sphere", lin_hook=lambda lin: other)
    config = tmp_path / "quick.toml"
    config.write_text("max_iters = 2\n", encoding="utf-8")
    assert main(["solve", str(folder), "--config", str(config), "--figures", "none"]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert "not taken with the sensor" in line, line
    assert line.endswith("`nlips solve --allow-sensor-misfit` (check_sensor=False in the API)"), line
    assert not (folder / "nlips" / "result.npz").exists()

    flag = ["--allow-sensor-misfit", "--config", str(config), "--figures", "none"]
    assert main(["solve", str(folder), *flag]) == 0
    report = json.loads((folder / "nlips" / "report.json").read_text(encoding="utf-8"))
    note = report["sensor_check"]
    assert note.startswith(f"{folder}: solved with --allow-sensor-misfit although its images miss"), note
    assert note in report["warnings"] and note in caplog.messages  # logged as a warning
    assert report["provenance"]["settings"]["solver_keywords"]["check_sensor"] is False


def test_the_override_on_a_press_that_fits_overrides_nothing_and_says_so(sphere_press):
    result = solve_press(sphere_press, options=QUICK, check_sensor=False)
    assert result.report["sensor_check"].startswith("off (--allow-sensor-misfit); nothing overridden: the images fit")
    assert not any("allow-sensor-misfit" in w for w in result.report.get("warnings", []))
    assert "sensor_check" not in solve_press(sphere_press, options=QUICK).report


def test_a_reference_capture_of_other_light_is_named_not_the_press_files(tmp_path, capsys):
    """`nlips solve PRESS --reference REF` where REF's light is another sensor's (or settings'): the contact is
    classified against REF's images, so the misfit is theirs, yet the line said "its images were not taken with the
    sensor that its meta.json and reference.npz describe ... Were those files copied from another sensor?" of a
    press whose files were its own (it solves without the --reference). Now it names REF."""
    from nlipscalib.cli import main

    cam = synth.camera()
    _, pts, normals, _ = synth.surface(cam, "none", 0.0)
    other = synth.render(cam, _other_ring(), pts, normals)
    reference = synth.make_press(tmp_path / "other_light_reference", "none", lin_hook=lambda lin: other)
    press = synth.make_press(tmp_path / "press", "sphere")
    config = tmp_path / "quick.toml"
    config.write_text("max_iters = 2\n", encoding="utf-8")
    argv = ["solve", str(press), "--config", str(config), "--figures", "none"]
    assert main([*argv, "--reference", str(reference)]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith(
        f"nlips solve: error: {press}: its images do not fit {reference}, the undeformed dome's capture it is solved "
        "with: "
    ), line
    assert "meta.json" not in line and "--allow-sensor-misfit" in line
    assert main(argv) == 0  # its own files fit its images
