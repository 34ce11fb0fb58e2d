import json
import logging
import os

import numpy as np
import pytest

from nlipscalib.core.atomic import TMP_PREFIX
from nlipscalib.core.errors import ConfigError
from nlipscalib.sim import dataset as ds
from nlipscalib.sim import dataset_pool
from nlipscalib.sim.dataset import DatasetSpec, expand_jobs, load_dataset_spec, run_dataset
from nlipscalib.sim.press import render_identity, render_spec_hash
from nlipscalib.sim.scene import SCENES_DIR


def _write(tmp_path, text):
    p = tmp_path / "spec.toml"
    p.write_text(text, encoding="utf-8")
    return p


GRID = """
scene = "nlipstac"
seed = 3
[render]
spp = 2
[grid]
indenters = [{ kind = "sphere", size = 6.0 }, { kind = "cube", size = 4.0 }]
polar_deg = [0.0, 20.0]
depth = [0.5, 1.0, 1.5]
"""


def test_grid_expands_to_every_combination_plus_reference(tmp_path):
    spec, scene = load_dataset_spec(_write(tmp_path, GRID))
    jobs = expand_jobs(spec)
    assert scene.render.spp == 2  # override applied
    assert jobs[0].name == "reference" and jobs[0].press is None
    presses = [j.press for j in jobs[1:]]
    assert len(presses) == 2 * 2 * 3
    assert {p.depth for p in presses} == {0.5, 1.0, 1.5}
    assert len({j.seed for j in jobs}) == len(jobs)  # every press its own noise seed


def test_random_draw_is_reproducible_and_in_range(tmp_path):
    text = """
seed = 11
reference = false
[random]
count = 20
indenters = [{ kind = "sphere", size = 6.0 }]
polar_deg = [5.0, 25.0]
depth = [0.4, 0.9]
"""
    spec, _ = load_dataset_spec(_write(tmp_path, text))
    a, b = expand_jobs(spec), expand_jobs(spec)
    assert [j.press for j in a] == [j.press for j in b] and len(a) == 20
    depths = np.array([j.press.depth for j in a])
    polars = np.array([j.press.polar_deg for j in a])
    assert depths.min() >= 0.4 and depths.max() <= 0.9 and polars.min() >= 5 and polars.max() <= 25
    assert np.ptp(depths) > 0.1  # actually random


def test_spec_needs_exactly_one_mode(tmp_path):
    with pytest.raises(ConfigError, match="exactly one"):
        DatasetSpec()
    with pytest.raises(ConfigError, match=r"spec\.toml.*grid.*unknown"):
        load_dataset_spec(_write(tmp_path, "[grid]\nindenters = []\ndepths = [1.0]\n"))


def test_shipped_dataset_specs_load():
    for path in (SCENES_DIR / "datasets").glob("*.toml"):
        spec, _ = load_dataset_spec(path)
        assert expand_jobs(spec)


def test_run_resumes_and_reports_failures(tmp_path, monkeypatch):
    """Resume logic with a stand-in renderer (the real one is tested in test_press)."""
    spec, scene = load_dataset_spec(_write(tmp_path, GRID))
    jobs = expand_jobs(spec)[:4]
    calls = []

    def fake_render(scene, job, out, overwrite=False):
        calls.append(job.name)
        if job.name == "press_0003":
            raise ConfigError("indenter off the dome")
        folder = out / job.name
        folder.mkdir()
        meta = {"provenance": {"spec_hash": render_spec_hash(scene, job.press, job.seed), **render_identity()}}
        (folder / "meta.json").write_text(json.dumps(meta), encoding="utf-8")

    monkeypatch.setattr(dataset_pool, "_run_one", fake_render)
    out = tmp_path / "out"
    (out / (TMP_PREFIX + "press_0002-x")).mkdir(parents=True)  # an interrupted earlier write (old naming)
    os.utime(out / (TMP_PREFIX + "press_0002-x"), (0, 0))
    first = run_dataset(scene, jobs, out, workers=1, progress=False)
    assert sorted(first["rendered"]) == ["press_0001", "press_0002", "reference"]
    assert first["failed"][0][0] == "press_0003" and "off the dome" in first["failed"][0][1]
    assert not list(out.glob(TMP_PREFIX + "*"))
    calls.clear()
    second = run_dataset(scene, jobs, out, workers=1, progress=False)
    assert calls == ["press_0003"]  # finished presses are never rendered twice
    assert len(second["skipped"]) == 3


@pytest.mark.parametrize(
    "was, said",
    [
        ({"code": "0" * 32}, "other code of sim/ or core/"),
        ({"libraries": {"mitsuba": "3.0.0", "drjit": "0.4.0"}}, "mitsuba 3.0.0 (now "),
        ({"code": None}, "twin code unrecorded: rendered before 2026-12-06"),
    ],
)
def test_presses_other_twin_code_or_another_renderer_made_are_named_and_rendered_again_on_overwrite(
    tmp_path, monkeypatch, caplog, was, said
):
    """A rerun after an upgrade (sim/ or core/, Mitsuba, Dr.Jit) skipped the presses the old code had rendered and
    rendered the rest with the new one: one dataset of two renderers, said nowhere (the spec hash holds neither).
    Now they are named with what differs and kept (`nlips demo` after an upgrade must not stop on its old
    renders); --overwrite renders exactly them again."""
    spec, scene = load_dataset_spec(_write(tmp_path, GRID))
    jobs = expand_jobs(spec)[:3]
    calls = []

    def fake_render(scene, job, out, overwrite=False):
        calls.append(job.name)
        folder = out / job.name
        folder.mkdir(exist_ok=True)
        meta = {"provenance": {"spec_hash": render_spec_hash(scene, job.press, job.seed), **render_identity()}}
        (folder / "meta.json").write_text(json.dumps(meta), encoding="utf-8")

    monkeypatch.setattr(dataset_pool, "_run_one", fake_render)
    out = tmp_path / "out"
    run_dataset(scene, jobs, out, workers=1, progress=False)
    path = out / jobs[1].name / "meta.json"
    meta = json.loads(path.read_text(encoding="utf-8"))
    meta["provenance"] |= was
    if was.get("code", "") is None:
        del meta["provenance"]["code"]
    path.write_text(json.dumps(meta), encoding="utf-8")
    calls.clear()
    with caplog.at_level("WARNING", logger="nlipscalib.sim"):
        kept = run_dataset(scene, jobs, out, workers=1, progress=False)
    assert calls == [] and sorted(kept["skipped"]) == sorted(j.name for j in jobs)
    warned = [r.getMessage() for r in caplog.records if "rendered by other twin code" in r.getMessage()]
    assert len(warned) == 1 and jobs[1].name in warned[0] and said in warned[0] and "--overwrite" in warned[0]
    again = run_dataset(scene, jobs, out, workers=1, progress=False, overwrite=True)
    assert calls == [jobs[1].name] and again["rendered"] == [jobs[1].name]
    assert not dataset_pool.check_existing(scene, jobs, out, False)  # all this code's now


def test_a_spec_finds_its_indenter_mesh_beside_it_from_any_working_directory(tmp_path, monkeypatch):
    """``mesh = "part.stl"`` in a spec was looked up in the working directory: the same spec failed with
    "no such file" when run from anywhere else (its ``scene`` was already found beside it)."""
    folder = tmp_path / "specs"
    folder.mkdir()
    (folder / "part.stl").write_bytes((SCENES_DIR / "indenters" / "pyramid.stl").read_bytes())
    spec_file = folder / "spec.toml"
    spec_file.write_text(
        'reference = false\n[random]\ncount = 2\nindenters = [{ kind = "mesh", mesh = "part.stl" }]\n', encoding="utf-8"
    )
    monkeypatch.chdir(tmp_path)
    spec, _ = load_dataset_spec(spec_file)
    assert spec.random.indenters[0].mesh == str(folder / "part.stl")


def test_an_edited_indenter_mesh_makes_its_presses_stale_and_only_those(tmp_path, monkeypatch, capsys):
    """Editing the STL a spec names (a relative path, found beside the spec) and re-running took the presses of
    the old shape as done. Now they are refused as stale (re-rendered with --overwrite); the sphere's presses,
    the reference, and every press of an unchanged mesh are kept."""
    import trimesh

    from nlipscalib.cli import main
    from tests.cli.test_faults import _fake_render

    folder = tmp_path / "specs"
    folder.mkdir()
    (folder / "part.stl").write_bytes((SCENES_DIR / "indenters" / "pyramid.stl").read_bytes())
    spec = folder / "spec.toml"
    spec.write_text(
        '[grid]\nindenters = [{ kind = "sphere" }, { kind = "mesh", mesh = "part.stl" }]\ndepth = [0.5, 1.0]\n',
        encoding="utf-8",
    )
    out, calls = tmp_path / "out", []
    monkeypatch.chdir(tmp_path)  # the mesh is found beside the spec, not in the working directory
    monkeypatch.setattr(dataset_pool, "_run_one", _fake_render(calls))
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 0
    assert calls == ["reference", "press_0001", "press_0002", "press_0003", "press_0004"]
    calls.clear()
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 0 and calls == []  # unchanged
    trimesh.creation.box(extents=[4.0, 4.0, 3.0]).export(folder / "part.stl")
    capsys.readouterr()
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "press_0003, press_0004 were rendered" in err[0] and "mesh file" in err[0], err
    assert calls == []
    monkeypatch.setattr(dataset_pool, "_run_one", _rerender(calls))
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1", "--overwrite"]) == 0
    assert calls == ["press_0003", "press_0004"]  # the mesh's presses only


def _rerender(calls):
    """The fake render of tests/cli, replacing the folder as ``--overwrite`` does."""
    import shutil

    from tests.cli.test_faults import _fake_render

    render = _fake_render(calls)

    def again(scene, job, out, overwrite=False):
        shutil.rmtree(out / job.name, ignore_errors=True)
        render(scene, job, out)

    return again


def test_a_grid_polar_angle_of_90_is_refused_when_the_spec_is_read(tmp_path):
    """``polar_deg = [0.0, 90.0]`` passed the spec check [0, 90], then every press at 90 failed to render
    ("off the dome"). A random range may end at 90: its draws lie below its high end."""
    grid = _write(tmp_path, '[grid]\nindenters = [{ kind = "sphere" }]\npolar_deg = [0.0, 90.0]\n')
    with pytest.raises(ConfigError, match=r"grid: polar_deg: must be in \[0, 90\) deg.*got 90\.0"):
        load_dataset_spec(grid)
    spec, _ = load_dataset_spec(_write(tmp_path, GRID.replace("[0.0, 20.0]", "[0.0, 89.5]")))
    assert spec.grid.polar_deg == (0.0, 89.5)
    spec, _ = load_dataset_spec(
        _write(tmp_path, '[random]\ncount = 4\nindenters = [{ kind = "sphere" }]\npolar_deg = [0.0, 90.0]\n')
    )
    assert all(0 <= j.press.polar_deg < 90 for j in expand_jobs(spec) if j.press is not None)
    stuck = '[random]\ncount = 1\nindenters = [{ kind = "sphere" }]\npolar_deg = [90.0, 90.0]\n'
    with pytest.raises(ConfigError, match=r"random: polar_deg: must be in \[0, 90\) deg"):
        load_dataset_spec(_write(tmp_path, stuck))


def test_press_folders_a_shorter_spec_no_longer_names_are_warned_about(tmp_path, caplog):
    """A spec shortened (an indenter dropped, `reference = false`) left the old folders in place, unsaid, and
    `nlips solve` / `calibrate` on the folder still took them as part of the dataset."""
    from types import SimpleNamespace

    from nlipscalib.sim.dataset import warn_unlisted

    for name in ("press_0001", "press_0003", "reference", "notes"):
        (tmp_path / name).mkdir()
        if name != "notes":
            (tmp_path / name / "meta.json").write_text("{}", encoding="utf-8")
    jobs = [SimpleNamespace(name="press_0001"), SimpleNamespace(name="press_0002")]
    assert warn_unlisted(jobs, tmp_path) == ["press_0003", "reference"]
    assert "press_0003, reference are not in this spec" in caplog.text
    caplog.clear()
    assert warn_unlisted([*jobs, SimpleNamespace(name="reference")], tmp_path) == ["press_0003"]
    assert (
        "press_0003 is not in this spec (left from an earlier one); later commands on the folder still use it: "
        "remove it," in caplog.text
    )  # one folder: "is", "it" ("press_0003 are not ...; remove them" was the line)


def _publish_as_another_run(scene, job, out):
    """A press folder as a run of ``scene``'s spec publishes it (meta.json records its spec hash)."""
    (out / job.name).mkdir(parents=True)
    meta = {"provenance": {"spec_hash": render_spec_hash(scene, job.press, job.seed), **render_identity()}}
    (out / job.name / "meta.json").write_text(json.dumps(meta), encoding="utf-8")


def test_a_press_another_spec_rendered_meanwhile_is_refused_not_counted_as_there(tmp_path, monkeypatch, capsys):
    """Two `nlips dataset` runs of different specs on one folder at once both exited 0, each counting the other's
    presses as "already there", and left a dataset of mixed specs. A press published by a run of another spec
    after this run's start-up check is now found under its claim and refused with the line a later run gives."""
    from nlipscalib.cli import main
    from tests.cli.test_faults import _fake_render

    spec = _write(tmp_path, GRID)
    other_spec = tmp_path / "other.toml"
    other_spec.write_text(GRID.replace("spp = 2", "spp = 3"), encoding="utf-8")
    other_scene = load_dataset_spec(other_spec)[1]
    other_job = expand_jobs(load_dataset_spec(other_spec)[0])[2]
    out, calls, checks = tmp_path / "out", [], []
    check = ds.check_existing

    def checked_then_the_other_run_publishes(scene, jobs, folder, overwrite):
        check(scene, jobs, folder, overwrite)
        checks.append(folder)
        if len(checks) == 2:  # just after the start-up checks (the command's, run_dataset's), before any claim
            _publish_as_another_run(other_scene, other_job, out)

    monkeypatch.setattr(ds, "check_existing", checked_then_the_other_run_publishes)  # the command's
    monkeypatch.setattr(dataset_pool, "check_existing", checked_then_the_other_run_publishes)  # run_dataset's
    monkeypatch.setattr(dataset_pool, "_run_one", _fake_render(calls))
    args = ["--no-progress", "dataset", str(spec), "--out", str(out), "--workers", "1", "--limit", "2"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"nlips dataset: error: {out}: press_0002 were rendered from a different scene or spec; render into a new "
        "folder, or use --overwrite to re-render them"
    ], err
    assert calls == ["reference", "press_0001"]  # found under press_0002's claim, not before the run
    calls.clear()
    monkeypatch.setattr(dataset_pool, "_run_one", _rerender(calls))
    assert main([*args, "--overwrite"]) == 0 and calls == ["press_0002"]  # --overwrite renders it again


def _whole_bytes(suffix: str) -> bytes:
    """A small whole file of the format: a 4x4 PNG, or an .npz of one array (the stand-in's press files, which the
    dataset judges by their ends: core.file_checks)."""
    import io

    import cv2

    if suffix == ".png":
        return cv2.imencode(".png", np.zeros((4, 4), np.uint8))[1].tobytes()
    buf = io.BytesIO()
    np.savez_compressed(buf, a=np.arange(64.0))
    return buf.getvalue()


_WHOLE_PNG, _WHOLE_NPZ = _whole_bytes(".png"), _whole_bytes(".npz")


def _whole_render(calls):
    """Stand-in renderer writing every file its meta.json lists (replacing the folder as ``--overwrite`` does)."""
    import shutil

    def render(scene, job, out, overwrite=False):
        calls.append(job.name)
        folder = out / job.name
        if overwrite:
            shutil.rmtree(folder)
        folder.mkdir()
        images = {"dark": "dark.png", "tricolor": "tricolor.png", "leds": ["led_01.png", "led_02.png"]}
        meta = {"images": images, "reference": "reference.npz", "ground_truth": "gt.npz"}
        for name in ["dark.png", "tricolor.png", *images["leds"], "reference.npz", "gt.npz"]:
            (folder / name).write_bytes(_WHOLE_PNG if name.endswith(".png") else _WHOLE_NPZ)
        meta["provenance"] = {"spec_hash": render_spec_hash(scene, job.press, job.seed), **render_identity()}
        (folder / "meta.json").write_text(json.dumps(meta), encoding="utf-8")

    return render


def test_a_press_that_lost_a_file_is_rendered_again_not_counted_as_there(tmp_path, monkeypatch, capsys, caplog):
    """A press with an image or reference.npz deleted was "already there" (only meta.json and the spec hash were
    looked at), and every solve of the dataset then failed on it. Now it is rendered again, as `nlips capture`
    captures such a press again."""
    from nlipscalib.cli import main

    spec, out, calls = _write(tmp_path, GRID), tmp_path / "out", []
    monkeypatch.setattr(dataset_pool, "_run_one", _whole_render(calls))
    args = ["--no-progress", "dataset", str(spec), "--out", str(out), "--workers", "1", "--limit", "2"]
    assert main(args) == 0 and calls == ["reference", "press_0001", "press_0002"]
    (out / "press_0001" / "led_02.png").unlink()
    (out / "reference" / "reference.npz").unlink()
    calls.clear()
    capsys.readouterr()
    assert main(args) == 0
    assert calls == ["reference", "press_0001"]
    said = capsys.readouterr()  # stdout: the folder alone; its counts on stderr
    counts = f"{out}: 1 press and the undeformed reference rendered, 1 press already there, 0 failed"
    assert said.out == f"{out}\n" and counts in said.err.splitlines()
    assert "led_02.png missing; rendering it again" in caplog.text
    assert not [p for p in out.rglob("*") if p.name.startswith((".tmp-", ".claim-"))]
    calls.clear()
    assert main(args) == 0 and calls == []  # whole again


def test_a_press_with_a_file_left_empty_is_rendered_again_not_counted_as_there(tmp_path, monkeypatch, capsys, caplog):
    """An empty image or .npz is what a power cut soon after a press was published leaves (the folder renamed into
    place, its files' data not yet on the disk): the press was "already there" at every run, and `nlips solve`
    failed on it ("led_02.png: not a readable PNG image") until its folder was deleted by hand. Now it is rendered
    again, as a press that lost a file is; the warning says which file is empty."""
    from nlipscalib.cli import main

    spec, out, calls = _write(tmp_path, GRID), tmp_path / "out", []
    monkeypatch.setattr(dataset_pool, "_run_one", _whole_render(calls))
    args = ["--no-progress", "dataset", str(spec), "--out", str(out), "--workers", "1", "--limit", "2"]
    assert main(args) == 0
    (out / "press_0002" / "led_02.png").write_bytes(b"")
    (out / "press_0002" / "gt.npz").write_bytes(b"")
    calls.clear()
    capsys.readouterr()
    assert main(args) == 0
    assert calls == ["press_0002"]
    said = capsys.readouterr()  # stdout: the folder alone; its counts on stderr
    counts = f"{out}: 1 press rendered, 1 press and the undeformed reference already there, 0 failed"
    assert said.out == f"{out}\n" and counts in said.err.splitlines()
    assert "press_0002: led_02.png empty, gt.npz empty; rendering it again" in caplog.text
    assert (out / "press_0002" / "led_02.png").stat().st_size > 0
    calls.clear()
    assert main(args) == 0 and calls == []  # whole again


def test_a_press_with_a_file_cut_short_is_rendered_again_not_counted_as_there(tmp_path, monkeypatch, capsys, caplog):
    """A power cut can leave a published file cut short rather than empty (part of its data on the disk): the
    press was "already there" at every run, as an empty file's was before. Now its ends are read (a PNG's IEND
    chunk, an .npz's end-of-central-directory record: core.file_checks) and it is rendered again."""
    from nlipscalib.cli import main

    spec, out, calls = _write(tmp_path, GRID), tmp_path / "out", []
    monkeypatch.setattr(dataset_pool, "_run_one", _whole_render(calls))
    args = ["--no-progress", "dataset", str(spec), "--out", str(out), "--workers", "1", "--limit", "2"]
    assert main(args) == 0
    for name in ("led_01.png", "reference.npz"):
        path = out / "press_0001" / name
        path.write_bytes(path.read_bytes()[: path.stat().st_size * 2 // 3])
    calls.clear()
    capsys.readouterr()
    assert main(args) == 0
    assert calls == ["press_0001"]
    said = capsys.readouterr()  # stdout: the folder alone; its counts on stderr
    counts = f"{out}: 1 press rendered, 1 press and the undeformed reference already there, 0 failed"
    assert said.out == f"{out}\n" and counts in said.err.splitlines()
    said = "press_0001: led_01.png cut short (no PNG end chunk), reference.npz cut short (no zip end record)"
    assert f"{said}; rendering it again" in caplog.text
    calls.clear()
    assert main(args) == 0 and calls == []  # whole again


def test_a_press_whose_meta_json_is_cut_short_is_rendered_again_when_the_dataset_lists_it(
    tmp_path, monkeypatch, capsys, caplog
):
    """A power cut can leave a press's meta.json cut short (published, not synced): `nlips dataset` stopped with "the
    press folder is damaged: delete it to render it again, or use --overwrite". The folder is the dataset's own
    render (dataset.json lists the press with this spec): it is rendered again, as a torn image is. A folder the
    record does not vouch for (no dataset.json) is still refused: it may hold anything."""
    from nlipscalib.cli import main

    spec, out, calls = _write(tmp_path, GRID), tmp_path / "out", []
    monkeypatch.setattr(dataset_pool, "_run_one", _whole_render(calls))
    args = ["--no-progress", "dataset", str(spec), "--out", str(out), "--workers", "1", "--limit", "2"]
    assert main(args) == 0
    meta = out / "press_0001" / "meta.json"
    whole = meta.read_bytes()
    meta.write_bytes(whole[: len(whole) // 2])
    calls.clear()
    capsys.readouterr()
    assert main(args) == 0
    assert calls == ["press_0001"] and meta.read_bytes() == whole
    said = capsys.readouterr()  # stdout: the folder alone; its counts on stderr
    counts = f"{out}: 1 press rendered, 1 press and the undeformed reference already there, 0 failed"
    assert said.out == f"{out}\n" and counts in said.err.splitlines()
    assert "press_0001: meta.json damaged (not valid JSON" in caplog.text and "rendering it again" in caplog.text
    calls.clear()
    assert main(args) == 0 and calls == []  # whole again
    reference = out / "reference" / "meta.json"
    reference.write_bytes(b"")  # the reference (no press) alike
    assert main(args) == 0 and calls == ["reference"] and json.loads(reference.read_bytes())
    calls.clear()

    meta.write_bytes(b"")  # emptied, and the dataset's record lost too: not known to be the dataset's own
    (out / "dataset.json").unlink()
    capsys.readouterr()
    assert main(args) == 2 and calls == []
    err = capsys.readouterr().err
    assert f"{meta}: not valid JSON" in err and "the press folder is damaged" in err and "Traceback" not in err


def _checksummed_render(calls):
    """The stand-in renderer, each press with its checksums.json as core.capture.write_press writes it."""
    from nlipscalib.core.press_checksums import write_checksums
    from nlipscalib.core.press_meta import listed_files

    whole = _whole_render(calls)

    def render(scene, job, out, overwrite=False):
        whole(scene, job, out, overwrite)
        folder = out / job.name
        write_checksums(folder, listed_files(json.loads((folder / "meta.json").read_bytes())))

    return render


def _flip_inside_member(path):
    """One byte of the first member's deflated data in the .npz at ``path`` changed: the archive keeps its size,
    its ends and its directory (a bad disk block, a bad copy); only the member's inflating or CRC-32 tells."""
    import zipfile

    with zipfile.ZipFile(path) as archive:
        info = archive.infolist()[0]
    data = bytearray(path.read_bytes())
    name_length, extra_length = (
        int.from_bytes(data[info.header_offset + at : info.header_offset + at + 2], "little") for at in (26, 28)
    )
    start = info.header_offset + 30 + name_length + extra_length
    data[start + info.compress_size // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def _other_whole_png() -> bytes:
    """A whole PNG of another size than the stand-in's: another press's image copied over one."""
    import cv2

    return cv2.imencode(".png", np.full((8, 8), 7, np.uint8))[1].tobytes()


@pytest.mark.parametrize("damage", ["truncated", "deleted", "another image copied over it"])
def test_a_finished_press_whose_file_changed_is_rendered_again_alone_and_named(
    tmp_path, monkeypatch, capsys, caplog, damage
):
    """A rerun judged a finished press by its files' ends only: another whole image copied over one of them (a
    user tidying up, a copy gone wrong) was "already there" at every run, and its press trained or solved on the
    wrong image. Now each file's size is compared with the press's checksums.json: that press alone is rendered
    again, said in one line naming the file; an untouched rerun renders nothing and reads no file's content."""
    from nlipscalib.cli import main
    from nlipscalib.core import press_checksums

    spec, out, calls = _write(tmp_path, GRID), tmp_path / "out", []
    monkeypatch.setattr(dataset_pool, "_run_one", _checksummed_render(calls))
    args = ["--no-progress", "dataset", str(spec), "--out", str(out), "--workers", "1", "--limit", "3"]
    assert main(args) == 0 and calls == ["reference", "press_0001", "press_0002", "press_0003"]
    path = out / "press_0002" / "led_01.png"
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:-20])
        said = "led_01.png cut short (no PNG end chunk)"
    elif damage == "deleted":
        path.unlink()
        said = "led_01.png missing"
    else:
        path.write_bytes(_other_whole_png())
        said = f"led_01.png changed since it was written ({len(_other_whole_png())} bytes, checksums.json records "
        said += f"{len(_WHOLE_PNG)})"
    calls.clear()
    capsys.readouterr()
    read, crc32 = [], press_checksums.file_crc32  # the files whose every byte is read
    monkeypatch.setattr(press_checksums, "file_crc32", lambda p: read.append(p) or crc32(p))
    monkeypatch.setattr(press_checksums, "damage_inside", lambda p: pytest.fail(f"{p} read without --verify"))
    assert main(args) == 0 and calls == ["press_0002"]
    assert f"{out / 'press_0002'}: {said}; rendering it again" in caplog.text
    counts = f"{out}: 1 press rendered, 2 presses and the undeformed reference already there, 0 failed"
    assert counts in capsys.readouterr().err.splitlines()
    assert read and {p.parent.name for p in read} == {"press_0002"}  # its new record written, nothing else read
    calls.clear()
    read.clear()
    assert main(args) == 0 and calls == [] and read == []  # whole again: nothing rendered, no content read


def test_a_file_changed_inside_at_its_size_is_rendered_again_with_verify(tmp_path, monkeypatch, capsys, caplog):
    """A bad disk block or copy inside a file keeps its size and its ends: a rerun keeps the press (it reads no
    image), ``--verify`` compares every file's CRC-32 with the press's checksums.json and renders that press
    again. A press without the record (an older nlipscalib's) is verified by its formats' own checksums."""
    from nlipscalib.cli import main

    spec, out, calls = _write(tmp_path, GRID), tmp_path / "out", []
    monkeypatch.setattr(dataset_pool, "_run_one", _checksummed_render(calls))
    args = ["--no-progress", "dataset", str(spec), "--out", str(out), "--workers", "1", "--limit", "2"]
    assert main(args) == 0
    for press in ("press_0001", "press_0002"):
        _flip_inside_member(out / press / "gt.npz")
    (out / "press_0001" / "checksums.json").unlink()  # as an older nlipscalib wrote it
    calls.clear()
    assert main(args) == 0 and calls == []
    assert main([*args, "--verify"]) == 0 and calls == ["press_0001", "press_0002"]
    assert "press_0001: gt.npz damaged inside (member a.npy: " in caplog.text
    said = "gt.npz changed since it was written (its CRC-32 is not the one checksums.json records)"
    assert f"press_0002: {said}; rendering it again" in caplog.text
    calls.clear()
    capsys.readouterr()
    assert main([*args, "--verify"]) == 0 and calls == []
    # the summary says the presses kept (and the reference) were read whole (it was a plain rerun's line)
    checked = "already there (every file read, its CRC-32 checked), 0 failed"
    assert f"{out}: 0 rendered, 2 presses and the undeformed reference {checked}" in capsys.readouterr().err


def test_a_press_that_lost_a_file_while_a_solve_works_in_it_is_left_alone(tmp_path, monkeypatch, capsys, caplog):
    """Rendering it again swapped the whole folder away under a running `nlips solve` (its result went with it,
    said by nothing but "led_02.png missing"): now the press waits for the next run, like an incomplete one."""
    from nlipscalib.cli import main
    from nlipscalib.core.claims import claim

    spec, out, calls = _write(tmp_path, GRID), tmp_path / "out", []
    monkeypatch.setattr(dataset_pool, "_run_one", _whole_render(calls))
    args = ["--no-progress", "dataset", str(spec), "--out", str(out), "--workers", "1", "--limit", "2"]
    assert main(args) == 0
    (out / "press_0001" / "led_02.png").unlink()
    (out / "press_0001" / "nlips").mkdir()  # a result of an earlier solve
    calls.clear()
    with claim(out / "press_0001" / "nlips") as mine:  # a solve at work in it (this process stands for it)
        assert mine
        assert main(args) == 1
    said = capsys.readouterr()
    assert calls == [] and "led_02.png missing, but process" in said.out + said.err + caplog.text
    assert main(args) == 0 and calls == ["press_0001"]
    assert "(its results nlips/ go with it)" in caplog.text


def test_a_live_run_of_another_spec_keeps_the_folder_even_from_overwrite_and_a_killed_one_does_not(
    tmp_path, monkeypatch, capsys
):
    """Runs of different specs at work in one folder at once each published presses and left a dataset of two
    specs. A run now claims the folder for its spec first: another spec's run is refused before it writes
    anything (``--overwrite`` too: it re-renders what a finished run left, it does not race a live one); the claim
    of a killed run does not count."""
    import subprocess
    import sys

    from nlipscalib.cli import main
    from nlipscalib.core.claims import HOST, claim_shared
    from tests.cli.test_faults import _fake_render

    spec, out, calls = _write(tmp_path, GRID), tmp_path / "out", []
    monkeypatch.setattr(dataset_pool, "_run_one", _fake_render(calls))
    args = ["--no-progress", "dataset", str(spec), "--out", str(out), "--workers", "1", "--limit", "1"]
    with claim_shared(out / ds.FOLDER_CLAIM, "0123456789abcdef") as other:  # this process stands for the other run
        assert other is None
        for extra in ([], ["--overwrite"]):
            assert main([*args, *extra]) == 2
            err = capsys.readouterr().err.strip().splitlines()
            assert err == [
                f"nlips dataset: error: {out}: a run of a different spec is rendering into it (process {os.getpid()} "
                f"on {HOST}); wait until it ends, or render into a new folder"
            ], err
    assert calls == [] and [p.name for p in out.iterdir()] == []  # nothing written, not even dataset.json
    killed = subprocess.Popen([sys.executable, "-c", "pass"])
    killed.wait(30)
    stale = out / ".claim-dataset~0123456789abcdef~0011223344556677"
    stale.write_text(json.dumps({"host": HOST, "pid": killed.pid, "token": "x"}), encoding="utf-8")
    assert main(args) == 0 and calls == ["reference", "press_0001"]
    assert sorted(p.name for p in out.iterdir()) == ["dataset.json", "press_0001", "reference"]  # its claim swept


def test_presses_are_numbered_from_1_as_a_capture_session_s_and_an_old_folder_keeps_its_numbering(
    tmp_path, monkeypatch, capsys
):
    """`nlips dataset` named its presses press_0000, ... while `nlips capture` starts at press_0001 (and LEDs count
    from 1): a dataset now starts at press_0001 too. A folder rendered from press_0000 (an older nlips) resumes under
    its own names: numbered afresh, its every press would be refused as rendered from another spec."""
    from nlipscalib.cli import main

    spec, calls = _write(tmp_path, GRID), []
    monkeypatch.setattr(dataset_pool, "_run_one", _whole_render(calls))
    new, old = tmp_path / "new", tmp_path / "old"
    args = ["--no-progress", "dataset", str(spec), "--workers", "1", "--limit", "2", "--out"]
    assert main([*args, str(new)]) == 0 and calls == ["reference", "press_0001", "press_0002"]
    assert [j.name for j in expand_jobs(load_dataset_spec(spec)[0])][:3] == ["reference", "press_0001", "press_0002"]

    spec_, scene = load_dataset_spec(spec)
    old.mkdir()
    for job in ds.limit_presses(expand_jobs(spec_, first=0), 2):  # what an older nlips rendered
        _whole_render([])(scene, job, old)
    calls.clear()
    capsys.readouterr()
    assert main([*args, str(old), "--limit", "3"]) == 0 and calls == ["press_0002"]  # its third press, old name
    said = capsys.readouterr()  # stdout: the folder alone; its counts on stderr
    counts = f"{old}: 1 press rendered, 2 presses and the undeformed reference already there, 0 failed"
    assert said.out == f"{old}\n" and counts in said.err.splitlines()
    assert ds.first_press_number(old) == 0 and ds.first_press_number(new) == 1
    names = sorted(p.name for p in old.iterdir() if p.is_dir())
    assert names == ["press_0000", "press_0001", "press_0002", "reference"]


def test_a_dataset_into_a_press_folder_is_refused_before_anything_is_written(tmp_path, monkeypatch, capsys):
    """`nlips dataset SPEC --out out/press` (a press folder) rendered its reference/ and presses among the press's
    images, exit 0; so did `nlips demo --out` and `nlips capture --out` there (an emulated session of 10 presses).
    Now one line naming the folder, exit 2, nothing written."""
    from nlipscalib.cli import main

    spec, calls = _write(tmp_path, GRID), []
    monkeypatch.setattr(dataset_pool, "_run_one", _whole_render(calls))
    press = tmp_path / "press"
    press.mkdir()
    (press / "meta.json").write_text("{}", encoding="utf-8")
    for out, command in [(press, ["dataset", str(spec)]), (press / "sub", ["dataset", str(spec)]), (press, ["demo"])]:
        capsys.readouterr()
        assert main(["--no-progress", *command, "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert "is a press folder" in err and str(press) in err and len(err.splitlines()) == 1, err
    assert calls == [] and sorted(p.name for p in press.iterdir()) == ["meta.json"]
    assert main(["capture", "--emulate", "nlipstac", "--out", str(press), "--yes"]) == 2  # a session alike
    err = capsys.readouterr().err.strip()
    assert err.endswith("is a press folder (it has meta.json); capture the session into another folder"), err


def test_the_default_render_workers_are_as_many_as_memory_holds(tmp_path, monkeypatch, caplog):
    """An 8-core PC renders on 4 processes by default; with 1 GB available only one fits (a render: ~0.9 GB at
    640x480), said in one INFO line, and the renders run in this process."""
    from nlipscalib.core import cpus

    spec, scene = load_dataset_spec(_write(tmp_path, GRID))
    jobs = expand_jobs(spec)[:2]
    calls = []

    def fake_render(scene, job, out, overwrite=False):
        calls.append(job.name)
        (out / job.name).mkdir()
        meta = {"provenance": {"spec_hash": render_spec_hash(scene, job.press, job.seed), **render_identity()}}
        (out / job.name / "meta.json").write_text(json.dumps(meta), encoding="utf-8")

    monkeypatch.setattr(dataset_pool, "_run_one", fake_render)
    monkeypatch.setattr(dataset_pool, "usable_cores", lambda: 8)
    monkeypatch.setattr(cpus, "available_memory", lambda: 10**9)
    caplog.set_level(logging.INFO, logger="nlipscalib.core.cpus")
    result = run_dataset(scene, jobs, tmp_path / "out", workers=0, progress=False)
    assert sorted(result["rendered"]) == sorted(calls) and len(calls) == 2  # in this process: the stand-in ran here
    assert "1 worker instead of 4: each render worker" in caplog.text and "--workers N overrides" in caplog.text


@pytest.mark.parametrize("indenter", [None, "coin"])
def test_the_space_a_press_is_counted_for_follows_what_a_render_writes(indenter, tmp_path):
    """`nlips dataset`'s up-front check counted a 160x120 press as 2437 KiB (uncompressed images), where one takes
    1.62-1.67 MB: it refused a run with 2188 KiB free that had room for a press. The estimate now follows the files
    a render writes, with a margin for busier images, and is at most 25 % above them."""
    pytest.importorskip("mitsuba")
    from nlipscalib.sim.indent import PressConfig
    from nlipscalib.sim.indenters import IndenterConfig
    from nlipscalib.sim.press import render_press
    from nlipscalib.sim.scene import SceneConfig

    scene = SceneConfig().replace(camera={"width": 80, "height": 60}, render={"spp": 2, "bounces": 0, "threads": 2})
    press = None if indenter is None else PressConfig(indenter=IndenterConfig(kind=indenter, size=8.0), depth=1.0)
    folder = render_press(scene, press, tmp_path / "press", seed=1)
    on_disk = sum(f.stat().st_blocks * 512 for f in folder.iterdir())  # whole blocks, as the free space counts
    estimate = dataset_pool.press_bytes(scene)
    assert on_disk <= estimate <= 1.25 * on_disk, (on_disk, estimate)


def _as_an_older_nlipscalib_rendered(scene, job, out, drop=("denoise", "denoise_indirect")):
    """A press folder as a render of an older nlipscalib left it: its provenance records the scene, press and seed
    (no spec_hash: recomputed from them), without render settings added since and without code or libraries."""
    from nlipscalib.core.config import to_mapping

    scene_dict = scene.to_dict()
    scene_dict["render"] = {k: v for k, v in scene_dict["render"].items() if k not in drop}
    press = None if job.press is None else to_mapping(job.press)
    (out / job.name).mkdir(parents=True)
    meta = {"provenance": {"source": "sim", "scene": scene_dict, "press": press, "seed": job.seed}}
    (out / job.name / "meta.json").write_text(json.dumps(meta), encoding="utf-8")


def test_a_dataset_an_older_nlipscalib_rendered_is_refused_naming_the_settings_added_since(tmp_path, capsys):
    """After an upgrade, `nlips dataset` on a folder of 2026-11-23 (754bd8b) refused it as "rendered from a different
    scene or spec" while the user had changed neither: the scene had gained render.denoise since. The line now names
    the settings that differ and that the record lacks them."""
    from nlipscalib.cli import main

    spec_file = _write(tmp_path, GRID)
    spec, scene = load_dataset_spec(spec_file)
    out = tmp_path / "out"
    for job in expand_jobs(spec)[:2]:
        _as_an_older_nlipscalib_rendered(scene, job, out)
    assert main(["--no-progress", "dataset", str(spec_file), "--out", str(out), "--limit", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "rendered from a different scene or spec (reference: scene.render.denoise: None" in err[0]
    assert "scene.render.denoise_indirect: None -> True" in err[0], err
    assert "settings its record lacks: an older nlipscalib rendered it" in err[0] and "--overwrite" in err[0]


def test_a_dataset_of_another_spec_is_refused_naming_what_differs(tmp_path):
    """A folder of another spec (not an older nlipscalib's) is named with the setting that differs, not as older."""
    spec, scene = load_dataset_spec(_write(tmp_path, GRID))
    other = load_dataset_spec(_write(tmp_path, GRID.replace("spp = 2", "spp = 3")))[1]
    jobs = expand_jobs(spec)[:2]
    out = tmp_path / "out"
    _as_an_older_nlipscalib_rendered(other, jobs[1], out, drop=())
    with pytest.raises(ConfigError, match=r"\(press_0001: scene\.render\.spp: 3 -> 2\); render into a new folder"):
        ds.check_existing(scene, jobs, out, overwrite=False)


def test_presses_other_twin_code_rendered_are_warned_of_once_a_command(tmp_path, monkeypatch, caplog):
    """`nlips dataset` checks the folder before writing its manifest and again as the renders start: the warning
    of presses an older twin rendered came twice in one command."""
    from nlipscalib.cli import main
    from tests.cli.test_faults import _fake_render

    spec_file = _write(tmp_path, GRID)
    spec, scene = load_dataset_spec(spec_file)
    out = tmp_path / "out"
    for job in expand_jobs(spec)[:2]:
        _as_an_older_nlipscalib_rendered(scene, job, out, drop=())
    monkeypatch.setattr(dataset_pool, "_run_one", _fake_render([]))
    with caplog.at_level("WARNING", logger="nlipscalib.sim"):
        assert main(["--no-progress", "dataset", str(spec_file), "--out", str(out), "--limit", "2"]) == 0
    warned = [r.getMessage() for r in caplog.records if "rendered by other twin code" in r.getMessage()]
    assert len(warned) == 1 and "reference, press_0001" in warned[0], warned


@pytest.mark.parametrize("overwrite", [False, True], ids=["plain", "overwrite"])
def test_a_press_captured_on_a_sensor_is_never_rendered_over(tmp_path, overwrite):
    """`nlips dataset SPEC --out SESSION` onto `nlips capture`'s session: its presses were "rendered from a different
    scene or spec (...: an older nlipscalib rendered it)", and --overwrite rendered over the captured presses."""
    spec, scene = load_dataset_spec(_write(tmp_path, GRID))
    jobs = expand_jobs(spec)[:2]
    out = tmp_path / "session"
    (out / jobs[1].name).mkdir(parents=True)
    (out / jobs[1].name / "meta.json").write_text(json.dumps({"provenance": {"source": "device"}}), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"press_0001: a press captured on a sensor .*even with --overwrite"):
        ds.check_existing(scene, jobs, out, overwrite=overwrite)
