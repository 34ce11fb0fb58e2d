"""render_press: capture round trip, determinism, shared exposure, presses."""

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.core.config import to_mapping  # noqa: E402
from nlipscalib.sim.press import render_press, scene_exposure, tricolor_linear  # noqa: E402
from nlipscalib.sim.scene import SceneConfig  # noqa: E402


@pytest.fixture(scope="module")
def scene():
    return SceneConfig().replace(camera={"width": 40, "height": 30}, render={"spp": 1, "threads": 2})


def test_undeformed_press_round_trip(scene, tmp_path):
    path, res = render_press(scene, None, tmp_path / "p0", seed=3, return_result=True)
    p = load_press(path)
    assert p.led_images.shape == (12, 30, 40, 3) and p.dark.shape == (30, 40, 3)
    prov = p.meta["provenance"]
    assert prov["source"] == "sim" and prov["seed"] == 3 and prov["press"] is None
    assert prov["exposure"] == pytest.approx(scene_exposure(scene))
    assert {"variant", "spp", "bounces", "scene"} <= set(prov)
    from importlib import metadata  # the renderer's release moves the images: meta.json says which made them

    assert prov["libraries"] == {"mitsuba": metadata.version("mitsuba"), "drjit": metadata.version("drjit")}
    # and the twin's code: a press that other code or another renderer made is not reused as this one's
    from nlipscalib.sim.press import rendered_elsewhere

    assert len(prov["code"]) == 32 and not rendered_elsewhere(prov)
    assert rendered_elsewhere(prov | {"code": "0" * 32})
    assert rendered_elsewhere(prov | {"libraries": prov["libraries"] | {"drjit": "0.4.0"}})
    assert rendered_elsewhere({k: v for k, v in prov.items() if k != "code"})  # rendered before 2026-12-06
    assert p.reference is not None and p.ground_truth is not None
    assert not p.ground_truth.contact.any()
    np.testing.assert_array_equal(p.reference.depth, p.ground_truth.depth)
    # stored images decode to exposure x linear radiance (noise: few % per pixel, unbiased on average)
    v = p.ground_truth.valid
    lin = p.linear(p.led_images)[:, v]
    want = res.images[:, v] * prov["exposure"]
    assert abs(lin.mean() / want.mean() - 1) < 0.01
    tri = p.linear(p.tricolor)[v]
    assert prov["tricolor_exposure"] == pytest.approx(scene_exposure(scene, tricolor=True))
    assert abs(tri.mean() / (tricolor_linear(res.images)[v] * prov["tricolor_exposure"]).mean() - 1) < 0.01
    assert (p.tricolor >= p.response.white_level).mean() < 0.01


def test_same_seed_bit_identical(scene, tmp_path):
    a = load_press(render_press(scene, None, tmp_path / "a", seed=5))
    b = load_press(render_press(scene, None, tmp_path / "b", seed=5))
    c = load_press(render_press(scene, None, tmp_path / "c", seed=6))
    np.testing.assert_array_equal(a.led_images, b.led_images)
    np.testing.assert_array_equal(a.tricolor, b.tricolor)
    np.testing.assert_array_equal(a.dark, b.dark)
    assert not np.array_equal(a.led_images, c.led_images)


def test_overwrite_guard(scene, tmp_path):
    render_press(scene, None, tmp_path / "p", seed=1)
    with pytest.raises(FileExistsError):
        render_press(scene, None, tmp_path / "p", seed=1)
    render_press(scene, None, tmp_path / "p", seed=1, overwrite=True)


def test_pressed_dome_has_contact_and_same_exposure(scene, tmp_path):
    indent = pytest.importorskip("nlipscalib.sim.indent")
    from nlipscalib.cli.render import DEFAULT_PRESS
    from nlipscalib.core.config import from_mapping

    press = from_mapping(indent.PressConfig, DEFAULT_PRESS | {"indenter": {"kind": "sphere"}, "depth": 1.5}, "press")
    p = load_press(render_press(scene.replace(camera={"width": 80, "height": 60}), press, tmp_path / "p", seed=2))
    assert p.ground_truth.contact.any()
    assert p.meta["provenance"]["press"]["depth"] == 1.5


def test_default_seed_differs_between_presses_and_repeats_for_one():
    from nlipscalib.sim.indent import IndenterConfig, PressConfig
    from nlipscalib.sim.press import press_seed

    a = to_mapping(PressConfig(IndenterConfig("sphere", 6.0), polar_deg=10.0, depth=1.0))
    b = to_mapping(PressConfig(IndenterConfig("sphere", 6.0), polar_deg=10.0, depth=1.1))
    assert press_seed(0, a) == press_seed(0, a)
    assert len({press_seed(0, a), press_seed(0, b), press_seed(0, None), press_seed(1, a)}) == 4


def test_only_a_mesh_press_hashes_its_file_content(tmp_path):
    """Hashing a mesh indenter's file must leave every other press's spec hash as it was (values from the code
    before mesh content was hashed): a changed hash re-renders or refuses every existing dataset's presses."""
    from nlipscalib.core.config import digest
    from nlipscalib.sim.indent import IndenterConfig, PressConfig
    from nlipscalib.sim.press import press_seed, render_spec_hash

    scene = SceneConfig()
    sphere = PressConfig(IndenterConfig(kind="sphere", size=6.0), polar_deg=20, azimuth_deg=30, depth=1.0)
    assert render_spec_hash(scene, sphere) == "c12b4e1ebfd82f33"
    assert render_spec_hash(scene, None, seed=3) == "4bf108c3ab66ac47"
    cube = PressConfig(IndenterConfig(kind="cube", size=5.0), depth=0.8)
    render = {k: v for k, v in scene.to_dict()["render"].items() if k != "threads"}
    before = digest({"scene": scene.to_dict() | {"render": render}, "press": to_mapping(cube), "seed": 9})
    assert render_spec_hash(scene, cube, 9) == before
    # a mesh press: the file's content counts, its noise seed does not change with it
    part = tmp_path / "part.stl"
    part.write_bytes(b"solid a\nendsolid a\n")
    mesh = PressConfig(IndenterConfig(kind="mesh", mesh=str(part)), depth=0.8)
    seed, first = press_seed(0, to_mapping(mesh)), render_spec_hash(scene, mesh)
    assert render_spec_hash(scene, mesh) == first
    part.write_bytes(b"solid b\nendsolid b\n")
    assert render_spec_hash(scene, mesh) != first and press_seed(0, to_mapping(mesh)) == seed


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_folder_of_other_things_is_refused_before_the_render(scene, tmp_path, overwrite):
    """It said "FileExistsError: already exists" after the render (and overwrite=True replaced the folder whole):
    one ConfigError naming the folder and what to do, worded for a Python caller, nothing replaced."""
    from nlipscalib.core.errors import ConfigError

    out = tmp_path / "notes"
    out.mkdir()
    (out / "mine.txt").write_text("keep me", encoding="utf-8")
    with pytest.raises(ConfigError, match="holding other things than a press") as caught:
        render_press(scene, None, out, overwrite=overwrite)
    assert str(out) in str(caught.value) and "choose another out_folder" in str(caught.value)
    assert "--out" not in str(caught.value) and (out / "mine.txt").read_text(encoding="utf-8") == "keep me"


def test_a_press_folder_without_overwrite_is_said_before_the_render(scene, tmp_path, monkeypatch):
    """FileExistsError (documented) naming the folder and the keyword, before the render (it came after it)."""
    from nlipscalib.sim.render import surface

    out = tmp_path / "p"
    out.mkdir()
    (out / "meta.json").write_text("{}", encoding="utf-8")
    monkeypatch.setattr(surface, "render_surface", lambda *a, **k: pytest.fail("rendered"))
    with pytest.raises(FileExistsError, match="overwrite=True renders it again") as caught:
        render_press(scene, None, out)
    assert caught.value.filename == str(out)


def test_an_empty_folder_needs_overwrite(scene, tmp_path):
    from nlipscalib.core.errors import ConfigError

    with pytest.raises(ConfigError, match="exists and is not a press folder; choose another out_folder or use "):
        render_press(scene, None, tmp_path)
    notes = tmp_path / "notes.txt"
    notes.write_text("x", encoding="utf-8")
    with pytest.raises(ConfigError, match="a file where a folder is needed"):
        render_press(scene, None, notes, overwrite=True)


@pytest.mark.parametrize(
    ("spoilt", "message"),
    [
        ({"scene": 3}, "scene must be a SceneConfig"),
        ({"press": {"depth": 1.0}}, "press must be a PressConfig, or None"),
        ({"out_folder": 7}, "out_folder must be the press folder's path"),
    ],
)
def test_arguments_of_another_kind_are_one_error_naming_them(scene, tmp_path, spoilt, message):
    """They failed with Python's own AttributeError or TypeError from inside the render."""
    from nlipscalib.core.errors import ShapeError

    args = {"scene": scene, "press": None, "out_folder": tmp_path / "p"} | spoilt
    with pytest.raises(ShapeError, match=message):
        render_press(**args)
