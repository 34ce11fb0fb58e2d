"""Disk faults on output: one clear line naming the path and the cause, exit != 0, nothing half-written.

Runs as root in CI, where chmod does not stop writes: read-only and permission faults are made by
patching os.mkdir (the first write of every command), a full disk by a real small tmpfs when this
process may mount one, else by a writer that fails on the second press.
"""

from __future__ import annotations

import errno
import os
import subprocess
import types
import uuid
from pathlib import Path

import pytest

from nlipscalib.cli import main
from nlipscalib.core.capture import load_press
from nlipscalib.sim import dataset_pool
from tests.specs import TINY_SPEC as SPEC


@pytest.fixture
def spec(tmp_path) -> Path:
    path = tmp_path / "spec.toml"
    path.write_text(SPEC, encoding="utf-8")
    return path


def _one_line_error(err: str, *needles: str) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], lines[0]


def _fake_render(calls, fail_at=None, error=errno.ENOSPC):
    """Stand-in renderer writing a valid-looking press; raises an OSError on the ``fail_at``-th call."""
    import json

    from nlipscalib.sim.press import render_identity, render_spec_hash

    def render(scene, job, out, overwrite=False):
        calls.append(job.name)
        if len(calls) == fail_at:
            raise OSError(error, os.strerror(error), str(out / job.name / "led_03.png"))
        (out / job.name).mkdir()
        provenance = {"spec_hash": render_spec_hash(scene, job.press, job.seed), **render_identity()}
        meta = json.dumps({"provenance": provenance})
        (out / job.name / "meta.json").write_text(meta, encoding="utf-8")

    return render


@pytest.mark.parametrize(
    "code,cause",
    [
        (errno.EROFS, "Read-only file system"),
        (errno.EACCES, "Permission denied"),
        (errno.ENOSPC, "No space left on device"),
    ],
)
def test_unwritable_output_fails_before_any_render(spec, tmp_path, monkeypatch, capsys, code, cause):
    out = tmp_path / "out"
    calls = []
    monkeypatch.setattr(dataset_pool, "_run_one", _fake_render(calls))
    real_mkdir = os.mkdir

    def mkdir(path, *args, **kwargs):
        if str(path).startswith(str(out)):
            raise OSError(code, os.strerror(code), str(path))
        return real_mkdir(path, *args, **kwargs)

    monkeypatch.setattr(os, "mkdir", mkdir)
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 2
    _one_line_error(capsys.readouterr().err, str(out), cause)
    assert calls == []  # checked before the long work


def test_disk_full_mid_run_stops_at_first_failure(spec, tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    calls = []
    monkeypatch.setattr(dataset_pool, "_run_one", _fake_render(calls, fail_at=2))
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 2
    _one_line_error(capsys.readouterr().err, "led_03.png", "No space left on device", "disk is full")
    assert len(calls) == 2  # the rest is not rendered only to fail writing
    assert not list(out.glob(".tmp-*")) and not list(out.glob(".claim-*"))


def test_name_too_long_is_one_line(spec, tmp_path, capsys):
    out = tmp_path / ("x" * 300)
    assert main(["dataset", str(spec), "--out", str(out)]) == 2
    _one_line_error(capsys.readouterr().err, "File name too long")


def _read_only_under(monkeypatch, root: Path) -> None:
    """os.mkdir refuses every folder at or under ``root`` as a read-only mount does (EROFS)."""
    real_mkdir = os.mkdir

    def mkdir(path, *args, **kwargs):
        if Path(path) == root or root in Path(path).parents:
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
        return real_mkdir(path, *args, **kwargs)

    monkeypatch.setattr(os, "mkdir", mkdir)


@pytest.mark.parametrize("stream", ["infer frames", "infer sequence", "live"])
def test_infer_and_live_refuse_a_read_only_out_before_loading_the_model(tmp_path, monkeypatch, capsys, stream):
    """`nlips infer MODEL FRAMES --out RO` loaded its model and read a frame before its first result folder found
    the disk read-only, naming that folder (RO/f0); a stream (`nlips infer MODEL 'f%d.png' --out RO`, `nlips live
    --camera FRAMES --out RO`) inferred and showed its first frame first. Now one line naming --out, exit 2, no
    model loaded, nothing made."""
    import numpy as np

    from nlipscalib.cli import _stream
    from nlipscalib.core.imageio import write_png16

    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(2):
        write_png16(frames / f"f{i}.png", np.full((12, 16, 3), 20000, np.uint16))
    model = tmp_path / "net.pt"
    model.write_bytes(b"never read: refused before it loads")
    monkeypatch.setattr(_stream, "nlipsnet_predictor", lambda *a, **k: pytest.fail("the model was loaded"))
    ro = tmp_path / "ro"
    ro.mkdir()
    _read_only_under(monkeypatch, ro)
    out = ro / "results"
    argv = {
        "infer frames": ["infer", str(model), str(frames), "--out", str(out)],
        "infer sequence": ["infer", str(model), str(frames / "f%d.png"), "--out", str(out)],
        "live": ["live", "--model", str(model), "--camera", str(frames), "--out", str(out), "--no-window"],
    }[stream]
    assert main(["--no-progress", *argv]) == 2
    _one_line_error(capsys.readouterr().err, f"{out}: Read-only file system (choose a writable output folder)")
    assert not out.exists()


def test_a_finished_infer_on_read_only_media_is_still_rechecked(tmp_path, monkeypatch, capsys):
    """The writability probe skips results a re-run may keep: `nlips infer` of finished results on read-only media
    says them kept, as before (its model is not loaded: the results are its)."""
    from nlipscalib.cli import infer

    out = tmp_path / "results"
    (out / "f0").mkdir(parents=True)
    looked = {out / "f0": ({}, True)}
    args = types.SimpleNamespace(out=str(out))
    _read_only_under(monkeypatch, tmp_path)
    infer._check_writable(args, [(out / "f0", False)], looked)  # kept: not probed
    with pytest.raises(OSError, match="Read-only"):
        infer._check_writable(args, [(out / "f0", False), (out / "f1", False)], looked)  # f1 to write


# ---------------------------------------------------------------------- real file systems
@pytest.fixture
def tmpfs(tmp_path):
    """A small tmpfs (when this process may mount one): real ENOSPC and EROFS."""
    mnt = tmp_path / f"mnt-{uuid.uuid4().hex[:6]}"
    mnt.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=160k", "tmpfs", str(mnt)]).returncode:
        pytest.skip("cannot mount a tmpfs here (the patched-writer tests cover the logic)")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], check=False)


def _remount(mnt: Path, *opts: str) -> None:
    subprocess.run(["mount", "-o", ",".join(("remount", *opts)), str(mnt)], check=True)


def test_real_full_disk_and_read_only_recheck(spec, tmpfs, capsys):
    pytest.importorskip("mitsuba")
    out = tmpfs / "out"
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 2
    _one_line_error(capsys.readouterr().err, str(out), "No space left on device")
    done = [p for p in out.iterdir() if not p.name.startswith(".") and p.is_dir()]
    for folder in done:  # whatever was published is whole
        load_press(folder)
    assert len(done) < 5 and not list(out.glob(".tmp-*"))

    _remount(tmpfs, "size=4m")  # room again: the run resumes and finishes
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    # one worker renders the reference first, then the presses in order: the folders published are those first jobs
    presses = f"{5 - len(done)} press{'' if 5 - len(done) == 1 else 'es'}"
    kept = f"{len(done) - 1} press{'' if len(done) == 2 else 'es'} and the undeformed reference"
    counts = f"{presses} rendered, {kept} already there" if done else "4 presses and the undeformed reference rendered"
    assert counts in capsys.readouterr().err

    (out / "dataset.json").unlink()  # even one from before dataset.json existed
    _remount(tmpfs, "ro")  # a finished dataset on read-only media can be re-checked
    assert main(["dataset", str(spec), "--out", str(out), "--no-progress"]) == 0
    assert "0 rendered, 4 presses and the undeformed reference already there, 0 failed" in capsys.readouterr().err


def test_real_read_only_unfinished_dataset(spec, tmpfs, capsys):
    out = tmpfs / "out"
    out.mkdir()
    _remount(tmpfs, "ro")
    assert main(["dataset", str(spec), "--out", str(out), "--no-progress"]) == 2
    _one_line_error(capsys.readouterr().err, str(out), "Read-only file system")


def test_no_room_for_one_press_fails_before_rendering(spec, tmp_path, monkeypatch, capsys, caplog):
    import shutil
    from collections import namedtuple

    from nlipscalib.sim.dataset import load_dataset_spec

    usage = namedtuple("usage", "total used free")
    calls = []
    monkeypatch.setattr(dataset_pool, "_run_one", _fake_render(calls))
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**9, 10**9 - 1000, 1000))
    out = tmp_path / "out"
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 2
    need = dataset_pool.press_bytes(load_dataset_spec(spec)[1])
    _one_line_error(capsys.readouterr().err, str(out), "No space left on device", "(0 KiB free, each of the 5 presses")
    assert calls == []
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**9, 0, 2 * need + 1000))  # room for two of five
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 0
    assert "room for ~2 of the 5 presses" in caplog.text and "the run will stop when the disk is full" in caplog.text


# ---------------------------------------------------------------------- bad input values
@pytest.mark.parametrize(
    "line,problem",
    [
        ("dead_led_level = 1.0", "solver.dead_led_level must be in [0, 1) of full scale, got 1.0"),
        ("prior_weight = inf", "solver.prior_weight must be a finite number, got inf"),
        ("robust_scale = nan", "solver.robust_scale must be a finite number, got nan"),
        ("anchor_threshold = -1", "solver.anchor_threshold must be >= 0, got -1.0"),
        ("line_search_expand = 0.5", "solver.line_search_expand must be 0 (off) or >= 1, got 0.5"),
        ("min_leds = 50", "solver.min_leds = 50 exceeds the 3 LEDs of"),
    ],
)
def test_a_solver_option_out_of_range_in_a_config_file_is_one_line_naming_the_file(tmp_path, capsys, line, problem):
    """``dead_led_level >= 1`` marked every LED dead ("need at least one array to stack" traceback), ``inf``
    weights filled the solve with NaN behind numpy warnings, and ``min_leds = 50`` was refused without
    naming the config file it came from."""
    from tests.core.test_capture import _press

    press = _press(tmp_path / "p")
    config = tmp_path / "c.toml"
    config.write_text(line + "\n", encoding="utf-8")
    assert main(["--no-progress", "solve", str(press), "--config", str(config)]) == 2
    _one_line_error(capsys.readouterr().err, str(config), problem)


def test_a_file_or_a_press_without_meta_json_is_called_what_it_is(tmp_path, capsys):
    """``--reference FILE`` said "not a press folder (no such directory)" of a path that exists; a press folder
    without its meta.json said "no press folders found"."""
    from tests.core.test_capture import _press

    press, reference = _press(tmp_path / "p"), _press(tmp_path / "ref")
    (tmp_path / "f.txt").write_text("x", encoding="utf-8")
    assert main(["--no-progress", "solve", str(press), "--reference", str(tmp_path / "f.txt")]) == 2
    _one_line_error(capsys.readouterr().err, "f.txt: a file, not a press folder")
    (press / "meta.json").unlink()
    for command in (
        ["solve", str(press)],
        ["eval", str(press)],
        ["calibrate", str(press), "--reference", str(reference), "--min-leds", "3"],
    ):
        assert main(["--no-progress", *command]) == 2
        _one_line_error(capsys.readouterr().err, f"{press / 'meta.json'}: missing", "holds press images but no")


def test_a_file_where_the_output_folder_needs_a_folder_is_named_as_such(tmp_path):
    """`--out FILE/sub` said "File exists (use --overwrite to replace it)", which would not help."""
    from nlipscalib.cli import describe_os_error

    blocker = tmp_path / "bfile"
    blocker.write_text("x", encoding="utf-8")
    try:
        blocker.mkdir(parents=True, exist_ok=True)  # what making --out's parent does
    except FileExistsError as exc:
        line = describe_os_error(exc, overwrite_flag=True, where=blocker / "sub")
        itself = describe_os_error(exc, overwrite_flag=True, where=blocker)  # --out FILE itself
    assert line == f"{blocker}: a file where a folder is needed (choose another --out, or move the file)"
    assert itself == line


def test_an_os_error_line_names_a_path_only_when_the_command_has_one():
    # calibrate-leds takes a list of presses and capture --presses a count: Path(list) raised a TypeError (a traceback)
    import argparse

    from nlipscalib.cli import _path_of

    assert _path_of(argparse.Namespace(out=None, presses=["a", "b"])) is None
    assert _path_of(argparse.Namespace(out=None, presses=5)) is None
    assert _path_of(argparse.Namespace(out="res", press="p")) == "res"
    assert _path_of(argparse.Namespace(press="p")) == "p"
