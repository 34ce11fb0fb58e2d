"""`nlips render`'s output folder: another run publishing it meanwhile, and a folder that cannot be written."""

from __future__ import annotations

import errno
import json
from pathlib import Path

import pytest

from nlipscalib.cli import main
from nlipscalib.sim import press as sim_press

TINY = ["render", "--width", "96", "--height", "72", "--spp", "1"]


def _published_meanwhile(seed_offset: int = 0):
    """A render_press that finds the folder published by another run (of the same render, or of another seed)
    when it publishes its own, as atomic_dir does: FileExistsError."""

    def render_press(scene, press, out_folder, seed=None, overwrite=False):
        out_folder = Path(out_folder)
        out_folder.mkdir(parents=True)
        recorded = sim_press.render_spec_hash(scene, press, None if seed_offset == 0 else seed_offset)
        (out_folder / "meta.json").write_text(
            json.dumps({"provenance": {"spec_hash": recorded, **sim_press.render_identity()}}), encoding="utf-8"
        )
        raise FileExistsError(errno.EEXIST, "already exists (written by another process)", str(out_folder))

    return render_press


def test_the_same_render_published_meanwhile_by_another_run_is_nothing_to_do(tmp_path, monkeypatch, capsys):
    """Two identical `nlips render` runs at once: the second failed "already exists (use --overwrite to replace
    it)", exit 2, though the folder held exactly its render; run after the first, it says "nothing to do"."""
    out = tmp_path / "r1" / "p"
    monkeypatch.setattr(sim_press, "render_press", _published_meanwhile())
    assert main([*TINY, "--out", str(out)]) == 0
    captured = capsys.readouterr()  # stdout: the press folder alone, done by the other run; the why on stderr
    assert captured.out == f"{out}\n"
    assert (
        captured.err == f"{out}: already rendered from this scene and press (by another run meanwhile), nothing to do\n"
    )


def test_another_render_published_meanwhile_is_still_refused(tmp_path, monkeypatch, capsys):
    out = tmp_path / "r1" / "p"
    monkeypatch.setattr(sim_press, "render_press", _published_meanwhile(seed_offset=12345))
    assert main([*TINY, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "already holds a press rendered from a different scene, press or seed" in err[0], err


def test_a_read_only_output_folder_is_named_as_the_user_gave_it(tmp_path, monkeypatch, capsys):
    """The writability probe's name leaked: "romnt/xxxxxxx: Read-only file system"."""
    mkdir = Path.mkdir

    def read_only(self, *args, **kwargs):
        if self.name.startswith(".tmp-"):
            raise OSError(errno.EROFS, "Read-only file system", str(self))
        return mkdir(self, *args, **kwargs)

    monkeypatch.setattr(Path, "mkdir", read_only)
    monkeypatch.setattr(sim_press, "render_press", lambda *a, **k: pytest.fail("rendered before the check"))
    out = tmp_path / "romnt" / "mypress"
    assert main([*TINY, "--out", str(out)]) == 2
    assert capsys.readouterr().err == (
        f"nlips render: error: {out}: Read-only file system (choose a writable output folder)\n"
    )


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]], ids=["plain", "overwrite"])
def test_a_file_or_a_folder_of_other_things_is_never_replaced_by_a_render(tmp_path, monkeypatch, capsys, overwrite):
    """`nlips render --out out/train50 --overwrite` replaced the whole dataset with the press, `--out notes.txt
    --overwrite` the user's file, and the refusal without --overwrite advised --overwrite; an empty folder or a
    press folder is still rendered into with --overwrite."""
    rendered = []

    def render_press(scene, press, out_folder, seed=None, overwrite=False):
        rendered.append(Path(out_folder))
        return Path(out_folder)

    monkeypatch.setattr(sim_press, "render_press", render_press)
    notes, dataset = tmp_path / "notes.txt", tmp_path / "train50"
    notes.write_text("mine", encoding="utf-8")
    (dataset / "press_0001").mkdir(parents=True)
    (dataset / "press_0001" / "meta.json").write_text("{}", encoding="utf-8")
    refusals = ((notes, "a file where a folder is needed"), (dataset, "a folder holding other things than a press"))
    for out, says in refusals:
        assert main([*TINY, "--out", str(out), *overwrite]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"nlips render: error: {out}: {says}"), err
        assert "use --overwrite" not in err[0]
    assert (
        rendered == []
        and notes.read_text(encoding="utf-8") == "mine"
        and (dataset / "press_0001" / "meta.json").exists()
    )
    if overwrite:
        (tmp_path / "empty").mkdir()
        for out in (tmp_path / "empty", dataset / "press_0001"):
            assert main([*TINY, "--out", str(out), *overwrite]) == 0
        assert rendered == [tmp_path / "empty", dataset / "press_0001"]


def test_a_press_that_other_twin_code_or_mitsuba_rendered_is_kept_with_a_warning(tmp_path, monkeypatch, capsys, caplog):
    """`nlips render` onto a press folder compared the press spec only: after an upgrade of Mitsuba (or of sim/) it
    said "nothing to do" and kept the old images without a word. Now it says what differs and keeps them, as
    `nlips dataset` does; --overwrite renders them again."""
    calls = []

    def render_press(scene, press, out_folder, seed=None, overwrite=False):
        calls.append(overwrite)
        Path(out_folder).mkdir(parents=True, exist_ok=True)
        provenance = {"spec_hash": sim_press.render_spec_hash(scene, press, seed), **sim_press.render_identity()}
        (Path(out_folder) / "meta.json").write_text(json.dumps({"provenance": provenance}), encoding="utf-8")
        return Path(out_folder)

    monkeypatch.setattr(sim_press, "render_press", render_press)
    out = tmp_path / "p"
    assert main([*TINY, "--out", str(out)]) == 0 and calls == [False]
    assert main([*TINY, "--out", str(out)]) == 0 and calls == [False]  # this installation's: nothing to say
    assert not [r for r in caplog.records if "rendered by other twin code" in r.getMessage()]
    meta = json.loads((out / "meta.json").read_text(encoding="utf-8"))
    meta["provenance"]["libraries"] = meta["provenance"]["libraries"] | {"mitsuba": "3.0.0"}
    (out / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    assert main([*TINY, "--out", str(out)]) == 0 and calls == [False]  # kept
    captured = capsys.readouterr()
    assert "already rendered from this scene and press, nothing to do" in captured.err
    assert captured.out.splitlines() == [str(out)] * 3  # rendered, then found done twice: the folder each time
    warned = [r.getMessage() for r in caplog.records if "rendered by other twin code" in r.getMessage()]
    assert len(warned) == 1 and str(out) in warned[0] and "mitsuba 3.0.0 (now " in warned[0], warned
    assert "--overwrite renders it again" in warned[0]
    assert main([*TINY, "--out", str(out), "--overwrite"]) == 0 and calls == [False, True]


def test_a_press_an_older_nlipscalib_rendered_is_refused_naming_the_settings_added_since(tmp_path, monkeypatch, capsys):
    """`nlips render` onto a press folder of 2026-11-23 (754bd8b) said "a different scene, press or seed" although
    the user gave the same: the scene had gained render.denoise since. The line names what differs."""
    from nlipscalib.core.config import to_mapping

    def render_as_754bd8b(scene, press, out_folder, seed=None, overwrite=False):
        scene_dict = scene.to_dict()
        scene_dict["render"] = {k: v for k, v in scene_dict["render"].items() if not k.startswith("denoise")}
        press_dict = None if press is None else to_mapping(press)
        seed = sim_press.press_seed(scene.render.seed, press_dict) if seed is None else seed
        provenance = {"source": "sim", "scene": scene_dict, "press": press_dict, "seed": seed}
        Path(out_folder).mkdir(parents=True, exist_ok=True)
        (Path(out_folder) / "meta.json").write_text(json.dumps({"provenance": provenance}), encoding="utf-8")
        return Path(out_folder)

    monkeypatch.setattr(sim_press, "render_press", render_as_754bd8b)
    args = [*TINY, "--out", str(tmp_path / "p")]
    assert main(args) == 0
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "different scene, press or seed (scene.render.denoise: None -> " in err, err
    assert "settings its record lacks: an older nlipscalib rendered it); use --overwrite" in err


def test_a_render_with_a_file_cut_short_is_rendered_again_not_nothing_to_do(tmp_path, capsys, caplog):
    """Writes are atomic but not synced: a power cut soon after a render was published can leave an image cut
    short. "already rendered from this scene and press, nothing to do" kept it at every run, and the solve failed on
    it. Now the press is rendered again, the same images."""
    from nlipscalib.core.file_checks import file_problem

    out = tmp_path / "p"
    assert main([*TINY, "--out", str(out)]) == 0
    image = out / "led_03.png"
    whole = image.read_bytes()
    image.write_bytes(whole[: len(whole) // 2])
    capsys.readouterr()
    assert main([*TINY, "--out", str(out)]) == 0
    assert "led_03.png cut short (no PNG end chunk); rendering it again" in caplog.text
    assert capsys.readouterr().err.endswith(f"rendered press to {out}\n")
    assert file_problem(image) is None and image.read_bytes() == whole
    assert main([*TINY, "--out", str(out)]) == 0
    assert "nothing to do" in capsys.readouterr().err


def test_a_render_whose_meta_json_is_cut_short_is_named_so_not_another_scene(tmp_path, capsys):
    """A press folder whose meta.json a power cut left cut short was refused as "already holds a press rendered from a
    different scene, press or seed": a wrong cause. Now its meta.json is named, and --overwrite renders it again."""
    out = tmp_path / "p"
    assert main([*TINY, "--out", str(out)]) == 0
    meta = out / "meta.json"
    whole = meta.read_bytes()
    meta.write_bytes(whole[:100])
    capsys.readouterr()
    assert main([*TINY, "--out", str(out)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "meta.json is cut short or damaged (not valid JSON)" in line and "different scene" not in line, line
    assert str(out) in line and "--overwrite" in line
    assert main([*TINY, "--out", str(out), "--overwrite"]) == 0
    capsys.readouterr()
    assert main([*TINY, "--out", str(out)]) == 0  # whole again, and this very render
    assert "nothing to do" in capsys.readouterr().err


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]], ids=["plain", "overwrite"])
def test_a_press_captured_on_a_sensor_is_never_replaced_by_a_render(tmp_path, monkeypatch, capsys, overwrite):
    """`nlips render --out SESSION/press_0001` said the captured press was "rendered from a different scene, press or
    seed (...: an older nlipscalib rendered it)" and advised --overwrite, which then deleted the capture."""
    import numpy as np

    from nlipscalib.core import Camera, Led, SensorResponse
    from nlipscalib.core.capture import write_press

    monkeypatch.setattr(sim_press, "render_press", lambda *args, **kwargs: pytest.fail("rendered over a capture"))
    n, shape = 3, (6, 8, 3)
    out = write_press(
        tmp_path / "session" / "press_0001",
        Camera.from_fov(8, 6, 90.0),
        [Led((np.cos(a) * 5, np.sin(a) * 5, 0.0)) for a in (0.0, 2.0, 4.0)],
        SensorResponse(bit_depth=16, black_level=256.0, white_level=65256.0),
        np.full(shape, 256, np.uint16),
        np.full((n, *shape), 9000, np.uint16),
        np.full(shape, 9000, np.uint16),
        provenance={"source": "device"},
    )
    assert main([*TINY, "--out", str(out), *overwrite]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"nlips render: error: {out}: holds a press captured on a sensor"), err
    assert "even with --overwrite" in err[0] and (out / "led_01.png").exists()


def test_a_press_file_out_of_range_is_one_line_before_the_render(tmp_path, capsys):
    """PressConfig refuses polar_deg = 200 when made (it was refused by the render, after "rendering press ...")."""
    spec = tmp_path / "press.toml"
    spec.write_text("polar_deg = 200\n", encoding="utf-8")
    assert main([*TINY, "--press-file", str(spec), "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    said = f"nlips render: error: {spec}: polar_deg: must be in [0, 90) deg (90 is the dome's open base), got 200.0"
    assert err == [said]
    assert not (tmp_path / "p").exists()


def test_a_missing_mesh_is_one_line_before_the_render(tmp_path, capsys):
    assert main([*TINY, "--mesh", str(tmp_path / "nope.stl"), "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(f"indenter mesh {tmp_path / 'nope.stl'}: no such file"), err


def test_a_press_files_missing_mesh_names_the_press_file_and_where_the_path_was_looked_for(
    tmp_path, capsys, monkeypatch
):
    """A press file naming a mesh that is not there said only "indenter mesh shapes/cone.stl: no such file":
    neither the press file nor that a relative path is read beside it (from the working directory first)."""
    spec = tmp_path / "specs" / "press.toml"
    spec.parent.mkdir()
    spec.write_text('[indenter]\nkind = "mesh"\nmesh = "shapes/cone.stl"\n', encoding="utf-8")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert main([*TINY, "--press-file", str(spec), "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"nlips render: error: {spec}: indenter mesh shapes/cone.stl: no such file; a relative path is looked for "
        f"from the working directory ({work / 'shapes' / 'cone.stl'}), then beside the press file "
        f"({spec.parent / 'shapes' / 'cone.stl'})"
    ]
    absolute = tmp_path / "gone.stl"  # an absolute path: the press file and the path
    spec.write_text(f'[indenter]\nkind = "mesh"\nmesh = "{absolute}"\n', encoding="utf-8")
    assert main([*TINY, "--press-file", str(spec), "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"nlips render: error: {spec}: indenter mesh {absolute}: no such file"]
    assert not (tmp_path / "p").exists()


@pytest.mark.parametrize("bounces, light", [([], "direct light"), (["--bounces", "1"], "1 bounce")])
def test_the_render_line_says_the_light_as_well_as_size_and_spp(tmp_path, monkeypatch, caplog, bounces, light):
    """A new lab's walk: `nlips render ... --bounces 1 --spp 16` said "rendering press (160x120, spp 16)", the same
    as a direct-light render's line, though a model calibrated on one-bounce presses warns on direct-light frames."""
    import logging

    monkeypatch.setattr(sim_press, "render_press", lambda scene, press, out_folder, **kw: Path(out_folder))
    caplog.set_level(logging.INFO)
    assert main([*TINY, *bounces, "--out", str(tmp_path / "p")]) == 0
    assert f"rendering press (96x72, spp 1, {light}) ..." in caplog.text, caplog.text
