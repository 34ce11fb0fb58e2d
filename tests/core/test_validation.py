"""Validation at the edge: every out-of-range config value or CLI argument is one line naming file and key."""

from __future__ import annotations

import pytest

from nlipscalib.cli import main
from nlipscalib.core.errors import ConfigError, NlipsError
from nlipscalib.sim.dataset import load_dataset_spec
from nlipscalib.sim.scene import load_scene

# (section, key, TOML value): each out of its physical range
SCENE_CASES = [
    ("noise", "bit_depth", "20"),
    ("noise", "bit_depth", "4"),
    ("noise", "full_well", "0.0"),
    ("noise", "read_noise", "-1.0"),
    ("noise", "black_level", "5000.0"),
    ("noise", "exposure", "0.0"),
    ("coating", "albedo", "[1.5, 0.5, 0.5]"),
    ("coating", "albedo", "[0.5, -0.1, 0.5]"),
    ("coating", "variation", "2.0"),
    ("coating", "variation_scale", "0.0"),
    ("render", "spp", "0"),
    ("render", "bounces", "-1"),
    ("render", "bounces", "1000"),
    ("render", "spp", "1000000000"),
    ("render", "threads", "-2"),
    ("render", "seed", "-5"),
    ("render", "variant", '"gpu_fast"'),
    ("render.denoise", "iterations", "9"),
    ("render.denoise", "normal_deg", "0"),
    ("camera", "width", "0"),
    ("camera", "height", "100000"),
    ("camera", "hfov_deg", "0.0"),
    ("camera", "dist", "[0.1, 0.2]"),
    ("dome", "radius", "-15.0"),
    ("dome", "thickness", "0.0"),
    ("dome", "thickness", "20.0"),
    ("dome", "edge_length", "0.0"),
    ("leds", "count", "2"),
    ("leds", "count", "30"),
    ("leds", "mu", "-1.0"),
    ("leds", "intensity", "[0.0, 0.0, 0.0]"),
    ("leds", "tilt_deg", "120.0"),
    ("leds", "ring_radius", "-1.0"),
]


@pytest.mark.parametrize("section,key,value", SCENE_CASES)
def test_scene_value_out_of_range_names_file_and_key(tmp_path, section, key, value):
    path = tmp_path / "bad_scene.toml"
    path.write_text(f"[{section}]\n{key} = {value}\n", encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_scene(path)
    message = str(info.value)
    assert str(path) in message and section in message and key in message, message
    assert "\n" not in message


def test_leds_given_as_a_word_says_so(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('leds = "twelve"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=r"s\.toml\.leds: expected a table"):
        load_scene(path)


GRID = """
[render]
spp = 1
[grid]
indenters = [{ kind = "sphere", size = 4.0 }]
"""

# (text appended or replaced in the spec, key expected in the message)
SPEC_CASES = [
    (GRID + "depth = [0.0]\n", "depth"),
    (GRID + "depth = [5.0]\n", "depth"),  # deeper than the gel
    (GRID + "polar_deg = [120.0]\n", "polar_deg"),
    (GRID + "depth = []\n", "depth"),
    (GRID.replace("spp = 1", "spp = 0"), "spp"),
    (GRID.replace("[render]", "[noise]\nbit_depth = 20\n[render]"), "bit_depth"),
    (GRID.replace("[render]", "[camera]\nwidth = 2\n[render]"), "width"),
    ("seed = -1\n" + GRID, "seed"),
    ("[random]\ncount = 0\nindenters = [{ kind = 'sphere' }]\n", "count"),
    ("[random]\ncount = 3\nindenters = [{ kind = 'sphere' }]\ndepth = [1.0, 0.5]\n", "depth"),
    ("[random]\ncount = 3\nindenters = []\n", "indenters"),
    ("[grid]\nindenters = [{ kind = 'sphere', size = -1.0 }]\n", "size"),
]


@pytest.mark.parametrize("text,key", SPEC_CASES)
def test_dataset_spec_value_out_of_range_names_file_and_key(tmp_path, text, key):
    path = tmp_path / "bad_spec.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_dataset_spec(path)
    message = str(info.value)
    assert str(path) in message and key in message, message


@pytest.mark.parametrize(
    "args,flag",
    [
        (["dataset", "SPEC", "--out", "OUT", "--workers", "-1"], "--workers"),
        (["dataset", "SPEC", "--out", "OUT", "--limit", "-8"], "--limit"),
        (["render", "--spp", "0", "--out", "OUT"], "--spp"),
        (["render", "--width", "-3", "--out", "OUT"], "--width"),
        (["render", "--threads", "-1", "--out", "OUT"], "--threads"),
        (["render", "--depth", "-1", "--out", "OUT"], "--depth"),
        (["render", "--polar", "100", "--out", "OUT"], "--polar"),
    ],
)
def test_cli_argument_out_of_range_is_one_line(tmp_path, capsys, args, flag):
    spec = tmp_path / "spec.toml"
    spec.write_text(GRID, encoding="utf-8")
    args = [str(spec) if a == "SPEC" else str(tmp_path / "out") if a == "OUT" else a for a in args]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and flag in err and "Traceback" not in err, err
    assert not (tmp_path / "out").exists()  # refused before anything was written


# ---------------------------------------------------------------------- indenter meshes
SINGLE_TRIANGLE = (
    "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid t\n"
)


def _mesh_spec(tmp_path, mesh_path):
    spec = tmp_path / "spec.toml"
    spec.write_text(
        f"[grid]\nindenters = [{{ kind = 'mesh', mesh = '{mesh_path}', size = 4.0 }}]\ndepth = [0.5]\n",
        encoding="utf-8",
    )
    return spec


def test_garbage_mesh_bytes_say_so(tmp_path):
    mesh = tmp_path / "garbage.stl"
    mesh.write_bytes(bytes(range(256)) * 7)
    with pytest.raises(ConfigError) as info:
        load_dataset_spec(_mesh_spec(tmp_path, mesh))
    message = str(info.value)
    assert "not an STL file" in message and "charset" not in message and "spec.toml" in message


def test_single_triangle_mesh_is_refused(tmp_path):
    mesh = tmp_path / "tri.stl"
    mesh.write_text(SINGLE_TRIANGLE, encoding="utf-8")
    with pytest.raises(ConfigError, match="cannot enclose a solid"):
        load_dataset_spec(_mesh_spec(tmp_path, mesh))


def test_open_mesh_is_repaired_with_a_warning_or_refused(tmp_path, caplog):
    trimesh = pytest.importorskip("trimesh")
    from nlipscalib.sim.indenters import IndenterConfig, make_indenter

    box = trimesh.creation.box((4.0, 4.0, 4.0))
    small_hole = tmp_path / "small_hole.stl"
    trimesh.Trimesh(box.vertices, box.faces[:10]).export(small_hole)  # one side missing
    mesh = make_indenter(IndenterConfig(kind="mesh", mesh=str(small_hole)))
    assert mesh.is_watertight and mesh.volume > 0
    assert "not watertight" in caplog.text and "small_hole.stl" in caplog.text

    sphere = trimesh.creation.icosphere()
    big_hole = tmp_path / "big_hole.stl"
    trimesh.Trimesh(sphere.vertices, sphere.faces[:200]).export(big_hole)  # most of it missing
    with pytest.raises(ConfigError, match="big_hole.stl: not a closed solid"):
        make_indenter(IndenterConfig(kind="mesh", mesh=str(big_hole)))


def test_led_file_with_a_word_for_leds_says_so(tmp_path):
    from nlipscalib.core.ledfile import read_led_file

    path = tmp_path / "leds.json"
    path.write_text('{"leds": "twelve"}', encoding="utf-8")
    with pytest.raises(NlipsError) as info:
        read_led_file(path)
    assert "leds.json" in str(info.value) and "must be a list" in str(info.value)
    assert "['t']" not in str(info.value)


def test_a_spec_naming_an_unknown_scene_or_a_folder_given_as_spec_is_named(tmp_path):
    spec = tmp_path / "spec.toml"
    spec.write_text('scene = "nope"\n[grid]\nindenters = [{ kind = "sphere", size = 6.0 }]\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=f"^{spec}: scene 'nope': no such scene file"):
        load_dataset_spec(spec)
    with pytest.raises(ConfigError, match=f"^{tmp_path}: a folder, not a config file"):
        load_dataset_spec(tmp_path)


@pytest.mark.parametrize(
    "camera,line",
    [
        ("width = 160", "[camera] width = 160 without height: the images would be 160x480 pixels"),
        ("height = 720", "[camera] height = 720 without width: the images would be 640x720 pixels"),
    ],
)
def test_a_dataset_specs_camera_with_one_side_is_refused_in_one_line(tmp_path, camera, line):
    """`[camera] width = 160` alone kept the scene's height: `nlips dataset` rendered 160x480 presses without a word."""
    path = tmp_path / "spec.toml"
    path.write_text(
        f'[camera]\n{camera}\n[random]\ncount = 1\nindenters = [{{ kind = "sphere", size = 6.0 }}]\n', encoding="utf-8"
    )
    with pytest.raises(ConfigError) as info:
        load_dataset_spec(path)
    message = str(info.value)
    assert message.startswith(f"{path}: {line}"), message
    assert message.endswith(("give both, e.g. width = 160, height = 120", "give both, e.g. width = 960, height = 720"))
    both = tmp_path / "both.toml"
    both.write_text(path.read_text(encoding="utf-8").replace(camera, "width = 161\nheight = 121"), encoding="utf-8")
    assert (load_dataset_spec(both)[1].camera.width, load_dataset_spec(both)[1].camera.height) == (161, 121)


def test_a_scene_files_camera_with_one_side_is_refused_in_one_line(tmp_path):
    """A scene file of one's own with `[camera] width = 1280` alone rendered 1280x480 images without a word."""
    path = tmp_path / "mine.toml"
    path.write_text("[camera]\nwidth = 1280\nhfov_deg = 100\n", encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_scene(path)
    assert str(info.value).startswith(f"{path}: [camera] width = 1280 without height: the images would be 1280x480")
    assert str(info.value).endswith("give both, e.g. width = 1280, height = 960")
    path.write_text("[camera]\nwidth = 1280\nheight = 720\n", encoding="utf-8")
    camera = load_scene(path).camera
    assert (camera.width, camera.height) == (1280, 720)
