"""The sensor design a capture was made with (core.sensor.capture_design): recorded whole, in the twin's scene,
or, for ``nlips capture`` sessions made before 2026-12-04, by the name of a shipped design."""

import dataclasses

import pytest

from nlipscalib.core.sensor import NO_DESIGN, SCENES_DIR, DomeConfig, capture_design, shipped_design
from nlipscalib.sim.scene import load_scene

SHIPPED = sorted(p.stem for p in SCENES_DIR.glob("*.toml"))


def meta(n_leds=12, **provenance):
    return {"leds": [{}] * n_leds, "provenance": provenance}


@pytest.mark.parametrize("name", SHIPPED)
def test_a_shipped_name_is_the_design_nlips_capture_design_records(name):
    assert shipped_design(name) == load_scene(name).design  # what `nlips capture --design NAME` records


@pytest.mark.parametrize("name", ["mysensor", "nlipstac.toml", "scenes/nlipstac", "../scenes/nlipstac", "", None, 3])
def test_only_bare_names_of_shipped_scenes_resolve(name):
    assert shipped_design(name) is None


def test_a_recorded_design_comes_before_the_scene_and_the_name():
    fingertip = dataclasses.asdict(load_scene("fingertip").design)
    recorded = meta(design="nlipstac") | {"design": fingertip}
    (dome, position), note = capture_design(recorded)
    assert dome.shape == "fingertip" and note == ""
    (dome, _), note = capture_design(meta(design="nlipstac", scene=fingertip))  # the twin's provenance.scene
    assert dome.shape == "fingertip" and note == ""


def test_an_old_capture_gets_the_shipped_design_it_names():
    (dome, position), note = capture_design(meta(design="nlipstac"))
    assert dome == DomeConfig() and position.tolist() == [0.0, 0.0, -3.0]
    assert note == "sensor design taken by name: the shipped 'nlipstac' (the capture records its name only)"


@pytest.mark.parametrize(
    "recorded, why",
    [
        (meta(), ""),
        (meta(design="mysensor"), " (it names the design 'mysensor', which does not ship with nlipscalib)"),
        (meta(design="lab/s.toml"), " (it names the design 'lab/s.toml', which does not ship with nlipscalib)"),
        (meta(8, design="nlipstac"), " (it names the design 'nlipstac', whose 12 LEDs are not its 8)"),
    ],
)
def test_no_design_says_so_naming_the_design_it_could_not_take(recorded, why):
    assert capture_design(recorded) == (None, NO_DESIGN + why)
