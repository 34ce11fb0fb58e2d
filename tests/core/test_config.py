import pytest

from nlipscalib.config import from_mapping
from nlipscalib.errors import ConfigError
from nlipscalib.sim.scene import SCENES_DIR, SceneConfig, load_scene


def test_every_shipped_scene_loads():
    names = sorted(p.stem for p in SCENES_DIR.glob("*.toml"))
    assert {"nlipstac", "fingertip", "oblate", "capsule", "flat"} <= set(names)
    for name in names:
        scene = load_scene(name)
        assert 3 <= len(scene.led_models()) <= 24
        assert scene.camera_model().shape == (scene.camera.height, scene.camera.width)


def test_default_scene_is_nlipstac():
    scene = load_scene()
    assert scene.name == "nlipstac" and len(scene.led_models()) == 12 and scene.dome.shape == "hemisphere"


def test_typo_names_file_section_and_key(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[dome]\nraduis = 15.0\n")
    with pytest.raises(ConfigError, match=r"bad\.toml.*dome.*raduis"):
        load_scene(bad)


@pytest.mark.parametrize(
    "data,message",
    [
        ({"dome": {"radius": "big"}}, "dome.radius: expected a number"),
        ({"dome": {"shape": "torus"}}, "dome.shape: must be one of"),
        ({"leds": {"count": 40}}, "3 to 24 LEDs"),
        ({"camera": {"position": [0, 0]}}, "camera.position: expected 3 values"),
        ({"render": {"spp": 1.5}}, "render.spp: expected an integer"),
    ],
)
def test_bad_values_are_explained(data, message):
    with pytest.raises(ConfigError, match=message.replace(".", r"\.")):
        from_mapping(SceneConfig, data, "scene")


def test_yaml_and_unparsable_files(tmp_path):
    y = tmp_path / "s.yaml"
    y.write_text("dome:\n  radius: 12.0\n")
    assert load_scene(y).dome.radius == 12.0
    broken = tmp_path / "x.toml"
    broken.write_text("[dome\n")
    with pytest.raises(ConfigError, match="x.toml: cannot parse"):
        load_scene(broken)
    with pytest.raises(ConfigError, match="no such config file"):
        load_scene(tmp_path / "missing.toml")


def test_replace_changes_one_field():
    s = SceneConfig().replace(render={"spp": 16})
    assert s.render.spp == 16 and s.render.bounces == 0
