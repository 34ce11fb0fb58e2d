"""Every shipped scene renders: the camera sees the gel, without holes, with sane exposure."""

import numpy as np
import pytest
from scipy.ndimage import binary_fill_holes

from nlipscalib.core import load_press
from nlipscalib.sim.press import render_press
from nlipscalib.sim.scene import SCENES_DIR, load_scene

pytest.importorskip("mitsuba")
SCENES = sorted(p.stem for p in SCENES_DIR.glob("*.toml"))


@pytest.mark.parametrize("name", SCENES)
def test_shipped_scene_sees_the_whole_gel_without_holes(tmp_path, name):
    # 64x48: u - cx = v - cy holds exactly for pixel centres on the image diagonal, the case in which
    # rays graze mesh edges that lie in a plane through the optical axis.
    scene = load_scene(name)
    # light through a refracting gel arrives only by sampled paths: a few more samples keep it from speckling
    spp = 32 if scene.gel_optics.enabled else 1
    scene = scene.replace(camera={"width": 64, "height": 48}, render={"spp": spp})
    press = load_press(render_press(scene, None, tmp_path / name, seed=0))
    valid = press.ground_truth.valid
    assert valid.mean() > 0.5, "the camera should mostly see the gel"
    assert np.array_equal(binary_fill_holes(valid), valid), "rays slip through the gel mesh"
    assert not press.ground_truth.contact.any()
    lit = press.linear(press.led_images)[:, valid]
    assert 0.05 < lit.max() and press.saturated(press.led_images).mean() < 0.01


def test_a_scene_name_that_is_neither_a_file_nor_shipped_says_so_and_lists_the_shipped_ones():
    """It read "nowhere: no such config file" (a scene name is not a config file the user wrote)."""
    from nlipscalib.core.errors import ConfigError

    with pytest.raises(ConfigError) as err:
        load_scene("nowhere")
    assert str(err.value).startswith("scene 'nowhere': no such scene file, nor a shipped scene (")
    assert "fingertip" in str(err.value) and "nlipstac" in str(err.value)
    with pytest.raises(ConfigError, match="no such config file"):
        load_scene("missing.toml")  # a file name keeps its message


def test_a_scene_file_named_without_its_suffix_is_named_in_the_error(tmp_path, monkeypatch):
    """The lab-2 walk: a copy of fingertip.toml saved as myfinger.toml and given as `--scene myfinger` (as the
    shipped scenes are named) was "no such scene file, nor a shipped scene (...)", the file beside it unnamed."""
    from nlipscalib.core.errors import ConfigError

    monkeypatch.chdir(tmp_path)
    (tmp_path / "myfinger.toml").write_text(
        (SCENES_DIR / "fingertip.toml").read_text(encoding="utf-8"), encoding="utf-8"
    )
    with pytest.raises(ConfigError) as err:
        load_scene("myfinger")
    assert str(err.value).startswith("scene 'myfinger': no such scene file, nor a shipped scene (")
    assert str(err.value).endswith("; a scene file of one's own is named with its suffix: myfinger.toml")
    assert load_scene("myfinger.toml").dome.shape == "fingertip"
    with pytest.raises(ConfigError) as err:
        load_scene("nowhere")
    assert "of one's own" not in str(err.value)  # no file of that name: no hint


def test_a_dataset_folder_given_for_its_spec_is_called_a_folder(tmp_path, monkeypatch, capsys):
    """`nlips dataset out/small --out ...` (the rendered folder, not its spec) said "dataset spec 'out/small': no
    such file, nor a shipped dataset spec": the folder is there, and the line sent the user looking for it."""
    from nlipscalib.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "out" / "small" / "press_0001").mkdir(parents=True)
    assert main(["--no-progress", "dataset", "out/small", "--out", "out/again"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["nlips dataset: error: out/small: a folder, not a config file (.toml, .yaml)"], err
    assert not (tmp_path / "out" / "again").exists()


def test_the_wide_scene_is_the_default_sensor_seen_past_its_gel(tmp_path):
    """scenes/nlipstac_wide.toml (docs/twin.md, "A view beyond the gel"): the default sensor with only its camera
    moved back and widened; the design's gel footprint (``core.dome.reference_surface``, a device capture's mask)
    leaves black corners, and the render's ``valid`` is that footprint."""
    from nlipscalib.core.dome import reference_surface

    small = {"width": 64, "height": 48}
    wide = load_scene("nlipstac_wide").replace(camera=small)
    default = load_scene().replace(camera={**small, "hfov_deg": 130.0, "position": (0.0, 0.0, -8.0)})
    assert {k for k, v in wide.to_dict().items() if default.to_dict()[k] != v} == {"name"}
    footprint = np.isfinite(reference_surface(wide.design, wide.camera_model()).depth)
    assert 0.75 < footprint.mean() < 0.9 and not footprint[0, 0] and not footprint[-1, -1]
    valid = load_press(render_press(wide, None, tmp_path / "wide", seed=0)).ground_truth.valid
    assert np.array_equal(valid, footprint)
