"""``nlips render`` on a tiny image."""

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core import load_press  # noqa: E402


def test_cli_renders_undeformed_dome(tmp_path, capsys):
    out = tmp_path / "ref"
    rc = main(
        [
            "render",
            "--undeformed",
            "--width",
            "32",
            "--height",
            "24",
            "--spp",
            "1",
            "--threads",
            "2",
            "--seed",
            "4",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    assert capsys.readouterr().out == f"{out}\n"  # the press folder alone: `press=$(nlips render ...)`
    p = load_press(out)
    assert p.camera.shape == (24, 32) and p.meta["provenance"]["seed"] == 4
    assert main(["render", "--undeformed", "--width", "32", "--height", "24", "--out", str(out)]) == 2  # exists


TINY = ["--width", "48", "--height", "36", "--spp", "1", "--threads", "2"]


def test_render_options_choose_the_indenter_size_side_and_a_user_mesh(tmp_path):
    """Size, side and a user's mesh needed a press file: the command line had only --indenter KIND."""
    from pathlib import Path

    pyramid = Path(__file__).resolve().parents[2] / "scenes" / "indenters" / "pyramid.stl"
    cube = tmp_path / "cube"
    assert (
        main(["render", "--indenter", "cube", "--orientation", "corner", "--size", "4", *TINY, "--out", str(cube)]) == 0
    )
    indenter = load_press(cube).meta["provenance"]["press"]["indenter"]
    assert (indenter["kind"], indenter["orientation"], indenter["size"]) == ("cube", "corner", 4.0)
    mesh = tmp_path / "mesh"
    assert main(["render", "--mesh", str(pyramid), "--size", "5", *TINY, "--out", str(mesh)]) == 0
    indenter = load_press(mesh).meta["provenance"]["press"]["indenter"]
    assert (indenter["kind"], indenter["mesh"], indenter["size"]) == ("mesh", str(pyramid), 5.0)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--indenter", "cube", "--mesh", "part.stl"], "--mesh is for --indenter mesh, not --indenter cube"),
        (["--orientation", "side"], "indenter 'sphere' cannot be pressed 'side' (orientations: face)"),
        (["--size", "0"], "--size: must be in (0.0, inf], got 0.0"),
        (["--azimuth", "inf"], "--azimuth: must be a finite angle in degrees, got inf"),
        # the option check allowed 90, then the render failed with "polar angle 90.0 deg is off the dome"
        (["--polar", "90"], "--polar: must be in [0, 90) deg"),
        (["--polar", "nan"], "--polar: must be in [0, 90) deg"),
    ],
)
def test_render_indenter_option_mistakes_are_one_line(tmp_path, capsys, argv, message):
    out = tmp_path / "press"
    assert main(["render", *argv, *TINY, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"nlips render: error: {err[0].removeprefix('nlips render: error: ')}"] and message in err[0]
    assert not out.exists()


def test_a_folder_given_as_the_mesh_is_named_a_folder(tmp_path, capsys):
    """A folder given to --mesh was said to be "no such file", though it exists."""
    folder = tmp_path / "meshes"
    folder.mkdir()
    assert main(["render", "--mesh", str(folder), *TINY, "--out", str(tmp_path / "press")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"nlips render: error: indenter mesh {folder}: a folder, not a mesh")
    assert not (tmp_path / "press").exists()


def test_the_shipped_example_mesh_is_named_where_it_is(tmp_path, capsys, monkeypatch):
    """A wheel's user read "scenes/indenters/pyramid.stl under the installed package" and had to find
    site-packages; `--mesh pyramid.stl` (or `pyramid`) that is not a file prints the example's path. (Not in
    --help: argparse wraps a path at its hyphens, site-packages included.)"""
    from nlipscalib.core.sensor import EXAMPLE_MESH

    assert EXAMPLE_MESH.is_file()
    monkeypatch.chdir(tmp_path)
    for bare in ("pyramid.stl", "pyramid"):
        assert main(["render", "--mesh", bare, *TINY, "--out", "press"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"nlips render: error: indenter mesh {bare}: no such file")
        assert f"shipped with nlipscalib is {EXAMPLE_MESH}" in err[0], err
    assert main(["render", "--mesh", "part.stl", *TINY, "--out", "press"]) == 2  # a user's own: no hint
    assert capsys.readouterr().err.strip() == "nlips render: error: indenter mesh part.stl: no such file"
    assert not (tmp_path / "press").exists()


def test_a_press_no_pixel_shows_is_rendered_with_a_warning(tmp_path, caplog):
    """A press beyond the camera's view (polar 80 deg: the fisheye sees up to about 60) rendered silently, its
    images the undeformed gel's; a press in view gives no warning."""
    import logging

    with caplog.at_level(logging.WARNING, logger="nlipscalib"):
        assert main(["render", "--polar", "80", *TINY, "--out", str(tmp_path / "unseen")]) == 0
        assert main(["render", "--polar", "20", *TINY, "--out", str(tmp_path / "seen")]) == 0
    warned = [r.getMessage() for r in caplog.records if "no pixel shows the contact" in r.getMessage()]
    assert len(warned) == 1 and str(tmp_path / "unseen") in warned[0] and "polar 80 deg" in warned[0]
    assert not load_press(tmp_path / "unseen").ground_truth.contact.any()


def test_an_edited_mesh_is_not_taken_for_its_rendered_press(tmp_path, capsys):
    """The spec hash held the mesh's path only: editing the STL and re-running said "already rendered, nothing to
    do" and kept the old shape's press. An unchanged mesh is still reused; an edited one is stale. The commands run
    in this one process, as in a notebook: the in-process caches of the indenter must not keep the old shape."""
    import json
    import shutil
    from pathlib import Path

    import trimesh

    part = tmp_path / "part.stl"
    shutil.copyfile(Path(__file__).resolve().parents[2] / "scenes" / "indenters" / "pyramid.stl", part)
    out = tmp_path / "press"
    args = ["render", "--mesh", str(part), "--size", "5", *TINY, "--out", str(out)]
    assert main(args) == 0
    first = load_press(out)
    first_contact = first.ground_truth.contact  # read now: a press is what its folder held when loaded
    assert main(args) == 0 and "nothing to do" in capsys.readouterr().err  # unchanged mesh: reused
    trimesh.creation.box(extents=[4.0, 4.0, 3.0]).export(part)  # the same path, another shape
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(out) in err[0] and f"another version of {part}" in err[0] and "--overwrite" in err[0]
    assert json.loads((out / "meta.json").read_text(encoding="utf-8")) == first.meta  # nothing touched
    assert main([*args, "--overwrite"]) == 0
    second = load_press(out)
    assert second.meta["provenance"]["spec_hash"] != first.meta["provenance"]["spec_hash"]
    assert second.meta["provenance"]["seed"] == first.meta["provenance"]["seed"]  # the noise seed stays
    assert not np.array_equal(second.ground_truth.contact, first_contact)  # the box's footprint
    assert main(args) == 0 and "nothing to do" in capsys.readouterr().err
    part.unlink()  # a missing mesh is named as such, not taken for an edited one
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"nlips render: error: indenter mesh {part}: no such file"], err


def _render_help() -> str:
    import argparse

    from nlipscalib.cli import build_parser

    subs = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return " ".join(subs.choices["render"].format_help().split())


def test_render_help_states_the_defaults_a_render_takes():
    """`nlips render --help` states each default (it stated none for the pose, spp, bounces or image size);
    the numbers it gives are the ones an untyped option gets."""
    import re

    from nlipscalib.cli.render import DEFAULT_PRESS
    from nlipscalib.sim.indenters import IndenterConfig
    from nlipscalib.sim.scene import load_scene

    text = _render_help()

    options = text.split("options:", 1)[1]

    def stated(option: str) -> str:
        entry = re.search(rf" {option} [A-Z_]+ (.*?)(?= --|$)", options).group(1)
        m = re.search(r"default:? (?:the scene's(?: \[render\] \w+)?; nlipstac )?([\w.]+)", entry)
        assert m, f"{option}: no default in `nlips render --help`: {entry}"
        return m.group(1)

    for option, key in (("--polar", "polar_deg"), ("--azimuth", "azimuth_deg"), ("--spin", "spin_deg")):
        assert float(stated(option)) == DEFAULT_PRESS[key]
    assert float(stated("--depth")) == DEFAULT_PRESS["depth"]
    assert float(stated("--size")) == IndenterConfig().size
    scene = load_scene("nlipstac")
    for option in ("--spp", "--bounces", "--threads"):
        assert int(stated(option)) == getattr(scene.render, option[2:])
    assert stated("--variant") == scene.render.variant
    assert (int(stated("--width")), int(stated("--height"))) == (scene.camera.width, scene.camera.height)
    pose = DEFAULT_PRESS
    assert f"polar {pose['polar_deg']:g} deg, azimuth {pose['azimuth_deg']:g}" in text
    assert f"{IndenterConfig().size:g} mm {pose['indenter']} {pose['depth']:g} mm deep" in text
    r = scene.render
    assert f"nlipstac: {scene.camera.width}x{scene.camera.height}, {r.spp} spp, direct light" in text and r.bounces == 0


def test_render_through_a_bayer_camera_records_it_and_its_tricolour_frame_fits(tmp_path, capsys):
    """`nlips render --bayer RGGB --crosstalk typical`: the press's scene records the camera (pattern, crosstalk; the
    default demosaicing left out), its frames are demosaiced (neighbouring pixels' colours mixed), and the tri-colour
    check holds its frame as it holds a three-colour camera's; a pattern that is none is refused (argparse's usage and
    its line naming the choices), exit 2."""
    from nlipscalib.core.tricolor_check import press_tricolor_verdict
    from nlipscalib.sim.bayer import TYPICAL_CROSSTALK

    out = tmp_path / "webcam"
    assert (
        main(
            [
                "render",
                "--undeformed",
                *TINY,
                "--seed",
                "3",
                "--bayer",
                "RGGB",
                "--crosstalk",
                "typical",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    press = load_press(out)
    effects = press.meta["provenance"]["scene"]["camera_effects"]
    assert effects["bayer"] == "RGGB" and effects["crosstalk"] == [list(row) for row in TYPICAL_CROSSTALK]
    assert "demosaic" not in effects
    assert press_tricolor_verdict(press).kind in ("fits", "not judged")
    with pytest.raises(SystemExit) as refused:
        main(["render", "--undeformed", *TINY, "--bayer", "RGBG", "--out", str(tmp_path / "bad")])
    assert refused.value.code == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert "argument --bayer: invalid choice: 'RGBG'" in last and "'RGGB'" in last
