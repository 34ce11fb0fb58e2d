"""The shared solve pipeline: honest re-runs, damaged results, interrupted writes, parallel presses."""

import contextlib
import logging
import shutil
import threading

import numpy as np
import pytest

from nlipscalib.core.errors import ConfigError
from nlipscalib.core.reconstruction import load_reconstruction, read_report
from nlipscalib.pipeline import make_provenance, make_settings, solve_folder, solve_presses
from nlipscalib.solver import SolverOptions
from tests.processes import until_each_waits_or_exits
from tests.solver import synth

FAST = SolverOptions(max_iters=6)


@pytest.fixture(scope="module")
def press_set(tmp_path_factory):
    """Three small exact-data presses (sphere, cube, deeper sphere) and the undeformed dome."""
    root = tmp_path_factory.mktemp("pipeline_presses")
    synth.make_press(root / "a_sphere", "sphere", size=(64, 48))
    synth.make_press(root / "b_cube", "cube", size=(64, 48))
    synth.make_press(root / "c_sphere_deep", "sphere", depth=2.0, size=(64, 48))
    return root


@pytest.fixture
def press(press_set, tmp_path):
    folder = tmp_path / "press"
    shutil.copytree(press_set / "a_sphere", folder)
    return folder


def test_identical_request_skips_and_a_changed_one_re_solves(press, caplog):
    rec, status = solve_folder(press, options=FAST, figures=False)
    assert status == "solved" and rec.reconstructed.any()
    stamp = (press / "nlips" / "result.npz").stat().st_mtime_ns
    again, status = solve_folder(press, options=FAST, figures=False)
    assert status == "skipped" and np.array_equal(again.normals, rec.normals, equal_nan=True)
    assert (press / "nlips" / "result.npz").stat().st_mtime_ns == stamp

    caplog.set_level(logging.INFO)
    _, status = solve_folder(press, options=SolverOptions(max_iters=7), figures=False)
    assert status == "solved" and "(max_iters)" in caplog.text  # the log names the option that changed
    assert read_report(press / "nlips")["provenance"]["settings"]["options"]["max_iters"] == 7
    _, status = solve_folder(press, options=SolverOptions(max_iters=7), roi=(10, 10, 30, 20), figures=False)
    assert status == "solved"
    assert read_report(press / "nlips")["roi"] == [10, 10, 30, 20]
    _, status = solve_folder(press, options=SolverOptions(max_iters=7), roi=(10, 10, 30, 20), overwrite=True)
    assert status == "solved"


def test_an_empty_output_folder_or_a_symlink_to_one_is_solved_into_without_a_warning(press, tmp_path, caplog):
    """`nlips solve PRESS --out DIR` into an empty DIR (or a symlink to one) warned "DIR/result.npz: missing;
    re-computing it", as for a damaged result (s25 walk); the symlink is kept and the result lands in its target."""
    empty, target = tmp_path / "empty", tmp_path / "target"
    empty.mkdir(), target.mkdir()
    (tmp_path / "link").symlink_to(target)
    for out in (empty, tmp_path / "link"):
        caplog.clear()
        _, status = solve_folder(press, options=FAST, figures=False, out=out)
        assert status == "solved" and not [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert (tmp_path / "link").is_symlink() and (target / "result.npz").is_file()


def test_provenance_records_inputs_and_changes_with_them(press_set, tmp_path):
    settings = make_settings(options=FAST, leds="1,2,3,5,7,9")
    a = make_provenance(press_set / "a_sphere", settings)
    assert a["settings"]["led_subset"] == [1, 2, 3, 5, 7, 9] and len(a["inputs"]["press"]) == 64
    assert make_provenance(press_set / "a_sphere", settings)["key"] == a["key"]  # deterministic
    copy = tmp_path / "moved"
    shutil.copytree(press_set / "a_sphere", copy)
    assert make_provenance(copy, settings)["key"] == a["key"]  # identity is content, not place
    assert make_provenance(press_set / "b_cube", settings)["key"] != a["key"]
    with_ref = make_settings(options=FAST, leds="1,2,3,5,7,9", reference=press_set / "b_cube")
    assert make_provenance(press_set / "a_sphere", with_ref)["key"] != a["key"]
    # the defaults of solve_press's keywords count as given: omitting one equals passing its default
    explicit = make_settings(options=FAST, leds="1,2,3,5,7,9", solver_keywords={"dent_interreflection": True})
    assert make_provenance(press_set / "a_sphere", explicit)["key"] == a["key"]
    with pytest.raises(ConfigError, match="unknown solver keywords"):
        make_settings(solver_keywords={"no_such_flag": 1})


def test_identity_notices_an_image_replaced_in_place(press, tmp_path):
    """The identity is cached per process: keyed on meta.json alone, it stayed the old one after an LED image
    was rewritten in place (meta.json untouched), and so did the reference loaded under it (a notebook, or
    ``nlips calibrate`` solving many presses, solved against the old images)."""
    from nlipscalib.pipeline import capture_identity

    before = capture_identity(press)
    meta = (press / "meta.json").stat()
    other = (press / "led_02.png").read_bytes()
    assert len(other) != (press / "led_01.png").stat().st_size  # noticed whatever the file clock's resolution
    with open(press / "led_01.png", "r+b") as f:  # in place: the same file (inode), new content
        f.write(other)
        f.truncate()
    assert (press / "meta.json").stat() == meta
    after = capture_identity(press)
    assert after != before
    shutil.copytree(press, tmp_path / "fresh")  # another folder: hashed anew, not served from the cache
    assert capture_identity(tmp_path / "fresh") == after


def test_an_identity_hashed_in_the_background_is_the_one_a_later_call_gets_without_hashing_again(press, tmp_path):
    """``nlips solve`` hashes the press (and --reference) on a thread while it imports the solver: the later call
    gets that identity, hashed once; a folder that is not a press fails there silently and is reported by the
    call that needs it."""
    from nlipscalib.core.errors import CaptureError
    from nlipscalib.pipeline import capture_identity, provenance

    shutil.copytree(press, tmp_path / "copy")  # a folder this process has not hashed yet
    original = capture_identity(press)
    hashed = provenance._capture_identity_cached.cache_info().misses
    threads_before = set(threading.enumerate())
    provenance.identity_in_background(tmp_path / "copy", None, tmp_path / "nowhere")
    for thread in set(threading.enumerate()) - threads_before:
        thread.join(timeout=30)
    assert provenance._capture_identity_cached.cache_info().misses == hashed + 1
    assert capture_identity(tmp_path / "copy") == original
    assert provenance._capture_identity_cached.cache_info().misses == hashed + 1  # the copy's: not hashed again
    with pytest.raises(CaptureError, match="meta.json: missing"):
        capture_identity(tmp_path / "nowhere")


def test_the_disk_caches_key_salt_is_made_in_the_background_too(tmp_path, monkeypatch):
    """The identity's thread also makes the disk cache's key salt (the package's source read and hashed), which the
    press's load needs next: not on the main thread after the solver's import. With the disk cache off, none."""
    from nlipscalib.core import diskcache
    from nlipscalib.pipeline import provenance

    for cache, made in [(str(tmp_path / "cache"), True), ("off", False)]:
        monkeypatch.setenv(diskcache.ENV_DIR, cache)
        monkeypatch.setattr(diskcache, "_salt", None)
        threads_before = set(threading.enumerate())
        provenance.identity_in_background(None)
        for thread in set(threading.enumerate()) - threads_before:
            thread.join(timeout=30)
        assert (diskcache._salt is not None) is made


def test_a_file_missing_from_a_press_is_named_as_the_folder_was_given(press, tmp_path, monkeypatch):
    """`nlips solve out/cs` said "/tmp/.../out/cs/press_0001/tricolor.png: listed in meta.json but missing": the
    resolved path the identity is cached under, where every other line names the folder as typed."""
    from nlipscalib.core.errors import CaptureError
    from nlipscalib.pipeline import capture_identity

    shutil.copytree(press, tmp_path / "presses" / "p")
    (tmp_path / "presses" / "p" / "tricolor.png").unlink()
    monkeypatch.chdir(tmp_path)
    with pytest.raises(CaptureError) as caught:
        capture_identity("presses/p")
    assert str(caught.value) == "presses/p/tricolor.png: listed in meta.json but missing"


def test_damaged_result_is_recomputed_with_a_warning(press, caplog):
    solve_folder(press, options=FAST, figures=False)
    npz = press / "nlips" / "result.npz"
    npz.write_bytes(npz.read_bytes()[:1000])  # truncated: a killed copy, a full disk
    caplog.set_level(logging.WARNING)
    rec, status = solve_folder(press, options=FAST, figures=False)
    assert status == "solved" and "damaged or truncated" in caplog.text
    assert load_reconstruction(press / "nlips").reconstructed.sum() == rec.reconstructed.sum()


@pytest.mark.parametrize("torn", ["empty", "cut short"])
def test_a_figure_left_empty_or_cut_short_is_drawn_again_without_re_solving(press, caplog, torn):
    """Figures are written atomically but not synced: a power cut soon after a solve can leave depth.png empty or
    cut short beside a whole result, and every run after kept it ("identical result exists, skipped"). Now the
    figures are drawn again (milliseconds) and the result is kept as it was (not solved again)."""
    solve_folder(press, options=FAST)
    out = press / "nlips"
    depth, result = out / "depth.png", out / "result.npz"
    whole, stamp = depth.read_bytes(), result.stat().st_mtime_ns
    depth.write_bytes(b"" if torn == "empty" else whole[: len(whole) // 2])
    caplog.set_level(logging.INFO)
    _, status = solve_folder(press, options=FAST)
    assert status == "skipped" and result.stat().st_mtime_ns == stamp  # the result kept, not solved again
    assert f"depth.png {torn}" in caplog.text and "figures (maps) drawn again, the result kept" in caplog.text
    assert depth.read_bytes() == whole  # the same figure as the solve drew
    caplog.clear()
    assert solve_folder(press, options=FAST)[1] == "skipped" and "drawn again" not in caplog.text


def test_interrupted_writes_are_cleaned_but_not_live_ones(press):
    import os
    import subprocess
    import sys

    from nlipscalib.core.atomic import tmp_prefix
    from nlipscalib.core.claims import HOST

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    killed = press / f".tmp-nlips~{HOST}~{int(dead.stdout)}~abc"  # its writer is gone
    legacy = press / ".tmp-nlips-k2j3"  # an older version's untagged leftover
    live = press / (tmp_prefix("nlips").replace(f"~{os.getpid()}~", "~1~") + "x")  # pid 1 is alive
    for tmp in (killed, legacy, live):
        tmp.mkdir()
        (tmp / "result.npz").write_bytes(b"half")
    solve_folder(press, options=FAST, figures=False)
    assert not killed.exists() and not legacy.exists() and live.exists()
    killed.mkdir()  # also cleaned when the result is reused
    assert solve_folder(press, options=FAST, figures=False)[1] == "skipped"
    assert not killed.exists() and (press / "nlips" / "result.npz").is_file()


def _held_by_another_process(target, until, publish=None):
    """A thread standing for another process (a claim is per process and not re-entrant): it claims
    ``target``, holds it until ``until()`` is true (polled; 60 s at most), moves ``publish`` (a finished result)
    to ``target`` if given, releases. ``until``, e.g. "this process's log says it met the claim", rather than a
    fixed time: a main thread late on a loaded machine found the claim already gone, and the log line the
    test expects was never written."""
    import threading
    import time

    from nlipscalib.core.claims import claim

    holding = threading.Event()

    def other_process():
        with claim(target):
            holding.set()
            deadline = time.monotonic() + 60  # the code under test never met the claim: its asserts say so
            while not until() and time.monotonic() < deadline:
                time.sleep(0.01)
            if publish is not None:
                publish.rename(target)

    thread = threading.Thread(target=other_process)
    thread.start()
    holding.wait()
    return thread


def test_a_press_another_process_holds_is_left_to_it_then_waited_for(press_set, tmp_path, caplog):
    """Two `nlips solve` runs with other settings on one folder: a press the other run held was "skipped"
    with exit 0, and this run's result never existed for it (audit). Now such a press is left to the other
    run while this one solves the rest, then waited for and solved with this run's settings."""
    root = tmp_path / "presses"
    shutil.copytree(press_set / "a_sphere", root / "a")
    shutil.copytree(press_set / "b_cube", root / "b")
    caplog.set_level(logging.INFO)
    left = lambda: "left to it for now" in caplog.text  # noqa: E731
    thread = _held_by_another_process(root / "a" / "nlips", left)  # it fails, or holds other settings' result
    statuses = solve_presses([root / "a", root / "b"], options=FAST, progress=False, figures=False)
    assert statuses == {"a": "solved", "b": "solved"}
    assert "left to it for now" in caplog.text and "waiting for them" in caplog.text
    assert load_reconstruction(root / "a" / "nlips").reconstructed.any()
    thread.join()
    done = threading.Event()
    thread = _held_by_another_process(root / "a" / "nlips", done.is_set)  # held throughout the call
    try:
        assert solve_folder(root / "a", options=FAST, figures=False)[1] == "skipped"  # its identical result reused
    finally:
        done.set()
        thread.join()


def test_two_runs_of_other_settings_on_one_press_one_solves_and_the_other_is_refused(press, tmp_path):
    """Two `nlips solve PRESS` runs with other settings (--roi auto, whole gel) started together: the one that
    found the press held waited, then replaced the other's result ("made with other settings, re-solving"), both
    exit 0, the press keeping whichever finished last. Now the first to hold the press solves it and the other is
    refused in one line naming the press, its output and the other run's settings, exit 2. To make both start
    before either solves, this process holds the press's claim until each run waits for it or has exited."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    from nlipscalib.core.claims import claim

    code = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
    logs = [tmp_path / "auto.log", tmp_path / "whole.log"]
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    procs = []
    with claim(press / "nlips"):
        for log_file, roi in zip(logs, (["--roi", "auto"], [])):
            argv = ["--no-progress", "--log-file", str(log_file), "solve", str(press), *roi, "--no-figures"]
            procs.append(
                subprocess.Popen([sys.executable, "-c", code, *argv], env=env, stderr=subprocess.PIPE, text=True)
            )
        until_each_waits_or_exits(procs, logs, "waiting for it", timeout=120)
    errs = [p.communicate(timeout=300)[1] for p in procs]
    assert sorted(p.returncode for p in procs) == [0, 2], errs
    winner, loser = (0, 1) if procs[0].returncode == 0 else (1, 0)
    lines = [line for line in errs[loser].splitlines() if not line.startswith(("DEBUG ", "INFO "))]
    roi = ("auto", "none")[winner]
    assert len(lines) == 1, errs[loser]
    assert f"{press / 'nlips'}: another run is solving {press} into it with other settings (roi {roi}" in lines[0]
    assert "re-solving" not in _text(logs[loser]) and "reconstructed" not in _text(logs[loser])
    recorded = json.loads((press / "nlips" / "report.json").read_text(encoding="utf-8"))["provenance"]["settings"][
        "roi"
    ]
    assert recorded == ("auto", None)[winner]
    assert not list(press.glob(".claim-*")) and not list(press.glob(".tmp-*"))


def test_a_batch_keeps_its_presses_from_a_run_of_other_settings_until_it_ends(press_set, tmp_path):
    """A press a live run of other settings holds is failed in one line naming it and that run's settings, the
    others solved; the run's presses are held until it ends (a batch reaching them once released replaced them)."""
    from nlipscalib.pipeline.provenance import run_record
    from nlipscalib.pipeline.reuse import _hold

    root = tmp_path / "presses"
    shutil.copytree(press_set / "a_sphere", root / "a")
    shutil.copytree(press_set / "b_cube", root / "b")
    other = run_record(make_settings(roi="auto", options=FAST))
    with _hold(root / "a", root / "a" / "nlips", other):  # another run's hold (claims are per file, not per process)
        statuses = solve_presses([root / "a", root / "b"], roi=None, options=FAST, progress=False, figures=False)
        assert statuses["b"] == "solved" and not (root / "a" / "nlips").exists()
        assert statuses["a"].startswith(f"failed: {root / 'a' / 'nlips'}: another run is solving {root / 'a'} into")
        assert "with other settings (roi auto (this run: none);" in statuses["a"]
        with pytest.raises(ConfigError, match="another run is solving"):
            solve_folder(root / "a", roi=None, options=FAST, figures=False)
        # a run of the same settings shares the press
        assert solve_folder(root / "a", roi="auto", options=FAST, figures=False)[1] == "solved"
    assert solve_presses([root / "a"], roi=None, options=FAST, progress=False, figures=False) == {"a": "solved"}
    assert not list(root.rglob(".claim-*"))


def _text(path) -> str:
    return path.read_text(encoding="utf-8") if path.exists() else ""


def test_figures_off_maps_and_full(press):
    solve_folder(press, options=FAST, figures=False)
    assert not list((press / "nlips").glob("*.png"))
    solve_folder(press, options=FAST, figures=True, overwrite=True)
    names = {p.name for p in (press / "nlips").glob("*.png")}
    assert names == {"normals.png", "depth.png", "residual.png", "error.png"}
    solve_folder(press, options=FAST, figures="full", overwrite=True)
    assert (press / "nlips" / "summary.png").stat().st_size > 5_000
    with pytest.raises(ConfigError, match="figures"):
        solve_folder(press, options=FAST, figures="some")


def test_maps_show_the_solved_box(press, monkeypatch):
    import cv2

    from nlipscalib.core.capture import load_press
    from nlipscalib.report import reconstruction
    from nlipscalib.report.maps import BAR_WIDTH, bar_min_height

    views, depth_view = [], reconstruction.depth_view
    keep = lambda rec, ref, box: views.append(ref) or depth_view(rec, ref, box)  # noqa: E731
    monkeypatch.setattr(reconstruction, "depth_view", keep)
    solve_folder(press, options=FAST, roi=(10, 12, 30, 20))
    depth = cv2.imread(str(press / "nlips" / "depth.png"), cv2.IMREAD_COLOR)
    normals = cv2.imread(str(press / "nlips" / "normals.png"), cv2.IMREAD_COLOR)
    # 20 rows of map, white rows under them so that the colour bar's range and unit fit
    assert depth.shape == (bar_min_height("indentation, mm"), 30 + BAR_WIDTH, 3) and normals.shape == (20, 30, 3)
    # the press's undeformed surface reached the figures: depth.png shows the indentation
    np.testing.assert_array_equal(views[0], load_press(press).reference.depth)


def test_parallel_solve_matches_serial(press_set, tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    shutil.copytree(press_set, one)
    shutil.copytree(press_set, two)
    folders = lambda root: sorted(p for p in root.iterdir() if p.is_dir())  # noqa: E731
    serial = solve_presses(folders(one), options=FAST, workers=1, progress=False, figures=False)
    parallel = solve_presses(folders(two), options=FAST, workers=2, progress=False, figures=False)
    assert serial == parallel == {"a_sphere": "solved", "b_cube": "solved", "c_sphere_deep": "solved"}
    for name in serial:
        a, b = load_reconstruction(one / name / "nlips"), load_reconstruction(two / name / "nlips")
        # the solver itself repeats only to float32 rounding (1e-6 mm run to run, in one process too)
        for key, arr in a.arrays().items():
            if arr.dtype.kind == "f":
                np.testing.assert_allclose(getattr(b, key), arr, rtol=1e-4, atol=1e-5, err_msg=f"{name} {key}")
            else:
                assert np.array_equal(arr, getattr(b, key)), (name, key)
    again = solve_presses(folders(two), options=FAST, workers=2, progress=False, figures=False)
    assert set(again.values()) == {"skipped"}


def test_failures_are_reported_per_press(press_set, tmp_path):
    root = tmp_path / "set"
    shutil.copytree(press_set, root)
    (root / "b_cube" / "led_03.png").write_bytes(b"broken")
    statuses = solve_presses(sorted(root.iterdir()), options=FAST, progress=False, figures=False)
    assert statuses["a_sphere"] == "solved" and statuses["c_sphere_deep"] == "solved"
    assert statuses["b_cube"].startswith("failed: ") and "led_03.png" in statuses["b_cube"]
    with pytest.raises(ConfigError, match="workers"):
        solve_presses([root / "a_sphere"], workers=0)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_press_whose_meta_json_names_an_image_by_a_number_fails_alone(press_set, tmp_path, workers):
    """``images.dark = 5`` was a TypeError out of the capture's identity, hashed before meta.json was checked:
    the whole batch stopped (``nlips calibrate`` wrote no dataset) and ``--workers 2`` printed tracebacks."""
    import json

    root = tmp_path / "set"
    shutil.copytree(press_set, root)
    meta = json.loads((root / "b_cube" / "meta.json").read_text(encoding="utf-8"))
    meta["images"]["dark"] = 5
    (root / "b_cube" / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    statuses = solve_presses(sorted(root.iterdir()), options=FAST, workers=workers, progress=False, figures=False)
    assert statuses["a_sphere"] == "solved" and statuses["c_sphere_deep"] == "solved"
    assert statuses["b_cube"] == f"failed: {root / 'b_cube' / 'meta.json'}: 'images.dark' must be a file name, got 5"


def test_a_batchs_log_lines_name_each_press_as_the_user_gave_it(press_set, tmp_path):
    """`nlips solve x --workers 2` named one press `x/press_0001` (the solver's lines), `press_0001` (its summary
    line, its failure) and by an absolute path (its result): now the path given, `x/press_0001`, on every line."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    for name in ("a_sphere", "b_cube"):
        shutil.copytree(press_set / name, tmp_path / "x" / name)
    (tmp_path / "fast.toml").write_text("max_iters = 6\n", encoding="utf-8")
    code = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))

    def solve(*extra: str) -> list[str]:
        argv = ["--no-progress", "solve", "x", "--roi", "auto", "--workers", "2", "--no-figures", *extra]
        run = subprocess.run([sys.executable, "-c", code, *argv], cwd=tmp_path, env=env, capture_output=True, text=True)
        logged = [line for line in run.stderr.splitlines() if line.startswith(("INFO ", "WARNING ", "ERROR "))]
        return [line for line in logged if "a_sphere" in line or "b_cube" in line]  # not the closing counts

    lines = solve("--config", "fast.toml")  # solved
    lines += solve()  # other options: re-solved
    lines += solve()  # reused
    meta = json.loads((tmp_path / "x" / "b_cube" / "meta.json").read_text(encoding="utf-8"))
    meta["images"]["dark"] = 5
    (tmp_path / "x" / "b_cube" / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    lines += solve("--overwrite")  # one press fails
    said = " ".join(lines)
    assert "reconstructed" in said and "re-solving" in said and "identical result" in said and "ERROR" in said
    for line in lines:
        assert str(tmp_path) not in line, line
        message = line.split(" ", 1)[1]
        assert message.startswith(("x/a_sphere", "x/b_cube")) and " a_sphere" not in line and " b_cube" not in line


def test_reference_is_used_not_solved_and_is_part_of_the_identity(press_set, tmp_path):
    root = tmp_path / "set"
    root.mkdir()
    shutil.copytree(press_set / "a_sphere", root / "a_sphere")
    synth.make_press(root / "reference", "none", size=(64, 48))
    folders = sorted(root.iterdir())
    # interreflection "on": the term is fitted on the reference capture even though this synthetic one has none
    on = {"interreflection": "on"}
    statuses = solve_presses(
        folders, reference=root / "reference", options=FAST, progress=False, figures=False, solver_keywords=on
    )
    assert statuses == {"a_sphere": "solved"} and not (root / "reference" / "nlips").exists()
    report = read_report(root / "a_sphere" / "nlips")
    assert report["indirect_compensation"] is True
    assert (
        report["provenance"]["inputs"]["reference"]
        == make_provenance(root / "reference", make_settings())["inputs"]["press"]
    )
    again = solve_presses(
        folders, reference=root / "reference", options=FAST, progress=False, figures=False, solver_keywords=on
    )
    assert again == {"a_sphere": "skipped"}
    without = solve_presses(folders[:1], options=FAST, progress=False, figures=False, solver_keywords=on)
    assert without == {"a_sphere": "solved"}  # the reference was an input: its absence re-solves


WORKER = """
import sys, time
from pathlib import Path
from nlipscalib.core.atomic import atomic_dir
from nlipscalib.core.claims import claim
from nlipscalib.pipeline.workers import _worker_signals

_worker_signals()
target = Path(sys.argv[1]) / "nlips"
with claim(target), atomic_dir(target):
    print("solving", flush=True)
    time.sleep(60)
"""


def test_a_worker_leaves_ctrl_c_to_the_parent_and_cleans_up_when_terminated(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-c", WORKER, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "solving"
        leftovers = lambda: sorted(p.name.split("~")[0] for p in tmp_path.iterdir())  # noqa: E731
        assert leftovers() == [".claim-nlips", ".tmp-nlips"]
        proc.send_signal(signal.SIGINT)  # Ctrl-C: the parent cancels the batch; the worker finishes its press
        time.sleep(0.5)
        assert proc.poll() is None
        proc.send_signal(signal.SIGTERM)  # a scheduler's kill: claim and half-written folder go with it
        assert proc.wait(timeout=10) == 128 + signal.SIGTERM
        assert leftovers() == []
    finally:
        proc.kill()
        proc.wait()


def test_ctrl_c_on_a_parallel_solve_leaves_no_claim_and_no_traceback(press_set, tmp_path):
    """Ctrl-C reaches the whole process group, idle workers too; the batch stops cleanly and resumes."""
    import os
    import signal
    import subprocess
    import sys
    import time

    root = tmp_path / "set"
    shutil.copytree(press_set, root)
    command = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
    argv = [sys.executable, "-c", command, "--no-progress", "solve", str(root), "--workers", "3", "--no-figures"]
    proc = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not list(root.glob("*/nlips/result.npz")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        os.killpg(proc.pid, signal.SIGINT)  # the first worker to finish now waits for work: it is hit idle
        _, err = proc.communicate(timeout=60)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert "Traceback" not in err, err
    assert proc.returncode in (0, 130), err  # 0: every press was done before the signal arrived
    assert not [p for p in root.rglob("*") if p.name.startswith((".claim-", ".tmp-"))]
    for result in root.glob("*/nlips"):
        load_reconstruction(result)
    statuses = solve_presses(sorted(root.iterdir()), progress=False, figures=False)
    assert "failed" not in " ".join(statuses.values())


def test_a_result_damaged_inside_or_with_a_strange_record_is_re_solved(press, caplog):
    import json

    from tests.core.test_reconstruction import _spoil_deflated_member

    solve_folder(press, options=FAST, figures=False)
    _spoil_deflated_member(press / "nlips" / "result.npz", "mask.npy")  # the zip directory is whole
    caplog.set_level(logging.INFO)
    assert solve_folder(press, options=FAST, figures=False)[1] == "solved"
    assert "compressed data damaged" in caplog.text
    report = press / "nlips" / "report.json"
    record = json.loads(report.read_text(encoding="utf-8"))
    for provenance in (5, {"settings": 5, "inputs": [1]}):  # hand-edited: valid JSON, not a record
        report.write_text(json.dumps(record | {"provenance": provenance}), encoding="utf-8")
        assert solve_folder(press, options=FAST, figures=False)[1] == "solved"
    assert read_report(press / "nlips")["provenance"]["key"] == record["provenance"]["key"]


def test_a_result_of_other_code_or_of_code_unrecorded_is_re_solved(press, caplog, monkeypatch):
    """The version is "0.1.0" in every commit: a user who upgraded was served the old code's result silently. The
    key holds the code's fingerprint; a result of other code, or one whose record has none (made before it was
    recorded), is solved again with one line saying why."""
    import hashlib
    import json

    from nlipscalib import __version__
    from nlipscalib.core import code_version

    monkeypatch.setattr(code_version, "_fingerprint", lambda: "0" * 32)  # an older commit's solver
    solve_folder(press, options=FAST, figures=False)
    monkeypatch.undo()
    caplog.set_level(logging.INFO)
    assert solve_folder(press, options=FAST, figures=False)[1] == "solved"
    assert "made with other settings or inputs (nlipscalib code), re-solving" in caplog.text
    report = press / "nlips" / "report.json"
    record = json.loads(report.read_text(encoding="utf-8"))
    assert record["provenance"]["code"] == code_version.code_fingerprint()
    assert solve_folder(press, options=FAST, figures=False)[1] == "skipped"  # the same code: reused

    old = {k: v for k, v in record["provenance"].items() if k != "code"}  # as an nlipscalib before it wrote
    source = {"settings": old["settings"], "inputs": old["inputs"], "software_version": __version__}
    settings = {k: v for k, v in old["settings"].items() if k not in ("leds_file", "reference")}  # keyed
    source["settings"] = settings
    old["key"] = hashlib.sha256(json.dumps(source, sort_keys=True).encode()).hexdigest()
    report.write_text(json.dumps(record | {"provenance": old}), encoding="utf-8")
    caplog.clear()
    assert solve_folder(press, options=FAST, figures=False)[1] == "solved"
    lines = [r.getMessage() for r in caplog.records if "re-solving" in r.getMessage()]
    assert lines == [
        f"{press / 'nlips'}: made with other settings or inputs (code unrecorded: an nlipscalib before "
        "2026-12-06 made it), re-solving"
    ]


def test_a_result_of_other_library_versions_or_of_versions_unrecorded_is_re_solved(press, caplog, monkeypatch):
    """A library's release moves numbers (the demo's coin press: 3.82 deg vs 4.05 at the lowest supported versions),
    yet the key held nlipscalib's version and code alone: an upgraded NumPy was served the old one's result. The
    provenance records the versions of the libraries that shape a solve and the key holds them; a result made under
    another version is solved again with one line naming it, one whose record has none (made before) too."""
    import hashlib
    import json
    from importlib import metadata

    from nlipscalib import __version__
    from nlipscalib.core import code_version, libraries

    installed = libraries.installed_version
    monkeypatch.setattr(libraries, "installed_version", lambda name: "2.3.1" if name == "numpy" else installed(name))
    solve_folder(press, options=FAST, figures=False)
    record = read_report(press / "nlips")["provenance"]
    assert record["libraries"] == {
        "numpy": "2.3.1",
        "scipy": metadata.version("scipy"),
        "pyamg": metadata.version("pyamg"),
        "opencv": metadata.version("opencv-python-headless"),
    }
    monkeypatch.undo()
    caplog.set_level(logging.INFO)
    assert solve_folder(press, options=FAST, figures=False)[1] == "solved"
    lines = [r.getMessage() for r in caplog.records if "re-solving" in r.getMessage()]
    assert lines == [f"{press / 'nlips'}: made with numpy 2.3.1, now {metadata.version('numpy')}: re-solving"]
    assert solve_folder(press, options=FAST, figures=False)[1] == "skipped"  # the same versions: reused

    report = press / "nlips" / "report.json"
    whole = json.loads(report.read_text(encoding="utf-8"))
    old = {k: v for k, v in whole["provenance"].items() if k != "libraries"}  # as an nlipscalib before it wrote
    settings = {k: v for k, v in old["settings"].items() if k not in ("leds_file", "reference")}  # keyed
    source = {"settings": settings, "inputs": old["inputs"], "software_version": __version__}
    old["key"] = hashlib.sha256(
        json.dumps(source | {"code": code_version.code_fingerprint()}, sort_keys=True).encode()
    ).hexdigest()
    report.write_text(json.dumps(whole | {"provenance": old}), encoding="utf-8")
    caplog.clear()
    assert solve_folder(press, options=FAST, figures=False)[1] == "solved"
    lines = [r.getMessage() for r in caplog.records if "re-solving" in r.getMessage()]
    assert lines == [
        f"{press / 'nlips'}: made with other settings or inputs (library versions unrecorded: an nlipscalib before "
        "2026-12-06 made it), re-solving"
    ]


def test_the_re_solve_line_names_library_versions_alone_or_among_other_differences():
    from nlipscalib.pipeline.reuse import _why_not_reused

    versions = {"numpy": "2.4.6", "scipy": "1.17.1", "pyamg": "5.4.1", "opencv": "5.1.0.95"}
    new = {"settings": {"roi": "auto"}, "inputs": {"press": "a"}, "software_version": "0.1.0", "code": "c"}
    new["libraries"] = versions
    old = new | {"libraries": versions | {"numpy": "2.3.1", "pyamg": None}}
    assert _why_not_reused(old, new) == "made with numpy 2.3.1, now 2.4.6; pyamg not installed, now 5.4.1: re-solving"
    old["settings"] = {"roi": None}
    assert _why_not_reused(old, new) == (
        "made with other settings or inputs (roi, numpy 2.3.1 now 2.4.6, pyamg not installed now 5.4.1), re-solving"
    )


@pytest.mark.parametrize("wait", [True, False])
def test_wait_reuses_what_another_process_was_solving(press, tmp_path, caplog, wait):
    """`nlips calibrate` needs every result: a press another process is solving is waited for (at once with
    wait=True, after the other presses without), then its result reused when made with the same settings."""
    solve_folder(press, options=FAST, figures=False)
    finished = tmp_path / "finished"
    (press / "nlips").rename(finished)
    caplog.set_level(logging.INFO)
    thread = _held_by_another_process(press / "nlips", lambda: "waiting for" in caplog.text, publish=finished)
    assert solve_presses([press], options=FAST, progress=False, figures=False, wait=wait) == {"press": "skipped"}
    assert "waiting for" in caplog.text and "identical result exists" in caplog.text
    load_reconstruction(press / "nlips")
    thread.join()


def test_overwrite_runs_sharing_a_folder_do_not_solve_each_others_presses_again(press, tmp_path, caplog):
    """Two `nlips solve DATASET --overwrite` runs (cluster jobs on one folder): a press the other run held was
    waited for and then solved a second time; what that run published meanwhile with these settings is fresh."""
    solve_folder(press, options=FAST, figures=False)
    finished = tmp_path / "finished"
    (press / "nlips").rename(finished)
    import os
    import time

    later = time.time() + 60  # the other run publishes after this run started (set, not raced)
    os.utime(finished / "report.json", (later, later))
    caplog.set_level(logging.INFO)
    thread = _held_by_another_process(press / "nlips", lambda: "waiting for" in caplog.text, publish=finished)
    statuses = solve_presses([press], options=FAST, progress=False, figures=False, overwrite=True)
    thread.join()
    assert statuses == {"press": "skipped"} and "identical result exists" in caplog.text
    # a result published before this run started is not fresh: --overwrite solves it again
    earlier = time.time() - 3600
    os.utime(press / "nlips" / "report.json", (earlier, earlier))
    assert solve_presses([press], options=FAST, progress=False, figures=False, overwrite=True) == {"press": "solved"}


def test_a_batch_re_solves_a_result_damaged_inside(press_set, tmp_path, caplog):
    """A batch reuses results without loading them (nlips solve, nlips calibrate): still, damage inside
    result.npz is found and the press re-solved, not skipped for `nlips calibrate` to fail on."""
    from tests.core.test_reconstruction import _spoil_deflated_member

    root = tmp_path / "set"
    shutil.copytree(press_set, root)
    folders = sorted(root.iterdir())
    solve_presses(folders, options=FAST, progress=False, figures=False)
    _spoil_deflated_member(root / "b_cube" / "nlips" / "result.npz", "mask.npy")
    caplog.set_level(logging.WARNING)
    statuses = solve_presses(folders, options=FAST, progress=False, figures=False)
    assert statuses == {"a_sphere": "skipped", "b_cube": "solved", "c_sphere_deep": "skipped"}
    assert "b_cube/nlips/result.npz: damaged" in caplog.text
    load_reconstruction(root / "b_cube" / "nlips")


def test_a_killed_worker_fails_the_unfinished_presses_in_one_line_each(press_set, tmp_path):
    """The out-of-memory killer (or kill -9) ends one worker: no traceback; the presses not finished are
    named as such, the other worker releases its claim, and the next run takes over the dead one's."""
    import json
    import os
    import signal
    import subprocess
    import sys
    import time

    root = tmp_path / "set"
    shutil.copytree(press_set, root)
    command = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
    argv = [sys.executable, "-c", command, "--no-progress", "solve", str(root), "--workers", "2", "--no-figures"]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not (claims := list(root.glob("*/.claim-nlips"))) and time.monotonic() < deadline:
            time.sleep(0.01)
        victim, killed = claims[0].parent.name, None
        with contextlib.suppress(ValueError, OSError, ProcessLookupError):  # it may have finished meanwhile
            killed = json.loads(claims[0].read_text(encoding="utf-8"))["pid"]
            os.kill(killed, signal.SIGKILL)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert "Traceback" not in err, err
    if proc.returncode == 0:  # the press was finished before the signal arrived: nothing to check
        return
    assert proc.returncode == 1 and f"{victim}: failed: not solved, a solver process was killed" in err, err
    # what the SIGKILL'd worker left (its claim; a clock probe it was writing, in any folder) is the next run's to
    # clean; the worker the broken pool terminated leaves nothing
    others = [p for p in root.rglob(".claim-*") if p.parent.name != victim and f".{killed}." not in p.name]
    assert not others and not list(root.rglob(".tmp-*"))
    statuses = solve_presses(sorted(root.iterdir()), progress=False, figures=False, options=FAST)
    assert "failed" not in " ".join(statuses.values()) and not list(root.rglob(".claim-*"))


@pytest.mark.parametrize("what", ["dataset", "press itself", "user folder", "user file"])
def test_out_that_is_not_a_reconstruction_is_never_replaced(press, press_set, tmp_path, capsys, what):
    """`nlips solve PRESS --out X` refuses an X that holds something else than a reconstruction (it used to be
    replaced whole, as a "damaged result": a dataset, the press's own images, a user's notes), with or without
    --overwrite; an empty folder or a damaged result is still written."""
    from nlipscalib.cli import main

    target = {
        "dataset": press_set,
        "press itself": press,
        "user folder": tmp_path / "notes",
        "user file": tmp_path / "notes.txt",
    }[what]
    if what == "user folder":
        target.mkdir()
        (target / "todo.txt").write_text("important", encoding="utf-8")
    elif what == "user file":
        target.write_text("precious", encoding="utf-8")
    before = sorted(p.name for p in target.iterdir()) if target.is_dir() else target.read_text(encoding="utf-8")
    for extra in ([], ["--overwrite"]):
        assert main(["--no-progress", "solve", str(press), "--out", str(target), *extra]) == 2
        err = capsys.readouterr().err
        assert str(target) in err and "choose another --out" in err and "Traceback" not in err
    after = sorted(p.name for p in target.iterdir()) if target.is_dir() else target.read_text(encoding="utf-8")
    assert after == before


def test_out_dot_inside_the_press_is_one_line(press, monkeypatch, capsys):
    from nlipscalib.cli import main

    monkeypatch.chdir(press)
    assert main(["--no-progress", "solve", ".", "--out", "."]) == 2
    assert "is a press folder" in capsys.readouterr().err


def test_empty_out_folder_and_damaged_result_are_written(press, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert solve_folder(press, options=FAST, figures=False, out=empty)[1] == "solved"
    (empty / "result.npz").write_bytes(b"damaged")
    assert solve_folder(press, options=FAST, figures=False, out=empty)[1] == "solved"
    assert load_reconstruction(empty).reconstructed.any()


def test_cleaning_an_output_leaves_the_live_temporary_of_an_output_named_like_it(tmp_path):
    """`--out res` removed `.tmp-res-2~host~pid~*`, the live temporary folder of a solve writing `--out res-2`
    (a glob `.tmp-res-*` meant for untagged leftovers of older versions); that solve then published a result
    without result.npz. Only `res`'s own untagged leftovers go."""
    from nlipscalib.core.atomic import tmp_prefix
    from nlipscalib.pipeline.reuse import _clean_interrupted

    sibling = tmp_path / (tmp_prefix("res-2") + "0s9ec5e9")  # this (live) process writes res-2
    sibling_legacy = tmp_path / ".tmp-res-2-k2j3x9ab"  # an older version's leftover of res-2: not res's to remove
    legacy = tmp_path / ".tmp-res-k2j3x9ab"  # an older version's leftover of res
    for tmp in (sibling, sibling_legacy, legacy):
        tmp.mkdir()
    _clean_interrupted(tmp_path / "res")
    assert sibling.is_dir() and sibling_legacy.is_dir() and not legacy.exists()


KILLED_AFTER_PUBLISHING = """
import sys, time
from nlipscalib.pipeline import solve as pipeline_solve
from nlipscalib.pipeline import solve_folder
from nlipscalib.solver import SolverOptions


def published(*args):  # the result is in place, its claim not yet released: the moment the kill comes
    print("published", flush=True)
    time.sleep(60)


pipeline_solve._log_solved = published
solve_folder(sys.argv[1], options=SolverOptions(max_iters=6), figures=False)
"""


def test_a_result_kept_after_a_kill_loses_the_dead_runs_claim(press):
    """A laptop dying between a press's publish and the release of its claim: the re-run reused the result
    (rightly) but left the dead run's ``.claim-nlips`` beside it for good, as the only thing a re-run never
    cleaned. Now a stale claim sends the re-run the claimed way, which takes it over and removes it."""
    from tests.processes import kill_when_it_says

    kill_when_it_says(KILLED_AFTER_PUBLISHING, str(press), line="published")
    assert (press / ".claim-nlips").exists()  # what the dead run left
    assert solve_folder(press, options=FAST, figures=False)[1] == "skipped"  # not solved again
    assert not [p.name for p in press.iterdir() if p.name.startswith((".claim-", ".tmp-"))]


def test_solver_workers_share_the_cores_out_as_threads(tmp_path, monkeypatch):
    """Each worker took one thread whatever the cores: 2 presses on 2 workers of an 8-core machine left 6 idle.
    Now the cores are shared out (2 workers of 8 cores: 4 threads each); as many workers as cores: one each."""
    from nlipscalib.core import cpus
    from nlipscalib.pipeline.workers import _solve_in_processes
    from tests.processes import threads_status

    folders = [tmp_path / "press_0", tmp_path / "press_1"]
    names = {f: f.name for f in folders}
    monkeypatch.setattr(cpus, "usable_cores", lambda: 8)  # the parent shares them out: the workers read none
    statuses = _solve_in_processes(threads_status, folders, names, 2, False, ())
    assert sorted(statuses.values()) == ["solver 4 opencv 4"] * 2
    monkeypatch.setattr(cpus, "usable_cores", lambda: 2)
    statuses = _solve_in_processes(threads_status, folders, names, 2, False, ())
    assert sorted(statuses.values()) == ["solver 1 opencv 1"] * 2


def test_ctrl_c_on_a_parallel_solve_starts_no_press_but_those_running(tmp_path, monkeypatch):
    """The pool was given every press at once and moved workers + 1 of them into its call queue, where no cancel
    reaches: after "interrupted: ... the others are not started", a 6-press set on 2 workers still solved the 4 it
    had not finished (here 6 of 10 after the first). The parent now sets a stop event the workers check first."""
    from nlipscalib import progress
    from nlipscalib.pipeline.workers import _solve_in_processes
    from tests.processes import sleepy_status

    class CtrlCAtTheFirstPress:  # the progress bar's first update is where the Ctrl-C lands
        def update(self, *args):
            raise KeyboardInterrupt

        def set_postfix_str(self, *args, **kwargs):
            pass

        def close(self):
            pass

    monkeypatch.setattr(progress, "progress_bar", lambda *args, **kwargs: CtrlCAtTheFirstPress())
    folders = [tmp_path / f"press_{i}" for i in range(10)]
    marks = tmp_path / "solved"
    marks.mkdir()
    with pytest.raises(KeyboardInterrupt):
        _solve_in_processes(sleepy_status, folders, {f: f.name for f in folders}, 2, False, (str(marks),))
    # the quick first press, the one running beside it, and perhaps the next one, had the first's worker taken it up
    # as it ended, before the parent read its result and set the stop (5 before: the call queue's presses too)
    solved = sorted(p.name for p in marks.iterdir() if p.is_file())
    assert solved in (["press_0", "press_1"], ["press_0", "press_1", "press_2"]), solved


def test_a_sessions_swapped_and_aged_leds_are_warned_of_once_by_a_batch_of_two_workers(tmp_path):
    """A session whose LED images 3 and 6 are swapped in every capture and whose presses are 10 % dimmer than its
    undeformed capture (s28-together): `nlips solve FOLDER --workers 2` said the swap once per worker process and
    the brightness once per press. Now each is one WARNING for the command, the other presses' lines at INFO, and
    each press's report keeps both."""
    from nlipscalib import progress

    def swapped(lin):
        lin = lin.copy()
        lin[[2, 5]] = lin[[5, 2]]
        return lin

    session = tmp_path / "session"
    synth.make_press(session / "reference", "none", lin_hook=swapped)
    names = ("p1", "p2", "p3", "p4")
    for name in names:
        synth.make_press(session / name, "sphere", lin_hook=lambda lin: swapped(lin) * 0.9)
    log = tmp_path / "run.log"
    progress.configure(progress=False, log_file=log)
    try:
        status = solve_presses(
            [session / n for n in names], reference=session / "reference", options=FAST, workers=2, figures=False
        )
    finally:
        progress.configure(progress=False)
    assert set(status.values()) == {"solved"}, status
    lines = log.read_text(encoding="utf-8").splitlines()
    for fault in ("out of order", "LEDs aged"):
        said = [line for line in lines if fault in line]
        assert len(said) == len(names), said  # each press's own line ...
        assert sum(" WARNING " in line for line in said) == 1, said  # ... one of them a warning
        for name in names:
            assert any(fault in note for note in read_report(session / name / "nlips")["warnings"]), name


def test_each_solve_of_a_sessions_folder_in_one_process_warns_of_its_swapped_leds_once(tmp_path, caplog):
    """A notebook (one long-lived process) that solved a session's folder twice, or after the session's presses had
    been captured again under the same path, heard the swapped LED images only the first time: the memory of what
    was said lasted the process. Now each call over the folder says it once (a WARNING), its other presses at INFO."""

    def swapped(lin):
        lin = lin.copy()
        lin[[2, 5]] = lin[[5, 2]]
        return lin

    session = tmp_path / "session"
    folders = [synth.make_press(session / name, "sphere", lin_hook=swapped) for name in ("p1", "p2")]
    for _ in range(2):
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="nlipscalib"):
            status = solve_presses(folders, options=SolverOptions(max_iters=1), figures=False, overwrite=True)
        assert set(status.values()) == {"solved"}, status
        said = [r for r in caplog.records if "out of order" in r.getMessage()]
        assert [r.levelno for r in said] == [logging.WARNING, logging.INFO], [r.getMessage() for r in said]
