"""`nlips solve` and `nlips eval` as a user runs them: honest re-runs, damaged results, figures, both methods."""

import dataclasses
import json
import logging
import shutil

import pytest

from nlipscalib.cli import main
from nlipscalib.core.capture import load_press
from nlipscalib.core.metrics import evaluate
from nlipscalib.core.reconstruction import load_reconstruction, save_reconstruction
from tests.solver import synth
from tests.solver.twin_helpers import recorded_anew


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli_presses")
    synth.make_press(root / "press_a", "sphere", size=(64, 48))
    synth.make_press(root / "press_b", "cube", size=(64, 48))
    return root


@pytest.fixture
def data(dataset, tmp_path):
    shutil.copytree(dataset, tmp_path / "d")
    cfg = tmp_path / "solver.toml"
    cfg.write_text("max_iters = 5\n", encoding="utf-8")
    return tmp_path / "d", cfg


def _stamp(press):
    return (press / "nlips" / "result.npz").stat().st_mtime_ns


def _log(caplog, capsys) -> str:
    """What the command logged (pytest's handler receives it; stderr has it when none is installed)."""
    text = caplog.text + capsys.readouterr().err
    caplog.clear()
    return text


def test_solve_again_with_new_options_re_solves_and_identical_skips(data, capsys, caplog):
    root, cfg = data
    caplog.set_level(logging.INFO)
    press = root / "press_a"
    assert main(["solve", str(press), "--config", str(cfg), "--no-progress"]) == 0
    first = _stamp(press)
    assert main(["solve", str(press), "--config", str(cfg), "--no-progress"]) == 0
    assert _stamp(press) == first and "identical result exists, skipped" in _log(caplog, capsys)
    assert main(["solve", str(press), "--config", str(cfg), "--roi", "auto", "--no-progress"]) == 0
    assert _stamp(press) != first  # new options: re-solved, not "result exists"
    assert "made with other settings or inputs (roi), re-solving" in _log(caplog, capsys)
    report = json.loads((press / "nlips" / "report.json").read_text(encoding="utf-8"))
    assert report["provenance"]["settings"]["roi"] == "auto" and report["roi"] is not None
    assert main(["solve", str(press), "--config", str(cfg), "--leds", "1,3,5,7,9,11", "--no-progress"]) == 0
    assert json.loads((press / "nlips" / "report.json").read_text(encoding="utf-8"))["provenance"]["settings"][
        "led_subset"
    ] == [
        1,
        3,
        5,
        7,
        9,
        11,
    ]
    used = json.loads((press / "nlips" / "report.json").read_text(encoding="utf-8"))["leds_used"]
    assert used == [0, 2, 4, 6, 8, 10]  # the capture's 0-based LED indices, not positions in the subset
    flags = ["--leds", "1,3,5,7,9,11", "--interreflection", "off", "--no-progress"]
    assert main(["solve", str(press), "--config", str(cfg), *flags]) == 0
    # named as the user gives it (--interreflection), not by the record's grouping (solver_keywords)
    assert "made with other settings or inputs (interreflection), re-solving" in _log(caplog, capsys)


def test_damaged_result_is_recomputed_by_solve_and_eval(data, capsys, caplog):
    root, cfg = data
    assert main(["solve", str(root), "--config", str(cfg), "--workers", "2", "--no-progress"]) == 0
    said = capsys.readouterr()  # stdout: each result's folder alone, one a line; the counts on stderr
    assert said.out.splitlines() == [str(root / p / "nlips") for p in ("press_a", "press_b")]
    assert "2 solved, 0 skipped" in said.err
    npz = root / "press_a" / "nlips" / "result.npz"
    npz.write_bytes(npz.read_bytes()[:-200])  # truncated
    assert main(["eval", str(root)]) == 0  # re-computed from the recorded settings, then scored
    out = capsys.readouterr().out
    log = caplog.text
    assert "press_a" in out and "press_b" in out and "damaged or truncated" in log and "re-computing" in log
    assert log.count("damaged or truncated") == 1  # eval's warning, not the solve's again
    assert load_reconstruction(root / "press_a" / "nlips").report["provenance"]["settings"]["options"]["max_iters"] == 5
    npz.write_bytes(b"garbage")
    assert main(["solve", str(root), "--config", str(cfg), "--no-progress"]) == 0
    assert "1 solved, 1 skipped" in capsys.readouterr().err
    assert load_reconstruction(root / "press_a" / "nlips").reconstructed.any()


def test_eval_of_a_result_whose_settings_are_unknown_says_how_to_re_solve_it(data, tmp_path, capsys, caplog):
    """Garbage in report.json: nothing to re-compute from, so no "re-computing" and no "re-solving failed". One
    press: its one line on stderr, exit 2 (it was printed on stdout, exit 1, as a folder's table row)."""
    root, cfg = data
    press, other = root / "press_a", tmp_path / "elsewhere"
    assert main(["solve", str(press), "--config", str(cfg), "--no-progress"]) == 0
    (press / "nlips" / "report.json").write_text("garbage", encoding="utf-8")
    caplog.set_level(logging.INFO)
    capsys.readouterr()
    assert main(["eval", str(press)]) == 2
    captured = capsys.readouterr()
    lines = [line for line in captured.err.splitlines() if line.strip()]
    assert len(lines) == 1 and not captured.out.strip() and "Traceback" not in captured.err, captured
    assert lines[0].startswith("nlips eval: error: ")
    assert str(press / "nlips" / "report.json") in lines[0] and "not valid JSON" in lines[0]
    assert "the settings it was solved with are unknown" in lines[0]
    assert f"`nlips solve {press} --overwrite`" in lines[0] and "re-solving failed" not in lines[0]
    assert "re-computing" not in caplog.text + captured.err
    # a result in another folder whose record has no settings: the command names that folder too
    assert main(["solve", str(press), "--config", str(cfg), "--out", str(other), "--no-progress"]) == 0
    report = json.loads((other / "report.json").read_text(encoding="utf-8"))
    del report["provenance"]
    (other / "report.json").write_text(json.dumps(report), encoding="utf-8")
    (other / "result.npz").write_bytes(b"garbage")
    capsys.readouterr()
    assert main(["eval", str(press), "--result", str(other)]) == 2
    out = capsys.readouterr().err
    assert "result.npz" in out and f"{other / 'report.json'} records no solve settings" in out
    assert f"`nlips solve {press} --out {other} --overwrite`" in out


def test_eval_scores_nlips_and_nlipsnet_alike(data, capsys):
    root, cfg = data
    press = root / "press_a"
    assert main(["solve", str(press), "--config", str(cfg), "--no-progress"]) == 0
    # an "NLiPsNet" result in the same format: here the exact truth, so its scores are known (zero)
    gt = load_press(press).ground_truth
    nlips = load_reconstruction(press / "nlips")
    exact = dataclasses.replace(
        nlips,
        normals=gt.normals,
        depth=gt.depth,
        points=gt.points,
        reconstructed=gt.valid,
        mask=gt.valid,
        report={"method": "nlipsnet"},
    )
    save_reconstruction(exact, press / "nlipsnet")
    capsys.readouterr()
    assert main(["eval", str(press / "nlipsnet")]) == 0
    said = capsys.readouterr()  # stdout: the table alone; what it scores, on stderr
    assert f"scoring {press / 'nlipsnet'}" in said.err  # the method came from the folder's name
    row = next(line for line in said.out.splitlines() if line.startswith("press_a")).split()
    # zero up to arccos near 1 on float32 unit vectors (~0.01 deg); depth exactly zero
    assert int(row[1]) == gt.valid.sum() and float(row[2]) < 0.02 and float(row[4]) == 0.0
    assert main(["eval", str(root), "--method", "nlipsnet"]) == 0
    assert "no nlipsnet result (not inferred), skipped: press_b" in capsys.readouterr().err
    assert main(["eval", str(press / "nlips")]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("press_a")).split()
    assert float(row[4]) > 0.0 and float(row[2]) < 5.0  # NLiPs on exact data: small but not exact
    assert main(["eval", str(press / "nlips"), "--method", "nlipsnet"]) == 2
    npz = press / "nlipsnet" / "result.npz"
    npz.write_bytes(npz.read_bytes()[:100])
    assert main(["eval", str(root), "--method", "nlipsnet"]) == 1  # not re-made here: named, exit 1
    out = capsys.readouterr().err
    # with the command that makes it again (the model the report names; this report names none)
    assert "damaged, not scored: press_a" in out and f"make it again with `nlips infer MODEL.pt {press}`" in out
    report = json.loads((press / "nlipsnet" / "report.json").read_text(encoding="utf-8"))
    (press / "nlipsnet" / "report.json").write_text(
        json.dumps(report | {"model": "/lab/models/net.pt"}), encoding="utf-8"
    )
    assert main(["eval", str(press), "--method", "nlipsnet"]) == 2  # one press: on stderr
    assert f"make it again with `nlips infer /lab/models/net.pt {press}`" in capsys.readouterr().err


def test_eval_header_names_what_is_scored(data, capsys):
    """The table's header said `scoring PRESS/nlips` whatever PATH was. That line is on stderr: stdout holds the
    table alone, its column heads first (a script reading the scores)."""
    root, cfg = data
    assert main(["solve", str(root), "--config", str(cfg), "--no-progress"]) == 0
    capsys.readouterr()
    press = root / "press_a"
    for path, header in (
        (root, f"scoring {root / '*' / 'nlips'}"),
        (press, f"scoring {press / 'nlips'}"),
        (press / "nlips", f"scoring {press / 'nlips'}"),
    ):
        assert main(["eval", str(path)]) == 0
        said = capsys.readouterr()
        assert header in said.err.splitlines() and said.out.split()[:2] == ["press", "pixels"]


def test_eval_quiet_prints_the_table_alone_and_still_says_what_it_left_out(data, capsys):
    """`nlips eval`'s product is its table: stdout, alone (no "scoring" line above it, no notes below it); with
    --quiet stderr says only what was not scored (a warning), not what was."""
    import shutil

    root, cfg = data
    assert main(["solve", str(root), "--config", str(cfg), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["-q", "eval", str(root)]) == 0
    out, err = capsys.readouterr()
    assert [line.split()[0] for line in out.splitlines()] == ["press", "press_a", "press_b", "mean", "pooled"]
    assert err == ""
    shutil.rmtree(root / "press_b" / "nlips")
    assert main(["-q", "eval", str(root)]) == 0
    out, err = capsys.readouterr()
    assert [line.split()[0] for line in out.splitlines()] == ["press", "press_a"]
    assert err == "not solved, skipped: press_b\n"


@pytest.mark.parametrize("method", ["nlipsnet", "lut"])
def test_eval_names_presses_without_a_network_or_table_result_as_not_inferred(data, capsys, method):
    """A new lab's walk: `nlips eval SESSION --method nlipsnet` after inferring only the held-out presses said
    "not solved, skipped: press_0001, ..." of presses NLiPs had solved: it now names the missing result."""
    root, cfg = data
    assert main(["solve", str(root), "--config", str(cfg), "--no-progress"]) == 0
    shutil.copytree(root / "press_a" / "nlips", root / "press_a" / method)  # a result in the core format
    capsys.readouterr()
    assert main(["-q", "eval", str(root), "--method", method]) == 0
    out, err = capsys.readouterr()
    assert [line.split()[0] for line in out.splitlines()] == ["press", "press_a"]
    assert err == f"no {method} result (not inferred), skipped: press_b\n"


def test_eval_of_several_presses_gives_their_mean_and_the_pooled_figures(data, capsys):
    """A folder of presses ended with the mean of the per-press figures only (each press counted once, whatever
    its size); the pooled row scores all their pixels together, checked against the pixels scored by hand."""
    import numpy as np

    from nlipscalib.core.metrics import angle_deg

    root, cfg = data
    assert main(["solve", str(root), "--config", str(cfg), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["eval", str(root), "--region", "contact"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == ["press", "press_a", "press_b", "mean", "pooled"]
    pixels, aae, mabse, rmse = lines[-1].split()[1:]
    angles, components, depth = [], [], []
    for name in ("press_a", "press_b"):
        gt, rec = load_press(root / name).ground_truth, load_reconstruction(root / name / "nlips")
        m = gt.valid & rec.reconstructed & gt.contact
        angles.append(angle_deg(rec.normals[m], gt.normals[m]))
        components.append(np.abs(rec.normals[m] - gt.normals[m]).ravel())
        depth.append(rec.depth[m] - gt.depth[m])
    assert int(pixels) == sum(len(a) for a in angles)
    assert float(aae) == pytest.approx(np.concatenate(angles).mean(), abs=1e-3)
    assert float(mabse) == pytest.approx(np.concatenate(components).mean(), abs=1e-4)
    assert float(rmse) == pytest.approx(np.sqrt(np.mean(np.concatenate(depth) ** 2)), abs=1e-4)
    per_press = [float(line.split()[2]) for line in lines[2:4]]
    assert per_press[0] != per_press[1]  # else mean and pooled could not differ


def test_eval_scores_a_result_solved_into_another_folder(data, tmp_path, capsys):
    root, cfg = data
    press, other = root / "press_a", tmp_path / "elsewhere"
    assert main(["solve", str(press), "--config", str(cfg), "--out", str(other), "--no-progress"]) == 0
    assert not (press / "nlips").exists()
    capsys.readouterr()
    assert main(["eval", str(other)]) == 2  # outside its press: no ground truth to score against; says how
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"nlips eval PRESS --result {other}" in err[0]
    assert main(["eval", str(press), "--result", str(other)]) == 0
    said = capsys.readouterr()
    assert f"scoring {other} against {press}" in said.err
    row = next(line for line in said.out.splitlines() if line.startswith("press_a")).split()
    scores = evaluate(load_reconstruction(other), load_press(press).ground_truth)["all"]
    assert int(row[1]) == scores["pixels"] > 0 and float(row[2]) == pytest.approx(scores["aae_deg"], abs=1e-3)
    assert main(["eval", str(press), "--result", str(other), "--method", "nlipsnet"]) == 2  # the report says nlips
    assert "--method nlipsnet" in capsys.readouterr().err
    assert main(["eval", str(root), "--result", str(other)]) == 2  # PATH must be the one press
    assert "--result needs PATH to be the press folder" in capsys.readouterr().err
    assert main(["eval", str(press), "--result", str(tmp_path / "none")]) == 2
    assert "--result" in capsys.readouterr().err


def test_eval_says_which_command_makes_the_missing_result(data, capsys):
    root, _ = data
    assert main(["eval", str(root / "press_a"), "--method", "nlipsnet"]) == 2
    err = capsys.readouterr().err
    # the command to run names the folder given (it said `nlips infer MODEL.pt PATH`, PATH literally)
    assert f"`nlips infer MODEL.pt {root / 'press_a'}`" in err and "nlips solve" not in err
    assert main(["eval", str(root / "press_a")]) == 2
    assert f"`nlips solve {root / 'press_a'}`" in capsys.readouterr().err


def test_figures_flags(data):
    root, cfg = data
    press = root / "press_b"
    assert main(["solve", str(press), "--config", str(cfg), "--no-figures", "--no-progress"]) == 0
    assert not list((press / "nlips").glob("*.png"))
    # the same settings again, now asking for figures: the result is kept and gets them (it was skipped as
    # identical and the figures never came without --overwrite, which re-solved)
    stamp = _stamp(press)
    assert main(["solve", str(press), "--config", str(cfg), "--no-progress"]) == 0
    maps = {"normals.png", "depth.png", "residual.png", "error.png"}
    assert {p.name for p in (press / "nlips").glob("*.png")} == maps
    assert main(["solve", str(press), "--config", str(cfg), "--figures", "full", "--no-progress"]) == 0
    assert (press / "nlips" / "summary.png").is_file() and _stamp(press) == stamp  # never re-solved
    assert main(["solve", str(press), "--config", str(cfg), "--figures", "full", "--overwrite", "--no-progress"]) == 0
    pngs = {p.name for p in (press / "nlips").glob("*.png")}
    assert pngs == {"normals.png", "depth.png", "residual.png", "error.png", "summary.png"}
    normals = (press / "nlips" / "normals.png").read_bytes()
    assert normals[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_arguments_are_one_line(data, capsys):
    root, cfg = data
    assert main(["solve", str(root), "--workers", "-1"]) == 2
    assert "--workers: must be an integer >= 0, got -1" in capsys.readouterr().err
    assert main(["solve", str(root / "press_a"), "--leds", "one"]) == 2
    assert "leds must be like '1,2,5'" in capsys.readouterr().err
    assert main(["solve", str(root / "press_a"), "--roi", "1", "2"]) == 2
    assert "--roi" in capsys.readouterr().err
    for spelling in ("--coating-reflectance", "--coating-albedo"):  # the former name, still taken
        assert main(["solve", str(root / "press_a"), spelling, "2"]) == 2
        assert "coating reflectance (--coating-reflectance) must be" in capsys.readouterr().err
    assert main(["solve", "--roi", "auto"]) == 2
    assert "press folder is missing" in capsys.readouterr().err
    # a --reference that is not there: one line before any solving (was a failure line per press, exit 1)
    assert main(["solve", str(root), "--reference", str(root / "nothing"), "--no-progress"]) == 2
    out, err = capsys.readouterr()
    assert err.strip() == f"nlips solve: error: {root / 'nothing'}: not a press folder (no such directory)"
    assert "failed" not in out and not (root / "press_a" / "nlips").exists()


def test_settings_that_do_not_fit_the_capture_are_refused_before_anything_is_said(data, capsys, caplog):
    root, cfg = data
    press = root / "press_a"
    assert main(["solve", str(press), "--config", str(cfg), "--no-progress"]) == 0
    caplog.clear()
    capsys.readouterr()
    assert main(["solve", str(press), "--roi", "500", "0", "10", "10", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "roi (500, 0, 10, 10) must lie inside" in err[0]
    assert main(["solve", str(press), "--leds", "1,2,40", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has LEDs 1..12" in err[0]
    # two LEDs: the solver loaded the press and said "only 2 LED images are lit (dead: [])"
    assert main(["solve", str(press), "--leds", "1,7", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "nlips solve: error: leds [1, 7]: 2 LED(s); NLiPs needs at least 3 (a normal and an albedo per pixel)"
    ]
    other = root.parent / "other_sensor"  # an undeformed capture of another LED ring
    synth.make_press(other, "none", size=(64, 48), leds=synth.ring_leds(tilt_deg=40))
    assert main(["solve", str(press), "--reference", str(other), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{other}: not a capture of the sensor of {press}" in err[0]
    assert "re-solving" not in caplog.text and "identical result" not in caplog.text


def test_a_capture_of_another_image_size_says_which_sizes(data, tmp_path, capsys):
    """`nlips solve PRESS --reference REF` and `nlips calibrate-leds A B` with REF or B rendered at another
    --width/--height said only "camera or LED count differs", leaving the user to find which."""
    root, cfg = data
    press = root / "press_a"  # 64x48
    small = synth.make_press(tmp_path / "small_reference", "none", size=(32, 24))
    assert main(["solve", str(press), "--reference", str(small), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(
        f"{small}: not a capture of the sensor of {press} (its images are 32x24 pixels, those of {press} 64x48)"
    ), err
    reference = synth.make_press(tmp_path / "reference", "none", size=(64, 48))
    leds = tmp_path / "leds.json"
    assert main(["--no-progress", "calibrate-leds", str(reference), str(small), "--out", str(leds)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "its images are 32x24 pixels, those of" in err[0] and not leds.exists(), err


@pytest.mark.parametrize("roi", [["0,0,0,0"], ["10", "10", "3", "3"], ["60", "10", "10", "10"]])
def test_a_roi_too_small_or_outside_states_the_one_true_minimum(data, capsys, roi):
    """`--roi 0,0,0,0` said "w, h >= 1" while `--roi 150 110 20 20` said "at least 4x4"."""
    root, cfg = data
    assert main(["solve", str(root / "press_a"), "--roi", *roi, "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith("at least 4x4 pixels") and ">= 1" not in err[0], err


def test_the_press_may_follow_the_roi(data, capsys):
    root, cfg = data
    press = root / "press_a"
    assert main(["solve", "--roi", "auto", str(press), "--config", str(cfg), "--no-progress"]) == 0
    assert (
        json.loads((press / "nlips" / "report.json").read_text(encoding="utf-8"))["provenance"]["settings"]["roi"]
        == "auto"
    )
    assert main(["solve", "--roi", "2", "3", "40", "30", str(press), "--config", str(cfg), "--no-progress"]) == 0
    assert json.loads((press / "nlips" / "report.json").read_text(encoding="utf-8"))["roi"] == [2, 3, 40, 30]
    # typed with commas, as `--leds 1,5,9` is (it was "--roi needs 'x0 y0 w h' or 'auto', got 2,3,40,30")
    assert main(["solve", "--roi", "2,3,40,31", str(press), "--config", str(cfg), "--no-progress"]) == 0
    assert json.loads((press / "nlips" / "report.json").read_text(encoding="utf-8"))["roi"] == [2, 3, 40, 31]


def test_demo_recomputes_a_damaged_cached_result(data, capsys):
    from nlipscalib.cli import demo

    root, _ = data
    press = load_press(root / "press_b")
    first = demo._solve(press, figures=False)
    npz = root / "press_b" / "nlips" / "result.npz"
    npz.write_bytes(npz.read_bytes()[:5000])  # was a BadZipFile traceback
    again = demo._solve(press, figures=False)
    assert again.reconstructed.sum() == first.reconstructed.sum()
    assert load_reconstruction(root / "press_b" / "nlips").reconstructed.any()


def test_unwritable_output_is_one_line_before_solving(data, capsys, monkeypatch):
    import errno

    from nlipscalib.core import atomic

    root, cfg = data

    def read_only(folder, longest_name=0):
        raise OSError(errno.EROFS, "Read-only file system", str(folder))

    monkeypatch.setattr(atomic, "check_writable", read_only)
    assert main(["solve", str(root), "--config", str(cfg), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "Read-only file system" in err and str(root / "press_a") in err and "Traceback" not in err
    assert not (root / "press_a" / "nlips").exists() and not (root / "press_b" / "nlips").exists()


def test_eval_refuses_a_result_of_another_press_unless_told(data, tmp_path, capsys, caplog):
    """It warned and printed the score of press_b's result against press_a's ground truth: a wrong number."""
    root, cfg = data
    press, other = root / "press_a", tmp_path / "of_b"
    assert main(["solve", str(root / "press_b"), "--config", str(cfg), "--out", str(other), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["eval", str(press), "--result", str(other)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and not captured.out, captured
    assert f"--result {other} was made from another capture, not from {press}" in err[0]
    assert "--other-capture" in err[0]
    caplog.set_level(logging.WARNING)
    assert main(["eval", str(press), "--result", str(other), "--other-capture"]) == 0
    assert "press_a" in capsys.readouterr().out
    assert f"{other}: made from another capture, not from {press}; --other-capture: scored if" in caplog.text
    assert main(["eval", str(press), "--other-capture"]) == 2
    assert "--other-capture is only used with --result" in capsys.readouterr().err


def test_eval_other_capture_refuses_a_result_of_another_sensors_surface(data, tmp_path, capsys):
    """--other-capture scored a NLiPsTac result against a fingertip press of the same image size without a word
    (34.9 deg, 3.8 mm; QA walk s26-mismatch): a result whose depth lies far from the press's true surface is one
    line, exit 2; another capture of the same sensor still scores (the test above)."""
    root, cfg = data
    press, other = root / "press_a", tmp_path / "of_b"
    assert main(["solve", str(root / "press_b"), "--config", str(cfg), "--out", str(other), "--no-progress"]) == 0
    report = (other / "report.json").read_text(encoding="utf-8")
    rec = load_reconstruction(other)
    save_reconstruction(dataclasses.replace(rec, depth=rec.depth + 1.0), other, overwrite=True)  # a dome 1 mm off
    (other / "report.json").write_text(report, encoding="utf-8")
    capsys.readouterr()
    assert main(["eval", str(press), "--result", str(other), "--other-capture"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and not captured.out and "Traceback" not in captured.err, captured
    assert f"--result {other}: its depth is 1.0" in err[0] and f"from {press}'s true surface" in err[0]


def test_eval_warns_that_a_result_recording_no_input_cannot_be_checked(data, tmp_path, capsys, caplog):
    """A result written outside `nlips solve`/`nlips infer` (save_reconstruction) or by an older nlipscalib: scored,
    with a warning that says it was not checked."""
    root, cfg = data
    press, other = root / "press_a", tmp_path / "elsewhere"
    assert main(["solve", str(press), "--config", str(cfg), "--out", str(other), "--no-progress"]) == 0
    report = json.loads((other / "report.json").read_text(encoding="utf-8"))
    del report["provenance"]["inputs"]
    (other / "report.json").write_text(json.dumps(report), encoding="utf-8")
    caplog.set_level(logging.WARNING)
    capsys.readouterr()
    assert main(["eval", str(press), "--result", str(other)]) == 0
    assert "press_a" in capsys.readouterr().out
    assert f"{other}: its report.json records no input identity" in caplog.text
    assert f"cannot check that it was made from {press}" in caplog.text


def test_eval_does_not_score_a_result_its_press_was_recaptured_since(data, capsys):
    """`nlips eval PRESS` scored PRESS/nlips without checking that it was made from the press as it is now: a press
    captured again into the same folder (or a result copied in) gave the old result's score against the new truth."""
    root, cfg = data
    press = root / "press_a"
    assert main(["solve", str(root), "--config", str(cfg), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["eval", str(root)]) == 0
    shutil.copytree(root / "press_b" / "nlips", press / "nlips", dirs_exist_ok=True)  # press_a's folder, b's result
    assert main(["eval", str(root)]) == 1
    said = capsys.readouterr()
    err = said.err
    assert (
        "press_b" in said.out
        and f"outdated, not scored: press_a: {press / 'nlips'} was made from another capture" in err
    )
    assert f"remake it: `nlips solve {press} --overwrite`" in err


def test_a_press_whose_tricolor_image_is_corrupt_still_solves(data, capsys, caplog):
    """`nlips solve` does not solve with the tri-colour image: its check against the LED images
    (core.tricolor_check, s37-swapcheck) says the file cannot be read, a warning, and the press is solved; the
    dataset builder, which needs it, still says which file is broken, in one line."""
    from nlipscalib.core.errors import CaptureError
    from nlipscalib.learn.dataset import reference_arrays

    root, cfg = data
    press = root / "press_a"
    (press / "tricolor.png").write_bytes(b"garbage")
    assert main(["solve", str(press), "--config", str(cfg), "--no-progress"]) == 0
    assert (press / "nlips" / "result.npz").is_file()
    assert "(no PNG signature); the tri-colour frame is not compared with the LED images" in caplog.text
    with pytest.raises(CaptureError, match=r"tricolor\.png: not a readable PNG image \(no PNG signature\)$"):
        reference_arrays(load_press(press))


def test_a_solve_without_figures_reads_no_ground_truth(data, capsys, caplog):
    """gt.npz is read for error.png only: `--no-figures` solves a press whose gt.npz is damaged (~0.06 s of CPU less at
    640x480); with figures the result and its other figures are published, and one warning names the file and says
    that error.png is skipped (the solve stopped there, exit 2, though it needs no ground truth)."""
    root, cfg = data
    press = root / "press_a"
    (press / "gt.npz").write_bytes(b"PK garbage")
    assert main(["solve", str(press), "--config", str(cfg), "--no-figures", "--no-progress"]) == 0
    assert (press / "nlips" / "result.npz").is_file() and not list((press / "nlips").glob("*.png"))
    out = root / "with_figures"
    capsys.readouterr()
    assert main(["solve", str(press), "--config", str(cfg), "--out", str(out), "--no-progress"]) == 0
    logged = caplog.text + capsys.readouterr().err  # pytest's handler receives the log; stderr has it without one
    warned = [line for line in logged.splitlines() if "gt.npz" in line]
    assert len(warned) == 1 and str(press / "gt.npz") in warned[0], warned
    assert "ground truth is damaged; the error figure (error.png) is skipped" in warned[0]
    assert (out / "result.npz").is_file() and (out / "depth.png").is_file() and not (out / "error.png").exists()


def test_a_damaged_ground_truth_array_costs_the_error_figure_and_is_named_by_eval(data, capsys, caplog):
    """gt.npz's arrays are read at their first use (the error map's three, a score's four): a damaged one read by
    the figures is still one warning naming the file and the array, the result published without error.png; `nlips
    eval`, which needs it, says so in one line and exits 2."""
    from tests.core.test_reconstruction import _spoil_deflated_member

    root, cfg = data
    press = root / "press_a"
    _spoil_deflated_member(press / "gt.npz", "contact.npy")
    capsys.readouterr()
    assert main(["solve", str(press), "--config", str(cfg), "--no-progress"]) == 0
    warned = [line for line in _log(caplog, capsys).splitlines() if "gt.npz" in line]
    assert len(warned) == 1 and f"{press / 'gt.npz'}: array 'contact' is not readable" in warned[0], warned
    assert "the error figure (error.png) is skipped" in warned[0]
    assert (press / "nlips" / "depth.png").is_file() and not (press / "nlips" / "error.png").exists()
    assert main(["eval", str(press)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{press / 'gt.npz'}: array 'contact' is not readable" in err[0], err


def test_eval_of_a_captured_press_says_only_twin_renders_carry_ground_truth(data, capsys):
    """`nlips eval SESSION` (a capture session's presses) said "PRESS: no ground truth (gt.npz) to evaluate against",
    leaving the user to wonder what made gt.npz go missing: a captured press never has one."""
    root, cfg = data
    press = root / "press_a"
    meta = json.loads((press / "meta.json").read_text(encoding="utf-8"))
    meta["ground_truth"] = None  # as `nlips capture` writes it
    (press / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    assert main(["solve", str(press), "--config", str(cfg), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["eval", str(press)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"nlips eval: error: {press}: no ground truth (gt.npz) to evaluate against: only twin renders (nlips render, "
        "dataset, demo) carry one; a captured press has none"
    ], err


def _as_twin_render(folder, **render) -> None:
    """Record ``folder`` as a twin render of the scene whose [render] section is ``render`` (meta.json provenance)."""
    path = folder / "meta.json"
    meta = json.loads(path.read_text(encoding="utf-8"))
    meta["provenance"] = {"source": "sim", "scene": {"name": "nlipstac", "render": render, "noise": {"enabled": True}}}
    path.write_text(json.dumps(meta), encoding="utf-8")


def test_a_twin_reference_rendered_with_other_light_settings_is_refused_in_one_line(data, tmp_path, capsys):
    """`nlips render --undeformed` at the scene's defaults (direct light, 4 spp) given as --reference of a press
    rendered with --bounces 1 --spp 16: the term fitted on it came out off (share 0.014), then "--roi auto found no
    contact (images match the undeformed dome)", exit 2, or on the whole gel "anchoring off: weak evidence", exit 0.
    Another sample count alone (the experiments' references have more) is the same sensor."""
    root, _ = data
    press = root / "press_a"
    reference = synth.make_press(tmp_path / "reference", "none", size=(64, 48))
    _as_twin_render(press, bounces=1, spp=16, seed=3)
    _as_twin_render(reference, bounces=0, spp=4, seed=0)
    assert main(["solve", str(press), "--reference", str(reference), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{reference}: rendered with other twin settings than {press}" in err[0], err
    assert "(render.bounces 0 here, 1 for the press)" in err[0] and not (press / "nlips").exists()
    # `nlips calibrate` says it once before solving (it failed every press alike, one ERROR line each)
    _as_twin_render(root / "press_b", bounces=1, spp=16, seed=4)
    assert main(["calibrate", str(root), "--reference", str(reference), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"nlips calibrate: error: --reference {reference}: rendered with"), err
    assert "solve without --reference" not in err[0]  # calibrate always solves with one (it offered that anyway)
    assert not (press / "nlips").exists() and not (root / "calibration").exists()
    _as_twin_render(reference, bounces=1, spp=64, seed=0)
    assert main(["solve", str(press), "--reference", str(reference), "--no-progress"]) == 0
    assert (press / "nlips" / "result.npz").is_file()


def _record_source(folder, **provenance) -> None:
    """Record in ``folder``'s meta.json what made it (``provenance``; none given: no provenance, as a capture
    written by other software)."""
    path = folder / "meta.json"
    meta = json.loads(path.read_text(encoding="utf-8"))
    meta["provenance"] = provenance or None
    path.write_text(json.dumps(meta), encoding="utf-8")


def test_a_press_solved_against_an_undeformed_capture_of_another_source_is_one_warning(data, tmp_path, caplog):
    """A twin press solved against the emulated sensor's reference (s33-e2e records each capture's source) was
    solved without a word; a lab may mix them on purpose, so it is said, once, and the solve goes on. Two captures
    of one source, or one that records none (other software's), say nothing."""
    root, cfg = data
    press = root / "press_a"
    reference = synth.make_press(tmp_path / "reference", "none", size=(64, 48))
    caplog.set_level(logging.WARNING)
    cases = (
        ({"source": "sim"}, {"source": "device", "device": "emulator"}, "a capture of the emulated sensor"),
        ({"source": "device", "device": {"port": "/dev/ttyACM0"}}, {"source": "sim"}, "a twin render"),
        (
            {"source": "device", "device": "emulator"},
            {"source": "device", "device": {"port": "COM3"}},
            "a capture of a sensor",
        ),
        ({"source": "sim"}, {"source": "sim"}, None),
        ({"source": "sim"}, {}, None),
    )
    for ours, theirs, said in cases:
        _record_source(press, **ours)
        _record_source(reference, **theirs)
        args = ["solve", str(press), "--reference", str(reference), "--config", str(cfg), "--no-progress"]
        assert main(args) == 0
        lines = [r.getMessage() for r in caplog.records if "solved against the undeformed capture" in r.getMessage()]
        if said is None:
            assert lines == [], (ours, theirs, lines)
        else:
            assert len(lines) == 1 and lines[0].startswith(f"{press}: "), lines
            assert f"solved against the undeformed capture {reference}, {said}" in lines[0], lines
        caplog.clear()


def test_a_folders_default_worker_count_is_one_per_two_cores_lowered_to_memory(data, monkeypatch):
    """``nlips solve FOLDER`` ran one worker whatever the cores. Now one per two usable cores (each press already
    solves on two threads: one worker on a 2-core machine, as before), fewer where memory holds fewer; ``--workers``
    is obeyed."""
    import nlipscalib.pipeline as pipeline
    from nlipscalib.core import cpus

    root, cfg = data
    asked = []
    monkeypatch.setattr(pipeline, "solve_presses", lambda presses, workers, **kw: asked.append(workers) or {})
    monkeypatch.setattr(cpus, "available_memory", lambda: 64 * 10**9)
    for cores, workers in ((2, 1), (3, 1), (4, 2), (8, 4)):
        monkeypatch.setattr(cpus, "usable_cores", lambda cores=cores: cores)
        main(["solve", str(root), "--config", str(cfg), "--no-progress"])
        assert asked.pop() == workers, cores
    main(["solve", str(root), "--config", str(cfg), "--workers", "3", "--no-progress"])
    assert asked.pop() == 3
    monkeypatch.setattr(cpus, "available_memory", lambda: 10**8)  # 0.1 GB: one worker at most
    main(["solve", str(root), "--config", str(cfg), "--no-progress"])
    assert asked.pop() == 1


def test_solve_and_calibrate_leds_take_the_coating_reflectance_by_one_name():
    """`nlips solve --coating-albedo A` and `nlips calibrate-leds --coating-reflectance A` set the same quantity (the
    coating's reflectance, IndirectModel.with_reflectance) under two names. Both take --coating-reflectance now;
    solve's former spelling still works (scripts), and its help shows the one name."""
    import argparse

    from nlipscalib.cli import build_parser

    parser = build_parser()
    for spelling in ("--coating-reflectance", "--coating-albedo"):
        assert parser.parse_args(["solve", "PRESS", spelling, "0.7"]).coating_albedo == 0.7
    assert parser.parse_args(["calibrate-leds", "REF", "--out", "x.json", "--coating-reflectance", "0.7"])
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    text = " ".join(commands["solve"].format_help().split())
    assert "--coating-reflectance A" in text and "formerly --coating-albedo, still accepted" in text
    assert "--coating-albedo A" not in text  # hidden: one name per idea


def test_eval_names_the_results_other_nlipscalib_code_made(data, capsys):
    """After an upgrade `nlips eval` printed an old result's scores like any other, and a lab read them as this
    version's (`nlips solve` would have made it again). The scores stay; one line names those results."""
    root, cfg = data
    assert main(["solve", str(root), "--config", str(cfg), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["eval", str(root)]) == 0
    assert "other nlipscalib code" not in capsys.readouterr().err  # this installation's results
    for name, code in (("press_a", "0" * 32), ("press_b", None)):  # other code; a result of before 2026-12-06
        path = root / name / "nlips" / "report.json"
        report = json.loads(path.read_text(encoding="utf-8"))
        report["provenance"]["code"] = code
        if code is None:
            del report["provenance"]["code"]
        path.write_text(json.dumps(report), encoding="utf-8")
    assert main(["eval", str(root)]) == 0
    said = capsys.readouterr()
    assert said.err.splitlines()[-1] == (
        f"made by other nlipscalib code, scored as they are: press_a, press_b (`nlips solve {root}` makes them with "
        "this version)"
    ), said.err
    out = said.out.splitlines()
    assert any(line.startswith("press_a ") for line in out) and any(line.startswith("press_b ") for line in out)


def test_a_press_with_two_neighbouring_led_images_exchanged_is_refused_in_one_line(data, capsys):
    """led_03.png and led_04.png renamed into each other's place: `nlips solve` solved it silently. Now one line
    naming the press and both files, exit 2, nothing written; --keep-led-order solves it as captured."""
    root, cfg = data
    press = root / "press_a"
    (press / "led_03.png").rename(press / "x.png")
    (press / "led_04.png").rename(press / "led_03.png")
    (press / "x.png").rename(press / "led_04.png")
    recorded_anew(press)  # captured so: its record names the files as they are (not an edit after capture)
    capsys.readouterr()
    assert main(["--no-progress", "solve", str(press), "--config", str(cfg), "--no-figures"]) == 2
    err = capsys.readouterr().err
    (line,) = [text for text in err.splitlines() if text.strip()]
    assert f"{press}: led_03.png and led_04.png look exchanged" in line and "Traceback" not in err
    assert not (press / "nlips" / "result.npz").exists()
    assert main(["--no-progress", "solve", str(press), "--config", str(cfg), "--no-figures", "--keep-led-order"]) == 0
    report = json.loads((press / "nlips" / "report.json").read_text(encoding="utf-8"))
    assert report["leds_exchanged"] == [[2, 3]]


def test_an_led_file_with_two_neighbouring_leds_exchanged_is_named_in_the_refusal(data, capsys):
    """`nlips solve PRESS --leds FILE`, FILE holding LED 3 at LED 4's place and back (calibrated on exchanged
    images, kept so), the press clean: the line blamed the press's images ("the LED model misplaces those LEDs")
    and named no file. Now it names FILE as the likelier exchanged; exit 2, nothing written."""
    root, cfg = data
    press = root / "press_a"
    leds = json.loads((press / "meta.json").read_text(encoding="utf-8"))["leds"]
    leds[2], leds[3] = leds[3], leds[2]
    led_file = root / "leds_exchanged.json"
    led_file.write_text(json.dumps({"leds": leds}), encoding="utf-8")
    capsys.readouterr()
    argv = ["--no-progress", "solve", str(press), "--config", str(cfg), "--no-figures", "--leds", str(led_file)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    (line,) = [text for text in err.splitlines() if text.strip()]
    assert f"{press}: led_03.png and led_04.png look exchanged" in line and "Traceback" not in err
    assert f"{led_file} is the likelier exchanged" in line and "misplaces those LEDs" not in line
    assert not (press / "nlips" / "result.npz").exists()
