"""Bad input found by a hostile audit of every `nlips` command: one line naming the file and the problem, exit 2,
and refused before the long work (renders, solves, fits) rather than after it.

Tiny presses (3 LEDs, 16x12, no rendering): each test takes well under a second.
"""

from __future__ import annotations

import errno
import json
from pathlib import Path

import pytest

from nlipscalib.cli import describe_os_error, main
from nlipscalib.core.sensor_response import SensorResponse
from tests.core.test_capture import _press


def _one_line_error(err: str, *needles: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def presses(tmp_path) -> Path:
    """A folder of presses: reference/ and one press, p1/."""
    root = tmp_path / "presses"
    _press(root / "reference", dark_level=int(SensorResponse().black_level))
    _press(root / "p1", dark_level=int(SensorResponse().black_level))
    return root


@pytest.fixture
def a_file(tmp_path) -> Path:
    path = tmp_path / "a file"
    path.write_text("notes", encoding="utf-8")
    return path


# ---------------------------------------------------------------------- a file where an output folder goes
@pytest.mark.parametrize("below", ["x", "press/nlipsnet", "samples/.tmp-a.npz~host~1~x"])
def test_a_path_made_through_a_file_names_the_file(a_file, below):
    """`nlips infer PRESS --out FILE` said "FILE/press: Not a directory", `nlips calibrate --out FILE`
    "FILE/samples: Not a directory": paths the user never typed, with no word of what to do."""
    try:
        (a_file / below).mkdir(parents=True)
    except NotADirectoryError as exc:
        line = describe_os_error(exc, where=a_file)
    assert line == f"{a_file}: a file where a folder is needed (choose another --out, or move the file)"


# ---------------------------------------------------------------------- refused before the long work
def test_calibrates_out_is_checked_before_any_press_is_solved(presses, a_file, monkeypatch, capsys):
    """`nlips calibrate PRESSES --out FILE` solved every press, then failed naming FILE/samples."""
    from nlipscalib.cli import calibration

    monkeypatch.setattr(calibration, "solve_all", lambda *a, **k: pytest.fail("presses solved"))
    assert main(["--no-progress", "calibrate", str(presses), "--out", str(a_file), "--min-leds", "3"]) == 2
    _one_line_error(capsys.readouterr().err, f"{a_file}: a file where a folder is needed")


@pytest.mark.parametrize("value", ["-1", "-3"])  # 0: the default count, as `nlips solve --workers 0`
def test_demos_solve_workers_is_checked_before_rendering(tmp_path, monkeypatch, capsys, value):
    """`nlips demo --solve-workers -1` rendered every press (a minute and more) before refusing the option."""
    from nlipscalib.sim import dataset

    rendered = []
    monkeypatch.setattr(dataset, "run_dataset", lambda *a, **k: rendered.append(a) or {"failed": []})
    assert main(["--no-progress", "demo", "--solve-workers", value, "--out", str(tmp_path / "demo")]) == 2
    _one_line_error(capsys.readouterr().err, f"--solve-workers: must be an integer >= 0, got {value}")
    assert rendered == []


@pytest.mark.parametrize("out", ["folder", "a file/leds.json", "new folder/"])
def test_calibrate_leds_out_is_checked_before_the_fit(presses, a_file, monkeypatch, capsys, out):
    """`nlips calibrate-leds --out FOLDER` fitted the LEDs, then said "FOLDER -> FOLDER: Is a directory"; `--out
    NEW/` (a folder meant, not there yet) wrote the LED file as NEW, printing NEW/."""
    from nlipscalib import solver

    (presses.parent / "folder").mkdir()
    monkeypatch.setattr(solver, "calibrate_leds", lambda *a, **k: pytest.fail("the fit ran"))
    target = str(presses.parent / out) + ("/" if out.endswith("/") else "")
    assert main(["--no-progress", "calibrate-leds", str(presses / "reference"), "--out", target]) == 2
    problem = "a file where a folder is needed" if out.startswith("a file") else "a folder; give the LED file to write"
    _one_line_error(capsys.readouterr().err, problem)
    assert not (presses.parent / "new folder").exists()


def test_calibrate_leds_on_a_full_disk_is_refused_before_the_fit(presses, monkeypatch, capsys):
    """`nlips calibrate-leds --out FULL/leds.json` on a full tmpfs fitted for 1-2 s, then said "No space left on
    device": its probe folder takes no block there. The free space is now checked against the file's size first."""
    import shutil
    from collections import namedtuple

    from nlipscalib import solver
    from nlipscalib.core.ledfile import led_file_bytes

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**9, 10**9 - 10240, 10240))
    monkeypatch.setattr(solver, "calibrate_leds", lambda *a, **k: pytest.fail("the fit ran"))
    out = presses.parent / "full" / "leds.json"
    assert main(["--no-progress", "calibrate-leds", str(presses / "reference"), "--out", str(out)]) == 2
    need = led_file_bytes(3) >> 10  # the test presses' 3 LEDs, one capture
    _one_line_error(
        capsys.readouterr().err,
        f"{out.parent}: No space left on device (10 KiB free, the LED file needs ~{need} KiB) (the disk is full",
    )
    assert not out.exists()


def test_a_hidden_width_out_of_reach_is_refused_before_loading_the_dataset(tmp_path, capsys):
    """`--hidden 100000000` loaded the dataset, then ran out of memory in the first batch: a torch traceback."""
    assert main(["train", str(tmp_path / "missing"), "--out", str(tmp_path / "m.pt"), "--hidden", "64,100000000"]) == 2
    _one_line_error(capsys.readouterr().err, "--hidden must list layer widths of at most 4096, got (64, 100000000)")


@pytest.mark.parametrize(
    "option, line",
    [
        (("--every", "0"), "nlips infer: error: --every: must be an integer >= 1, got 0"),
        (("--max-frames", "0"), "nlips infer: error: --max-frames: must be an integer >= 1, got 0"),
    ],
)
def test_a_streams_count_out_of_range_is_one_line_in_the_clis_wording(tmp_path, capsys, caplog, option, line):
    """A user trial: `nlips infer fast.pt video.avi --every 0` warned "--every without an output folder" before its
    error line, and --max-frames said "must be >= 1" where every other count says "must be an integer >= 1"."""
    (tmp_path / "video.avi").write_bytes(b"")  # refused before the video or the model is read
    assert main(["infer", str(tmp_path / "fast.pt"), str(tmp_path / "video.avi"), *option]) == 2
    logged = caplog.text + capsys.readouterr().err  # the log goes to pytest's handler (or to stderr)
    assert _one_line_error(logged) == line


# ---------------------------------------------------------------------- a file of the wrong kind named as such
@pytest.mark.parametrize(
    "content,problem",
    [
        ("[1, 2]", "not a camera calibration file (no 'camera' block"),  # was "list indices must be integers"
        ('{"leds": []}', "not a camera calibration file (no 'camera' block"),  # an LED file: was "('camera')"
        (None, "a folder, not a camera calibration file"),  # was "Is a directory"
    ],
)
def test_a_camera_calibration_of_the_wrong_kind_says_what_it_is(tmp_path, content, problem):
    from nlipscalib.cli.capture import _calibrated_camera
    from nlipscalib.core.errors import ConfigError

    path = tmp_path / "cam.json"
    path.mkdir() if content is None else path.write_text(content, encoding="utf-8")
    with pytest.raises(ConfigError) as caught:
        _calibrated_camera(str(path))
    assert str(caught.value).startswith(f"{path}: {problem}"), caught.value


def test_an_led_file_that_is_a_folder_is_called_a_folder(presses, tmp_path, capsys):
    """`nlips solve --leds FOLDER` said "leds must be like '1,2,5'", capture --leds FOLDER "Is a directory"."""
    from nlipscalib.core.errors import CaptureError
    from nlipscalib.core.ledfile import read_led_file

    folder = tmp_path / "leds"
    folder.mkdir()
    with pytest.raises(CaptureError, match="a folder, not an LED file"):
        read_led_file(folder)
    assert main(["--no-progress", "solve", str(presses / "p1"), "--leds", str(folder)]) == 2
    _one_line_error(capsys.readouterr().err, f"{folder}: a folder, not an LED file")


@pytest.mark.parametrize(
    "given,problem",
    [
        ("missing", "{path}: no such folder"),  # was "missing/index.json: missing; ..."
        ("a file", "{path}: a file, not a folder; {path} is not a calibration dataset"),  # was "a file/index.json"
    ],
)
def test_a_calibration_dataset_that_is_no_folder_says_so(tmp_path, a_file, capsys, given, problem):
    path = tmp_path / given
    assert main(["train", str(path), "--out", str(tmp_path / "m.pt")]) == 2
    _one_line_error(capsys.readouterr().err, problem.format(path=path))


def test_a_report_folder_that_is_a_file_is_called_a_file(a_file, capsys):
    """`nlips experiment q1 --redraw FILE` said "FILE: no such folder" of a path that exists."""
    assert main(["experiment", "q1", "--redraw", str(a_file)]) == 2
    _one_line_error(capsys.readouterr().err, f"{a_file}: a file, not a report folder")


def test_a_reconstruction_folder_given_as_a_press_is_named(presses, capsys):
    """`nlips solve PRESS/nlips` said "no press folders found"."""
    from nlipscalib.core.reconstruction import RESULT_FILE

    result = presses / "p1" / "nlips"
    result.mkdir()
    (result / RESULT_FILE).write_bytes(b"PK")
    (result / "report.json").write_text(json.dumps({}), encoding="utf-8")
    assert main(["--no-progress", "solve", str(result)]) == 2
    _one_line_error(capsys.readouterr().err, f"{result}: a reconstruction folder (result.npz), not a press")


def test_an_enotdir_below_no_file_keeps_the_systems_words(tmp_path):
    exc = NotADirectoryError(errno.ENOTDIR, "Not a directory", str(tmp_path / "gone" / "x"))
    assert describe_os_error(exc) == f"{tmp_path / 'gone' / 'x'}: Not a directory"


# ---------------------------------------------------------------------- a folder of presses for one capture
@pytest.mark.parametrize("command", ["calibrate-leds", "solve --reference", "calibrate --reference"])
def test_a_folder_of_presses_for_the_undeformed_capture_names_its_reference(presses, tmp_path, capsys, command):
    """`nlips calibrate-leds DATASET`, `nlips solve PRESS --reference DATASET` and `nlips calibrate PRESSES --reference
    DATASET` said "DATASET/meta.json: missing; DATASET is not a complete press folder", not that the dome they
    wanted is DATASET/reference."""
    if command == "calibrate-leds":
        args = ["calibrate-leds", str(presses), "--out", str(tmp_path / "leds.json")]
    elif command == "solve --reference":
        args = ["solve", str(presses / "p1"), "--reference", str(presses)]
    else:
        args = ["calibrate", str(presses), "--reference", str(presses), "--out", str(tmp_path / "calibration")]
    assert main(["--no-progress", *args]) == 2
    _one_line_error(
        capsys.readouterr().err,
        f"{presses}: a folder of presses, not ",
        f"its undeformed dome is {presses / 'reference'} (give that)",
    )
    assert not (tmp_path / "leds.json").exists() and not (presses / "p1" / "nlips").exists()
    assert not (tmp_path / "calibration").exists()


def test_a_folder_of_presses_without_a_reference_asks_for_one_capture(presses, tmp_path, capsys):
    """Without reference/ (a folder of presses of the user's own) the line still says what the folder is."""
    (presses / "reference").rename(presses / "p0")
    assert main(["--no-progress", "calibrate-leds", str(presses), "--out", str(tmp_path / "leds.json")]) == 2
    _one_line_error(capsys.readouterr().err, f"{presses}: a folder of presses, not ", "give one capture's folder")


def test_calibrate_on_one_press_of_a_dataset_names_the_dataset(presses, tmp_path, capsys):
    """`nlips calibrate DATASET/p1` said "no reference/ capture of the undeformed dome; name one with --reference",
    and following it calibrated that one press alone (too few to train on)."""
    out = tmp_path / "calibration"
    assert main(["--no-progress", "calibrate", str(presses / "p1"), "--out", str(out)]) == 2
    _one_line_error(
        capsys.readouterr().err,
        f"{presses / 'p1'}: one press, not a folder of presses; its folder {presses} holds them and their reference/",
    )
    assert not out.exists()


def test_calibrate_on_a_datasets_reference_names_it_and_the_dataset(presses, tmp_path, capsys):
    """`nlips calibrate DATASET/reference` said "DATASET/reference: one press, not a folder of presses": it is the
    dataset's undeformed dome, no press."""
    out = tmp_path / "calibration"
    assert main(["--no-progress", "calibrate", str(presses / "reference"), "--out", str(out)]) == 2
    _one_line_error(
        capsys.readouterr().err,
        f"{presses / 'reference'}: the undeformed dome's capture of {presses}, not a folder of presses; give {presses}",
    )
    assert not out.exists()


def test_calibrate_on_a_folder_without_presses_says_so_before_asking_for_a_reference(tmp_path, capsys):
    """`nlips calibrate EMPTY` (or a folder of something else) said "no reference/ capture of the undeformed dome;
    name one with --reference"; given one, it then said "no press folders found": the presses come first."""
    empty = tmp_path / "empty"
    empty.mkdir()
    out = tmp_path / "calibration"
    assert main(["--no-progress", "calibrate", str(empty), "--out", str(out)]) == 2
    _one_line_error(capsys.readouterr().err, f"{empty}: no press folders found")
    assert not out.exists()


# ---------------------------------------------------------------------- a path given with ~
def test_a_tilde_the_shell_left_alone_is_the_home_folder_not_a_folder_named_tilde(presses, tmp_path, monkeypatch):
    """`nlips solve PRESS --out=~/res` (bash expands no ~ after "=", nor inside quotes) made ./~/res in the working
    folder (s25 walk); now the result goes to the home folder, and so does an input given so."""
    home, work = tmp_path / "home", tmp_path / "work"
    home.mkdir(), work.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(work)
    (home / "presses").symlink_to(presses)
    assert main(["solve", "~/presses/p1", "--out=~/res", "--no-figures", "--no-progress"]) == 0
    assert (home / "res" / "result.npz").is_file() and not (work / "~").exists()


@pytest.mark.parametrize(
    "command, option, example",
    [
        (["export", "{tmp}/m.pt", "--out", "{typed}"], "--out", "a folder; give the ONNX file to write (e.g. "),
        (["train", "{tmp}/data", "--out", "{typed}"], "--out", "a folder; give the model file to write in it"),
        (
            ["calibrate-camera-response", "--emulate", "nlipstac", "--out", "{tmp}/r.json", "--figure", "{typed}"],
            "--figure",
            "a folder; give the PNG file to write (e.g. ",
        ),
        (
            ["experiment", "q1", "--out", "{tmp}/work", "--write-baseline", "{typed}"],
            "--write-baseline",
            "is a folder; give a file name",
        ),
    ],
    ids=lambda c: c[0] if isinstance(c, list) else "",
)
def test_a_file_option_typed_as_a_folder_is_one_line(tmp_path, monkeypatch, capsys, command, option, example):
    """`nlips export MODEL --out x.onnx/` (a folder meant, not there yet) wrote the file x.onnx; `train --out m.pt/`,
    `calibrate-camera-response --figure figs/` and `experiment --write-baseline b.json/` wrote theirs the same way
    (pathlib drops the slash), or failed after the work on "Is a directory"."""
    from nlipscalib.experiments import framework

    monkeypatch.setattr(framework, "run_experiment", lambda *a, **k: pytest.fail("the experiment ran"))
    typed = f"{tmp_path / 'new.onnx'}/"
    argv = [part.format(tmp=tmp_path, typed=typed) for part in command]
    assert main(["--no-progress", *argv]) == 2
    line = _one_line_error(capsys.readouterr().err, f"{option} {typed}: {example}")
    assert "Traceback" not in line
    assert not (tmp_path / "new.onnx").exists()
