import pytest

from nlipscalib.core.config import from_mapping
from nlipscalib.core.errors import ConfigError
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
    bad.write_text("[dome]\nraduis = 15.0\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"bad\.toml.*dome.*raduis'\] \(did you mean 'radius'\?\) \(known: "):
        load_scene(bad)


@pytest.mark.parametrize(
    "data,message",
    [
        ({"dome": {"radius": "big"}}, "dome.radius: expected a number"),
        ({"dome": {"shape": "torus"}}, "dome.shape: must be one of"),
        ({"dome": {"shape": "hemisphre"}}, "got 'hemisphre' \\(did you mean 'hemisphere'"),
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
    y.write_text("dome:\n  radius: 12.0\n", encoding="utf-8")
    assert load_scene(y).dome.radius == 12.0
    broken = tmp_path / "x.toml"
    broken.write_text("[dome\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="x.toml: cannot parse"):
        load_scene(broken)
    with pytest.raises(ConfigError, match="no such config file"):
        load_scene(tmp_path / "missing.toml")


@pytest.mark.parametrize("text", ["counts: [3\n", "twin:\n  width: 3\n bad: 1\n", "a: 'open\n"])
def test_a_yaml_file_that_does_not_parse_is_one_line_naming_file_and_place(tmp_path, text):
    """PyYAML's message spans several lines (quoting the file, a caret under the place): one line of an error
    message became five on the user's terminal."""
    from nlipscalib.core.config import read_config_file

    bad = tmp_path / "exp.yaml"
    bad.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        read_config_file(bad)
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"{bad}: cannot parse (") and "line " in message


def test_an_empty_yaml_file_reads_as_an_empty_toml_file(tmp_path):
    """An empty (or comments-only) YAML config was refused ("the top level must be a table/mapping") while an
    empty TOML file gives every default."""
    from nlipscalib.core.config import read_config_file

    (tmp_path / "a.yaml").write_text("# nothing changed yet\n", encoding="utf-8")
    (tmp_path / "a.toml").write_text("# nothing changed yet\n", encoding="utf-8")
    assert read_config_file(tmp_path / "a.yaml") == read_config_file(tmp_path / "a.toml") == {}


def test_replace_changes_one_field():
    s = SceneConfig().replace(render={"spp": 16})
    assert s.render.spp == 16 and s.render.bounces == 0


def test_a_section_keeps_the_rest_of_its_fields_default_not_its_classes():
    """``[twin]`` with only ``spp`` for a config whose twin defaults to 640x480 kept the class's 320x240, and Q2's
    ``[train]`` with only ``indenters`` its class's 3 presses instead of Q2's 50 (silently)."""
    import dataclasses

    @dataclasses.dataclass(frozen=True)
    class Inner:
        width: int = 320
        spp: int = 16

    @dataclasses.dataclass(frozen=True)
    class Middle:
        inner: Inner = Inner(width=640)
        name: str = "middle"

    @dataclasses.dataclass(frozen=True)
    class Outer:
        middle: Middle = Middle(inner=Inner(width=800, spp=4))
        flag: bool = False

    cfg = from_mapping(Outer, {"middle": {"inner": {"spp": 8}}})
    assert cfg.middle == Middle(inner=Inner(width=800, spp=8), name="middle")
    assert from_mapping(Outer, {"middle": {"name": "m"}}).middle.inner == Inner(width=800, spp=4)
    assert from_mapping(Outer, {}) == Outer()
    with pytest.raises(ConfigError, match="middle.inner: unknown key"):
        from_mapping(Outer, {"middle": {"inner": {"widht": 1}}})


def test_an_experiment_config_file_overrides_only_what_it_names(tmp_path):
    import dataclasses

    from nlipscalib.experiments.q2 import Q2, Q2Config

    path = tmp_path / "q2.toml"
    path.write_text('[train]\nindenters = [{kind = "brick", size = 8.0}]\n[twin]\nspp = 4\n', encoding="utf-8")
    cfg, full = Q2().config(None, path), Q2Config()
    assert cfg.train == dataclasses.replace(full.train, indenters=cfg.train.indenters) and cfg.train.count == 50
    assert cfg.train.indenters[0].kind == "brick"
    assert (cfg.twin.width, cfg.twin.height, cfg.twin.spp) == (full.twin.width, full.twin.height, 4)
    assert cfg.seen == full.seen and cfg.net == full.net


@pytest.mark.parametrize(
    "camera,message",
    [
        ('model = "brown"', r"dist: the brown model takes 5 coefficients \(k1, k2, p1, p2, k3\), got 4"),
        ('model = "brown"\ndist = [0, 0, 0, 0, 0, 0, 0, 0]', "brown model takes 5 coefficients .*got 8"),
        ("dist = [0.05, -0.01, 0, 0, 0]", r"fisheye model takes 4 coefficients \(k1, k2, k3, k4\), got 5"),
    ],
)
def test_a_scene_camera_with_the_wrong_number_of_lens_coefficients_is_one_line(tmp_path, camera, message):
    """A brown [camera] with the default (fisheye's four) or OpenCV's eight coefficients passed the scene's check and
    failed later in Camera.from_fov: "ValueError: not enough values to unpack (expected 5, got 4)", a traceback."""
    scene = tmp_path / "lens.toml"
    scene.write_text(f"[camera]\n{camera}\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"lens\.toml.*" + message):
        load_scene(scene).camera_model()
    scene.write_text('[camera]\nmodel = "brown"\ndist = [-0.1, 0.01, 0, 0, 0]\n', encoding="utf-8")
    assert load_scene(scene).camera_model().dist == (-0.1, 0.01, 0.0, 0.0, 0.0)


def test_omit_at_leaves_a_field_out_at_its_old_value_and_writes_its_default():
    import dataclasses

    from nlipscalib.core.config import OMIT_AT, OMIT_AT_DEFAULT, to_mapping

    @dataclasses.dataclass(frozen=True)
    class Options:
        kept: int = 1
        new: float = dataclasses.field(default=0.0, metadata={OMIT_AT_DEFAULT: True})
        changed: float = dataclasses.field(default=0.08, metadata={OMIT_AT: 0.0})

    # the default of a field whose default changed is written out (it must not share the old records' key) ...
    assert to_mapping(Options()) == {"kept": 1, "changed": 0.08}
    # ... and its old value, the one records made before it existed meant, is left out like an unchanged default
    assert to_mapping(Options(changed=0.0, new=0.5)) == {"kept": 1, "new": 0.5}
