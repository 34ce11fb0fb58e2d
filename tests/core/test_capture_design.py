"""The sensor design a capture was made with (core.sensor.capture_design): recorded whole, in the twin's scene,
or, for ``nlips capture`` sessions made before 2026-12-04, by the name of a shipped design."""

import dataclasses

import pytest

from nlipscalib.core.config import from_mapping, to_mapping
from nlipscalib.core.errors import ConfigError
from nlipscalib.core.sensor import (
    MAX_EMITTER_DIAMETER_MM,
    NO_DESIGN,
    SCENES_DIR,
    DomeConfig,
    LedConfig,
    SensorDesign,
    capture_design,
    capture_led_diameter,
    shipped_design,
)
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


# --- the LEDs' emitting diameter a design declares (leds.emitter_diameter, s29-ledsize) ---


@pytest.mark.parametrize("name", SHIPPED)
def test_the_shipped_designs_declare_the_led_size_their_twin_renders(name):
    scene = load_scene(name)
    renders_disks = scene.led_package.enabled and scene.led_package.shape == "disk"
    assert scene.design.leds.emitter_diameter == (scene.led_package.size if renders_disks else 0.0)


@pytest.mark.parametrize("value", [-0.1, MAX_EMITTER_DIAMETER_MM + 0.1, float("nan")])
def test_an_led_size_out_of_range_is_refused_naming_the_field(value):
    with pytest.raises(ConfigError, match="emitter_diameter"):
        LedConfig(emitter_diameter=value)
    with pytest.raises(ConfigError, match="emitter_diameter"):
        from_mapping(SensorDesign, {"leds": {"emitter_diameter": value}}, "design.toml")


def test_a_design_without_the_led_size_loads_and_records_as_before():
    old = {"leds": {"count": 8, "ring_radius": 7.0}}  # a design file written before the field
    design = from_mapping(SensorDesign, old, "old.toml")
    assert design.leds.emitter_diameter == 0.0
    assert "emitter_diameter" not in to_mapping(design)["leds"]  # at 0 the record is the one made before
    assert to_mapping(LedConfig(emitter_diameter=3.6))["emitter_diameter"] == 3.6


def test_the_led_size_changes_no_render_or_experiment_hash():
    from nlipscalib.experiments.tasks import scene_key
    from nlipscalib.sim.press import render_spec_hash

    declared = load_scene("nlipstac")
    undeclared = declared.replace(leds={"emitter_diameter": 0.0})
    assert declared.leds.emitter_diameter > 0 and "emitter_diameter" not in undeclared.to_dict()["leds"]
    assert render_spec_hash(declared) == render_spec_hash(undeclared)  # the twin renders [led_package], not it
    assert scene_key(declared.to_dict()) == scene_key(undeclared.to_dict())
    other = declared.replace(led_package={"size": 3.0})  # what the render does read still counts
    assert render_spec_hash(other) != render_spec_hash(declared)


def test_the_capture_records_its_designs_led_size_where_calibrate_leds_reads_it():
    scene = dataclasses.asdict(load_scene("nlipstac").design)
    assert capture_led_diameter({"design": scene, "leds": [{}] * 12}, "m.json") == (
        3.6,
        "m.json: design.leds.emitter_diameter",
    )
    assert capture_led_diameter(meta(scene=load_scene("nlipstac").to_dict()))[0] == 3.6  # the twin's provenance
    size, why = capture_led_diameter(meta(scene=load_scene("nlipstac_ideal").to_dict()), "m.json")
    assert size == 0.0 and why == "m.json: its design (provenance.scene) declares no leds.emitter_diameter"
    assert capture_led_diameter(meta(design="nlipstac"))[0] == 3.6  # a session before the design was recorded
    assert capture_led_diameter(meta(design="nlipstac", n_leds=8))[0] == 0.0  # not the sensor the name designs
    assert capture_led_diameter(meta(), "m.json") == (0.0, "m.json: no sensor design recorded")


@pytest.mark.parametrize("value", [-1, "3.6", True, None, 25])
def test_a_bad_recorded_led_size_is_one_line_naming_the_file_and_key(value):
    bad = meta(scene={"leds": {"emitter_diameter": value}})
    with pytest.raises(ConfigError, match=r"^p/meta.json: provenance.scene.leds.emitter_diameter"):
        capture_led_diameter(bad, "p/meta.json")


def test_a_reference_rendered_before_the_led_size_was_declared_still_matches_its_presses():
    """A twin reference rendered before the shipped scenes declared ``emitter_diameter`` and a press rendered after
    differ in that key only: the same light (the twin renders ``[led_package]``), so no refusal."""
    from nlipscalib.pipeline.settings import twin_render_difference

    now = load_scene("nlipstac").to_dict()
    before = now | {"leds": {k: v for k, v in now["leds"].items() if k != "emitter_diameter"}}
    sim = lambda scene: {"provenance": {"source": "sim", "scene": scene}}  # noqa: E731
    assert twin_render_difference(sim(before), sim(now)) == ""
    bounced = now | {"render": now["render"] | {"bounces": 1}}
    assert twin_render_difference(sim(before), sim(bounced)) == "render.bounces 0 here, 1 for the press"


def test_a_direct_light_reference_rendered_before_the_bounce_filter_still_matches_its_presses():
    """A twin reference of 2026-11-23 (754bd8b) records no render.denoise settings (added with the bounce light's
    filter): `nlips solve --reference` of it for a direct-light press rendered since was refused ("render.denoise.
    depth_rel None here, 0.01 for the press"), though the filter touches bounce light only. With bounces it still
    differs."""
    from nlipscalib.pipeline.settings import twin_render_difference

    now = load_scene("nlipstac").to_dict()
    assert now["render"]["bounces"] == 0
    before = now | {"render": {k: v for k, v in now["render"].items() if not k.startswith("denoise")}}
    sim = lambda scene: {"provenance": {"source": "sim", "scene": scene}}  # noqa: E731
    assert twin_render_difference(sim(before), sim(now)) == ""
    bounced = lambda scene: scene | {"render": scene["render"] | {"bounces": 1}}  # noqa: E731
    assert twin_render_difference(sim(bounced(before)), sim(bounced(now))).startswith(
        "render.denoise.depth_rel None here, 0.01 for the press"
    )
