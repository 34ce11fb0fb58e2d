"""`nlips calibrate --leds FILE`: capture -> calibrate-leds -> calibrate, the LED file's sensor checked once before
any solving, and the LEDs part of what a reused result must have been solved with (exact-data presses, 64x48)."""

import json
import logging

import pytest

from nlipscalib.cli import main
from tests.solver import synth

SIZE = (64, 48)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("calibrate_leds") / "presses"
    synth.make_press(root / "reference", "none", size=SIZE)
    synth.make_press(root / "press_0001", "sphere", size=SIZE)
    synth.make_press(root / "press_0002", "cube", size=SIZE)
    leds = root.parent / "leds.json"
    assert main(["calibrate-leds", str(root / "reference"), "--out", str(leds), "--stride", "4"]) == 0
    return root, leds


def _solved_with(press) -> list | None:
    return json.loads((press / "nlips" / "report.json").read_text(encoding="utf-8"))["provenance"]["settings"]["leds"]


def test_calibrate_solves_with_the_led_file_and_again_when_the_leds_change(session, capsys, caplog):
    """`nlips calibrate` had no --leds: the calibrated LEDs never reached NLiPsNet's labels."""
    root, leds = session
    caplog.set_level(logging.INFO)
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 0
    assert _solved_with(root / "press_0001") is None  # the capture's own LEDs
    caplog.clear()
    assert main(["calibrate", str(root), "--leds", str(leds), "--workers", "1", "--no-progress"]) == 0
    calibrated = json.loads(leds.read_text(encoding="utf-8"))["leds"]
    for name in ("press_0001", "press_0002"):
        assert [d["position"] for d in _solved_with(root / name)] == [d["position"] for d in calibrated]
    # not reused silently: each result made with the capture's LEDs is named and solved again
    resolved = [r.getMessage() for r in caplog.records if "made with other settings or inputs (leds)" in r.getMessage()]
    assert len(resolved) == 2, caplog.text
    out, err = capsys.readouterr()
    assert set(out.splitlines()) == {str(root / "calibration")}  # stdout: the dataset's folder alone (each run)
    assert "2 presses" in err and "press next: an object in image region" in err  # was "an unknown"
    assert f"next: nlips train {root / 'calibration'} --out MODEL.pt" in err  # a new user's next step, with its folder
    caplog.clear()
    assert main(["calibrate", str(root), "--leds", str(leds), "--workers", "1", "--no-progress"]) == 0
    assert "identical result exists" in caplog.text and "re-solving" not in caplog.text


def test_an_led_file_of_another_sensor_or_an_led_subset_is_one_line_before_any_solving(session, tmp_path, capsys):
    root, leds = session
    other = json.loads(leds.read_text(encoding="utf-8"))  # calibrated on a sensor whose LEDs sit 20 % further out
    for led in other["leds"]:
        led["position"] = [v * 1.2 for v in led["position"]]
    other["sensor"]["led_positions"] = [[v * 1.2 for v in p] for p in other["sensor"]["led_positions"]]
    foreign = tmp_path / "other.json"
    foreign.write_text(json.dumps(other), encoding="utf-8")
    fresh = tmp_path / "presses"
    for name in ("reference", "press_0001"):
        synth.make_press(fresh / name, "none" if name == "reference" else "sphere", size=SIZE)
    capsys.readouterr()
    for given, problem in (
        (str(foreign), f"{foreign}: calibrated on another sensor than {fresh / 'reference'} (LED 1 is"),
        ("1,5,9", "--leds 1,5,9: no LED file (a .json file from `nlips calibrate-leds`)"),
        (str(tmp_path / "missing.json"), "missing.json: no such LED file"),
    ):
        assert main(["calibrate", str(fresh), "--leds", given, "--workers", "1", "--no-progress"]) == 2
        err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
        assert len(err) == 1 and problem in err[0], err
    assert not (fresh / "press_0001" / "nlips").exists() and not (fresh / "calibration").exists()


def test_presses_of_another_dome_than_the_reference_are_one_line_naming_the_surfaces(tmp_path, capsys):
    """The lab-2 walk: a press of one's own design (the fingertip with its dome 4 mm lower) beside the fingertip's
    reference was refused as "rendered with other twin settings (dome.height ...)", with a remedy of re-rendering
    the reference or solving without one; on a device session (no twin settings) each press failed alone. Now the
    undeformed surfaces are compared first, as `nlips solve --reference` compares them."""
    from nlipscalib.core import load_press
    from nlipscalib.core.capture import Reference
    from tests.solver.twin_helpers import recorded_anew

    root = tmp_path / "presses"
    synth.make_press(root / "reference", "none", size=SIZE)
    press = synth.make_press(root / "press_0001", "sphere", size=SIZE)
    ref = Reference.load(press / "reference.npz", load_press(press).camera.shape)
    Reference(depth=ref.depth * 1.05, normals=ref.normals).save(press / "reference.npz")  # a dome 5 % larger
    recorded_anew(press)  # captured so: its record holds that file
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1, err
    assert err[0].startswith(f"nlips calibrate: error: --reference {root / 'reference'}: not a capture of the sensor")
    assert "undeformed surfaces" in err[0] and "mm apart (median)" in err[0], err
    assert not (press / "nlips").exists() and not (root / "calibration").exists()


def test_presses_of_another_source_than_the_reference_are_one_warning(tmp_path, caplog):
    """Twin presses calibrated against the emulated sensor's undeformed capture: one line for both presses (said
    once per command), and the calibration goes on (a lab may mix them on purpose)."""
    root = tmp_path / "presses"
    for name, kind in (("reference", "none"), ("press_0001", "sphere"), ("press_0002", "cube")):
        folder = synth.make_press(root / name, kind, size=SIZE)
        meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
        emulated = {"source": "device", "device": "emulator"}
        meta["provenance"] = emulated if name == "reference" else {"source": "sim"}
        (folder / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    caplog.set_level(logging.WARNING)
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 0
    lines = [r.getMessage() for r in caplog.records if "solved against the undeformed capture" in r.getMessage()]
    assert len(lines) == 1, lines
    assert (
        f"a twin render (nlips render, nlips dataset), solved against the undeformed capture {root / 'reference'}, "
        in lines[0]
    )
    assert "a capture of the emulated sensor (nlips capture --emulate)" in lines[0]


def test_calibrate_leds_help_names_both_commands(capsys):
    with pytest.raises(SystemExit):
        main(["calibrate-leds", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "`nlips solve --leds FILE` or `nlips calibrate --leds FILE`" in text


def test_calibrate_normals_refined_reaches_every_label_solve(tmp_path):
    """`nlips calibrate --normals refined`: each press's result holds the refined normals (as `nlips solve
    --normals refined`), and a later default run solves it again with the depth's normals."""
    root = tmp_path / "presses"
    synth.make_press(root / "reference", "none", size=SIZE)
    synth.make_press(root / "press_0001", "sphere", size=SIZE)
    synth.make_press(root / "press_0002", "cube", size=SIZE)

    def normals(name):
        return json.loads((root / name / "nlips" / "report.json").read_text(encoding="utf-8"))["normals"]

    assert main(["calibrate", str(root), "--normals", "refined", "--workers", "1", "--no-progress"]) == 0
    assert [normals(n) for n in ("press_0001", "press_0002")] == ["refined", "refined"]
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 0
    assert [normals(n) for n in ("press_0001", "press_0002")] == ["depth", "depth"]


def test_calibrate_runs_as_many_solvers_as_memory_holds(session, monkeypatch, caplog):
    """Without --workers, one solver per two cores (as `nlips solve FOLDER`; it was one per core) unless the
    memory available holds fewer (one INFO line)."""
    from nlipscalib.core import cpus

    root, _ = session
    monkeypatch.setattr(cpus, "usable_cores", lambda: 8)
    monkeypatch.setattr(cpus, "available_memory", lambda: 10**8)  # 100 MB: not one 64x48 solver's ~0.16 GB
    caplog.set_level(logging.INFO)
    assert main(["calibrate", str(root), "--no-progress"]) == 0
    assert "1 worker instead of 4: each solve, auto ROI worker may take ~0.2 GB at 64x48" in caplog.text


@pytest.mark.parametrize("cores, workers", [(2, 1), (3, 1), (4, 2), (8, 4)])
def test_every_solving_command_starts_as_many_solvers_by_one_default(session, monkeypatch, cores, workers):
    """`nlips solve FOLDER` started one solver per two cores, `nlips calibrate` one per core and `nlips demo` one
    per core (at most 3), for the same work and under help texts that said so three ways. Now one default
    (core.cpus.solve_worker_count) and one help text; ``--workers`` is obeyed alike."""
    import nlipscalib.pipeline as pipeline
    from nlipscalib.cli import build_parser
    from nlipscalib.core import cpus

    root, _ = session
    asked = []
    monkeypatch.setattr(pipeline, "solve_presses", lambda presses, workers, **kw: asked.append(workers) or {})
    monkeypatch.setattr(cpus, "available_memory", lambda: 64 * 10**9)
    monkeypatch.setattr(cpus, "usable_cores", lambda: cores)
    main(["solve", str(root), "--roi", "auto", "--no-progress"])
    main(["calibrate", str(root), "--no-progress"])  # no press solved here: refused after the solves, as it should
    main(["calibrate", str(root), "--workers", "3", "--no-progress"])
    assert asked == [workers, workers, 3]
    commands = build_parser()._subparsers._group_actions[0].choices
    pools = [(commands["solve"], "workers"), (commands["calibrate"], "workers"), (commands["demo"], "solve_workers")]
    options = [next(a for a in parser._actions if a.dest == dest) for parser, dest in pools]
    assert {(a.default, a.help) for a in options} == {(0, options[0].help)}  # one default, said one way


def _capture_line(out: str) -> str:
    return next(line for line in out.splitlines() if line.startswith("capture 1:"))


def test_calibrate_leds_names_the_interreflection_threshold_it_used_and_no_other(session, tmp_path, capsys):
    """`nlips calibrate-leds` printed "(auto threshold 0.02)" -- the solver's, which its first round does not use --
    beside "calibration: not used (threshold 0.1 with the starting LEDs)", the one it did use: two thresholds for
    one decision. With --interreflection on, no threshold decides anything, and none is named."""
    root, _ = session
    capsys.readouterr()
    args = ["--no-progress", "calibrate-leds", str(root / "reference"), "--stride", "4"]
    assert main([*args, "--out", str(tmp_path / "auto.json")]) == 0
    said = capsys.readouterr()  # stdout: the LED file alone (`leds=$(nlips calibrate-leds ...)`); the table on stderr
    assert said.out == f"{tmp_path / 'auto.json'}\n"
    out = said.err
    # and, as `nlips calibrate` and `nlips train` end, what to run next with the file (it ended on "written FILE")
    leds = tmp_path / "auto.json"
    assert out.splitlines()[
        -1
    ] == f"next: nlips solve PRESS --leds {leds}, or nlips calibrate FOLDER --leds {leds} " + ("(NLiPsNet's labels)")
    line = _capture_line(out)
    assert line.startswith("capture 1: interreflection off: fitted indirect share ")
    assert "of the direct light with the starting LEDs (below the LED calibration's auto threshold 0.1)" in line
    assert line.count("threshold") == 1, line
    assert main([*args, "--interreflection", "on", "--out", str(tmp_path / "on.json")]) == 0
    line = _capture_line(capsys.readouterr().err)
    assert line.startswith("capture 1: interreflection on: fitted indirect share ") and "threshold" not in line


@pytest.mark.parametrize("length", [0, 200])
def test_a_torn_index_is_named_by_train_with_its_remedy_and_calibrate_writes_it_anew(session, tmp_path, capsys, length):
    """A calibration dataset's index.json cut short (a power cut soon after `nlips calibrate` published it): `nlips
    train` said only "index.json: not valid JSON (Expecting ... (char 200))", no remedy. Now one line saying it is
    torn and which command writes it anew; that command (calibrate again) keeps the intact samples."""
    import shutil

    root = tmp_path / "presses"
    shutil.copytree(session[0], root, ignore=shutil.ignore_patterns("calibration"))
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 0
    index = root / "calibration" / "index.json"
    whole = json.loads(index.read_text(encoding="utf-8"))
    shards = {p: p.stat().st_mtime_ns for p in (root / "calibration" / "samples").glob("*.npz")}
    with open(index, "r+b") as f:
        f.truncate(length)
    capsys.readouterr()
    model = tmp_path / "m.pt"
    assert main(["train", str(index.parent), "--out", str(model), "--epochs", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    problem = "empty" if length == 0 else "cut short or damaged (not valid JSON)"
    said = f"nlips train: error: {index}: {problem}: the dataset's index, torn"
    assert len(err) == 1 and err[0].startswith(said), err
    assert f"run `nlips calibrate {root}` again to write it anew" in err[0]
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 0  # the remedy named works
    assert json.loads(index.read_text(encoding="utf-8"))["presses"] == whole["presses"]
    assert {p: p.stat().st_mtime_ns for p in shards} == shards  # the samples kept, not made again


def test_calibrate_led_model_disks_solves_every_label_press_with_the_led_files_disks(session, tmp_path, capsys):
    """`nlips calibrate --led-model disks` (as `nlips solve --led-model disks`): every press solved with the LED
    file's disks, recorded in its result's settings, so a default run solves it again with points; an LED file
    without disks, or no LED file on a capture whose design declares no LED size, is one line before any solving.
    Before s32-diskmodel calibrate had no --led-model: its labels came from point LEDs whatever the view."""
    _, leds = session
    root = tmp_path / "presses"
    synth.make_press(root / "reference", "none", size=SIZE)
    synth.make_press(root / "press_0001", "sphere", size=SIZE)
    calibrated = json.loads(leds.read_text(encoding="utf-8"))
    calibrated["emitters"] = {"radius_mm": 1.8, "leds": calibrated["leds"]}
    with_disks = tmp_path / "disks.json"
    with_disks.write_text(json.dumps(calibrated), encoding="utf-8")
    no_disks = tmp_path / "points.json"
    no_disks.write_text(json.dumps({k: v for k, v in calibrated.items() if k != "emitters"}), encoding="utf-8")
    capsys.readouterr()
    for given, problem in (
        ([], f"{root / 'reference' / 'meta.json'}: no sensor design recorded: --led-model disks without --leds"),
        (["--leds", str(no_disks)], f"{no_disks}: no disk LEDs fitted"),
    ):
        assert main(["calibrate", str(root), *given, "--led-model", "disks", "--workers", "1", "--no-progress"]) == 2
        err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
        assert len(err) == 1 and problem in err[0], err
    assert not (root / "press_0001" / "nlips").exists() and not (root / "calibration").exists()

    def radius() -> float | None:
        report = json.loads((root / "press_0001" / "nlips" / "report.json").read_text(encoding="utf-8"))
        return report["provenance"]["settings"]["solver_keywords"].get("led_radius")

    command = ["calibrate", str(root), "--leds", str(with_disks), "--workers", "1", "--no-progress"]
    assert main([*command, "--led-model", "disks"]) == 0
    assert radius() == 1.8
    assert main(command) == 0  # the same LED file's points: solved again, not the disks' result reused
    assert radius() is None


def test_calibrate_led_model_disks_without_an_led_file_takes_the_designs_led_size(tmp_path, monkeypatch):
    """`nlips calibrate --led-model disks` without --leds solves each press's own LEDs as disks of its design's
    declared size, as `nlips solve --led-model disks` (pipeline.settings.for_press), and the dataset's record says
    led_model "disks" (another build of point labels into the folder is told apart). It was refused ("needs --leds
    FILE") although --led-model auto could pick those disks."""
    from nlipscalib.learn import dataset

    root = tmp_path / "presses"
    for name, kind in (("reference", "none"), ("press_0001", "sphere")):
        synth.make_press(root / name, kind, size=SIZE)
        meta = json.loads((root / name / "meta.json").read_text(encoding="utf-8"))
        meta["design"] = {"leds": {"emitter_diameter": 3.6}}  # a device capture's design: its LEDs' size only
        (root / name / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    runs = []
    real = dataset.dataset_run

    def recorded(*args, **kwargs) -> dict:
        runs.append(real(*args, **kwargs))
        return runs[-1]

    monkeypatch.setattr(dataset, "dataset_run", recorded)
    assert main(["calibrate", str(root), "--led-model", "disks", "--workers", "1", "--no-progress"]) == 0
    report = json.loads((root / "press_0001" / "nlips" / "report.json").read_text(encoding="utf-8"))
    keywords = report["provenance"]["settings"]["solver_keywords"]
    assert keywords["led_radius"] == 1.8 and keywords["emitters"] is None
    assert runs[-1]["options"]["led_model"] == "disks" and runs[-1]["options"]["leds"] is None
    assert (root / "calibration" / "index.json").is_file()
    assert main(["calibrate", str(root), "--led-model", "points", "--workers", "1", "--no-progress"]) == 0
    assert "led_model" not in runs[-1]["options"]  # point labels keep their record


def test_an_interrupted_calibrate_leaves_no_empty_dataset_folder_and_runs_again(session, tmp_path, monkeypatch):
    """Ctrl-C of `nlips calibrate` before the dataset's first write (during the solves) left an empty calibration/
    folder (made for the run's hold), which `nlips train` then took for a dataset. Now a folder the run made and
    left empty goes with it; an empty one already there (a killed run's) is a dataset not started: built into."""
    from nlipscalib import pipeline

    root, _ = session
    out = tmp_path / "new" / "calibration"

    def interrupted(*args, **kwargs):
        assert out.is_dir()  # held before the solves: made by then
        raise KeyboardInterrupt

    with monkeypatch.context() as patched:
        patched.setattr(pipeline, "solve_presses", interrupted)
        assert main(["calibrate", str(root), "--out", str(out), "--workers", "1", "--no-progress"]) == 130
    assert not (tmp_path / "new").exists()
    out.mkdir(parents=True)  # as a killed run (SIGKILL) leaves it
    assert main(["calibrate", str(root), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    assert (out / "index.json").is_file()


STOPPED_IN_THE_SOLVES = """
import sys
import time
from pathlib import Path

from nlipscalib import pipeline
from nlipscalib.cli import main


def solving(*args, **kwargs):  # the run's hold has made its output folder; nothing is written in it yet
    Path(sys.argv[1]).touch()
    time.sleep(120)


pipeline.solve_presses = solving
sys.exit(main(sys.argv[2:]))
"""
"""`nlips calibrate` whose solves wait, after saying so in a file (argv[1]): the point where SIGTERM found its
dataset folder empty."""


def test_a_calibrate_terminated_during_the_solves_leaves_no_empty_dataset_folder(session, tmp_path):
    """SIGTERM (a scheduler's time limit, `kill PID`) of `nlips calibrate` during the solves left the calibration
    folder it made for its hold, empty, which `nlips train` then took for a dataset ("index.json: missing"); Ctrl-C
    already removed it. The handler ends the process at once (no `finally`), so it removes the folder itself."""
    import os
    import signal
    import subprocess
    import sys
    import time

    root, _ = session
    out = tmp_path / "new" / "calibration"
    ready = tmp_path / "solving"
    argv = [sys.executable, "-c", STOPPED_IN_THE_SOLVES, str(ready), "calibrate", str(root), "--out", str(out)]
    proc = subprocess.Popen([*argv, "--workers", "1", "--no-progress"], stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not ready.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert ready.exists(), proc.stderr.read() if proc.poll() is not None else "not solving after 60 s"
        assert out.is_dir()  # held: made, with the hold's claim file alone in it
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "nlips calibrate: terminated" in err
    assert not (tmp_path / "new").exists(), sorted(os.listdir(tmp_path / "new"))  # nor its missing parent
