"""nlips infer: reconstructions in the core format, PLY, frames, only changed pixels through the network."""

from pathlib import Path

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core import load_press, load_reconstruction
from nlipscalib.core.errors import ConfigError
from nlipscalib.core.metrics import evaluate
from nlipscalib.core.tolerances import MIN_REFERENCE_COLOUR
from nlipscalib.learn.infer import Predictor
from nlipscalib.learn.prefilter import Prefilter

from .conftest import HELD_OUT

MODELS = ("trained", "trained_ratio")
"""The tests' models: the paper's (linear colour inputs) and the default's (colour ratios), both on every path."""


@pytest.mark.parametrize("trained_model", MODELS)
def test_infer_press_writes_a_scorable_reconstruction_and_ply(trained_model, twin_presses, tmp_path, capsys, request):
    trained = request.getfixturevalue(trained_model)
    out = tmp_path / "out"
    assert main(["infer", str(trained), str(twin_presses / HELD_OUT), "--out", str(out), "--mesh"]) == 0
    stdout, said = capsys.readouterr()
    assert stdout == f"{out / HELD_OUT / 'nlipsnet'}\n"  # the result's folder alone; the summary on stderr
    assert "frames/s" in said
    # the result's own folder, which `nlips eval PRESS --result` takes (it named OUT/PRESS/, the folder above it)
    assert f"saved: 1 result folder(s) in {out / HELD_OUT / 'nlipsnet'}/ (result.npz, report.json, points.ply, " in said
    press = load_press(twin_presses / HELD_OUT)
    rec = load_reconstruction(out / HELD_OUT / "nlipsnet", press.camera.shape)
    scores = evaluate(rec, press.ground_truth)["contact"]
    assert scores["aae_deg"] < 8.0 and scores["depth_rmse_mm"] < 0.4, scores
    assert rec.report["model"] == str(trained.resolve())  # absolute: `nlips eval` names it from anywhere
    head = (out / HELD_OUT / "nlipsnet" / "points.ply").read_bytes()[:400]
    assert b"element vertex" in head and b"element face" in head


def test_the_result_folder_is_published_with_its_ply_or_not_at_all(
    trained, twin_presses, tmp_path, capsys, monkeypatch
):
    import errno
    import os

    from nlipscalib.learn import ply

    def disk_full(path, *args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    out = tmp_path / "out"
    monkeypatch.setattr(ply, "write_ply", disk_full)
    assert main(["infer", str(trained), str(twin_presses / HELD_OUT), "--out", str(out), "--ply"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "No space left on device" in err[0], err
    assert not (out / HELD_OUT / "nlipsnet").exists()  # no result without the points.ply asked for
    assert not [p for p in out.rglob("*") if p.name.startswith(".tmp-")]
    monkeypatch.undo()
    assert main(["infer", str(trained), str(twin_presses / HELD_OUT), "--out", str(out), "--ply"]) == 0
    assert sorted(p.name for p in (out / HELD_OUT / "nlipsnet").iterdir()) == [
        "depth.png",
        "error.png",
        "normals.png",
        "points.ply",
        "report.json",
        "result.npz",
    ]


@pytest.mark.parametrize("trained_model", MODELS)
def test_unchanged_pixels_keep_the_reference_and_skip_the_network(trained_model, twin_presses, request):
    """Only the changed pixels go through the network, given the colours its training samples were (filtered; for a
    model of colour ratios the runtime divides them by its reference's: the ONNX graph does, and PyTorch's runner,
    so the runner is given the filtered linear colours either way); the rest keep the undeformed dome's normals,
    whatever the network would say there."""
    predictor = Predictor(request.getfixturevalue(trained_model))
    calls = []
    run = predictor._run
    predictor._run = lambda x: calls.append(len(x)) or run(x)
    ref = load_press(twin_presses / "reference")
    frame = predictor.predict(ref.linear(ref.tricolor))
    assert calls == [] or calls == [0] or sum(calls) < 0.01 * predictor.valid.sum()
    assert frame.changed.sum() < 0.01 * predictor.valid.sum()
    press = load_press(twin_presses / HELD_OUT)
    calls.clear()
    frame = predictor.predict(press.linear(press.tricolor))
    assert sum(calls) == frame.changed.sum() > 0
    # the network sees the colours filtered as the model's training samples were
    inputs = []
    predictor._run = lambda x: inputs.append(x.copy()) or run(x)
    tri = press.linear(press.tricolor)
    predictor.predict(tri)
    x = np.concatenate(inputs)
    assert predictor.model.smoothing_px > 0 and predictor.model.smoothing_colour > 0  # the defaults
    prefilter = Prefilter(predictor.valid, predictor.model.smoothing_px, predictor.model.smoothing_colour)
    colours = prefilter(tri)
    divide = predictor.model.input_reference
    if divide is not None:  # a model of colour ratios: the reference frame itself is 1 wherever it lies above the floor
        assert predictor.model.colour_input == "ratio"
        # filtered with the reference's own Gaussian (TrainConfig.reference_smoothing_px, 3 px by default)
        assert predictor.model.reference_smoothing_px == 3.0
        ones = Prefilter(predictor.valid, 3.0, 0.0)(ref.linear(ref.tricolor)) / divide
        lit = predictor.valid & (divide > MIN_REFERENCE_COLOUR).all(-1)
        assert lit.sum() > 0.9 * predictor.valid.sum()
        np.testing.assert_allclose(ones[lit], 1.0, atol=1e-6)
    np.testing.assert_allclose(x[:, 2:], colours[x[:, 1].astype(int), x[:, 0].astype(int)], atol=1e-6)
    same = predictor.valid & ~frame.changed
    np.testing.assert_array_equal(frame.normals[same], predictor.ref_normals[same])


def test_infer_folder_of_png_frames_with_onnx(trained, twin_presses, tmp_path, capsys):
    import shutil

    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.onnx_export import export_onnx

    export_onnx(load_model(trained), trained.with_suffix(".onnx"))
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, name in enumerate(("press_a", "press_b", HELD_OUT)):
        shutil.copy(twin_presses / name / "tricolor.png", frames / f"frame_{i}.png")
    assert main(["infer", str(trained), str(frames), "--backend", "onnx", "--out", str(tmp_path / "o")]) == 0
    assert "3 frame(s), onnx" in capsys.readouterr().err
    assert (tmp_path / "o" / "frame_2" / "result.npz").is_file()


def test_nlips_eval_scores_the_nlipsnet_reconstruction(trained, twin_presses, tmp_path, capsys):
    import shutil

    press = tmp_path / HELD_OUT
    shutil.copytree(twin_presses / HELD_OUT, press)
    assert main(["infer", str(trained), str(press)]) == 0
    assert (press / "nlipsnet" / "result.npz").is_file()
    capsys.readouterr()
    assert main(["eval", str(press), "--method", "nlipsnet", "--region", "contact"]) == 0
    assert HELD_OUT in capsys.readouterr().out


def test_press_folder_without_meta_json_is_not_taken_for_frames(trained, twin_presses, tmp_path, capsys):
    import shutil

    press = tmp_path / "incomplete"
    shutil.copytree(twin_presses / HELD_OUT, press, ignore=shutil.ignore_patterns("meta.json", "nlips"))
    out = tmp_path / "out"
    assert main(["infer", str(trained), str(press), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "incomplete" in err[0] and "meta.json" in err[0] and "press folder" in err[0]
    assert not out.exists()


@pytest.mark.parametrize(
    "option, message",
    [
        (("--max-frames", "3"), "--max-frames is for a stream"),
        (("--every", "3"), "--every is for a stream"),
        (("--tricolor-level", "100"), "--tricolor-level is not used with press folders"),
        (("--exposure-ms", "5"), "--exposure-ms sets a live camera's exposure"),
    ],
)
def test_stream_options_on_press_folders_are_refused(trained, twin_presses, tmp_path, capsys, option, message):
    """They did nothing there, without a word, while --port or --adalight were refused."""
    assert main(["infer", str(trained), str(twin_presses / HELD_OUT), "--out", str(tmp_path / "o"), *option]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


@pytest.mark.parametrize("option", [("--max-frames", "0"), ("--threads", "-1")])
def test_infer_refuses_out_of_range_options(trained, twin_presses, tmp_path, capsys, option):
    assert main(["infer", str(trained), str(twin_presses / HELD_OUT), "--out", str(tmp_path / "o"), *option]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"error: {option[0]}" in err[0] and option[1] in err[0]
    assert not (tmp_path / "o").exists()
    with pytest.raises(ConfigError, match="threads"):
        Predictor(trained, threads=-1)


def _angle_deg(a, b):
    return np.degrees(np.arccos(np.clip((a * b).sum(-1), -1.0, 1.0)))


def test_eight_bit_png_jpeg_and_upper_case_frames_are_inferred_like_16_bit_ones(
    trained, twin_presses, tmp_path, caplog
):
    """A lab's frames: 8-bit PNG and JPEG (were refused or streamed as a video), FRAME.PNG (was skipped), notes."""
    import logging

    import cv2

    caplog.set_level(logging.INFO)
    bgr16 = cv2.imread(str(twin_presses / HELD_OUT / "tricolor.png"), cv2.IMREAD_UNCHANGED)
    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "a16.PNG"), bgr16)
    cv2.imwrite(str(frames / "b8.png"), (bgr16 >> 8).astype(np.uint8))
    cv2.imwrite(str(frames / "c8.jpg"), (bgr16 >> 8).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 98])
    (frames / "notes.txt").write_text("press g, 2026-12-03", encoding="utf-8")
    out = tmp_path / "o"
    assert main(["infer", str(trained), str(frames), "--backend", "torch", "--out", str(out)]) == 0
    assert "notes.txt" in caplog.text and "skipped" in caplog.text
    assert caplog.text.count("an 8-bit image") == 1  # once per command, not per frame
    shape = load_press(twin_presses / HELD_OUT).camera.shape
    full = load_reconstruction(out / "a16", shape)
    changed = full.report["changed_pixels"]
    assert changed > 0
    for name in ("b8", "c8"):
        rec = load_reconstruction(out / name, shape)
        # the same pixels change and the network sees the same colours up to 8-bit rounding: a swapped channel
        # order or another scaling would change (nearly) every pixel or none, and turn the normals far away
        assert abs(rec.report["changed_pixels"] - changed) < 0.25 * changed, (name, rec.report, changed)
        both = full.mask & np.isfinite(rec.normals).all(-1)
        assert np.median(_angle_deg(rec.normals[both], full.normals[both])) < 0.5
        assert np.percentile(_angle_deg(rec.normals[both], full.normals[both]), 95) < 10.0


def test_a_grey_image_is_refused_in_one_line(trained, twin_presses, tmp_path, capsys):
    import cv2

    grey = tmp_path / "grey.png"
    cv2.imwrite(str(grey), cv2.imread(str(twin_presses / HELD_OUT / "tricolor.png"), cv2.IMREAD_UNCHANGED)[..., 1])
    assert main(["infer", str(trained), str(grey), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "grey.png" in err[0] and "3 colour channels, found 1" in err[0], err
    assert not (tmp_path / "o").exists()


def test_a_frame_unlike_the_reference_everywhere_is_warned_about(trained, twin_presses, tmp_path, caplog, capsys):
    """Red and blue swapped (BGR saved as RGB): no pixel stood out, the undeformed dome came back silently."""
    import logging

    import cv2

    caplog.set_level(logging.WARNING)
    bgr16 = cv2.imread(str(twin_presses / HELD_OUT / "tricolor.png"), cv2.IMREAD_UNCHANGED)
    assert main(["infer", str(trained), str(twin_presses / HELD_OUT), "--out", str(tmp_path / "good")]) == 0
    assert "differs from the calibration's reference" not in caplog.text
    swapped = tmp_path / "swapped.png"
    cv2.imwrite(str(swapped), np.ascontiguousarray(bgr16[..., ::-1]))
    assert main(["infer", str(trained), str(swapped), "--out", str(tmp_path / "o")]) == 0
    assert "swapped.png: differs from the calibration's reference" in caplog.text and "BGR" in caplog.text
    assert "times as bright" not in caplog.text  # as bright as the reference: the colours are what differ
    dim = tmp_path / "twelve_bit.png"  # 12-bit values in a 16-bit file, as some cameras store them
    cv2.imwrite(str(dim), bgr16 >> 4)
    caplog.clear()
    assert main(["infer", str(trained), str(dim), "--out", str(tmp_path / "o")]) == 0
    assert "twelve_bit.png: differs from the calibration's reference" in caplog.text
    assert "times as bright" in caplog.text and "bit depth" in caplog.text and "BGR" not in caplog.text
    # a stream of such frames: the warning once, and how many frames it concerned at the end
    seq = tmp_path / "seq"
    seq.mkdir()
    for i in range(3):
        cv2.imwrite(str(seq / f"img_{i:04d}.png"), np.ascontiguousarray(bgr16[..., ::-1]))
    caplog.clear()
    assert main(["infer", str(trained), str(seq / "img_%04d.png"), "--out", str(tmp_path / "s")]) == 0
    assert caplog.text.count("differs from the calibration's reference") == 1
    assert "3 of 3 frames differed" in caplog.text


def test_a_twin_press_rendered_otherwise_names_the_setting_not_the_exposure(trained, twin_presses, tmp_path, caplog):
    """A press rendered with interreflections (the model's presses had none) was "1.2 times as bright: was it taken
    at the calibration's exposure and LED level ...?"; the model records its presses' capture settings, so the
    warning names the render setting that differs."""
    import logging

    from nlipscalib.sim.press import render_press

    from .conftest import PRESSES, small_twin

    caplog.set_level(logging.WARNING)
    other = tmp_path / "bounced"
    render_press(small_twin().replace(render={"bounces": 2}), PRESSES[HELD_OUT], other, seed=16)
    assert main(["infer", str(trained), str(other), "--out", str(tmp_path / "o")]) == 0
    assert f"{other}: differs from the calibration's reference" in caplog.text
    assert "other settings than the calibration's presses (scene.render.bounces: 0 -> 2)" in caplog.text
    assert "calibration's exposure" not in caplog.text


def test_a_model_without_led_geometry_warns_and_infers_while_a_whole_one_refuses_another_ring(
    trained, twin_presses, tmp_path, caplog, capsys
):
    """Models trained before 2026-12-03 lack led_positions/led_directions: usable, with a warning naming the file."""
    import json
    import logging
    import shutil

    import torch

    caplog.set_level(logging.WARNING)
    payload = torch.load(trained, weights_only=True)
    del payload["sensor"]["led_positions"], payload["sensor"]["led_directions"]
    old = tmp_path / "old.pt"
    torch.save(payload, old)
    other = tmp_path / "other_ring"
    shutil.copytree(twin_presses / HELD_OUT, other, ignore=shutil.ignore_patterns("nlips*"))
    meta = json.loads((other / "meta.json").read_text(encoding="utf-8"))
    for led in meta["leds"]:
        led["position"][2] += 1.5  # a ring 1.5 mm higher: another sensor
    (other / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    assert main(["infer", str(trained), str(other), "--out", str(tmp_path / "new")]) == 2
    assert "another sensor" in capsys.readouterr().err
    assert "records no LED geometry" not in caplog.text
    assert main(["infer", str(old), str(other), "--out", str(tmp_path / "o")]) == 0
    assert f"{old}: records no LED geometry" in caplog.text and "cannot be checked" in caplog.text
    assert (tmp_path / "o" / "other_ring" / "nlipsnet" / "result.npz").is_file()


def test_a_folder_or_the_onnx_export_given_as_the_model_says_which_file_to_give(
    trained, twin_presses, tmp_path, capsys
):
    import shutil

    models = tmp_path / "models"
    models.mkdir()
    shutil.copy(trained, models / "net.pt")
    (models / "net.onnx").write_bytes(b"\x08\x07onnx-ish")
    (tmp_path / "renamed.onnx").write_bytes(trained.read_bytes())  # a .pt renamed: was "not a readable ONNX model"
    cases = {
        models: "a folder, not a model file: give the .pt file from `nlips train` (it holds net.pt)",
        models / "net.onnx": f"the ONNX export, not the model file: give the .pt file from `nlips train` ({models}",
        tmp_path / "renamed.onnx": "the ONNX export, not the model file",
    }
    for model, expected in cases.items():
        assert main(["infer", str(model), str(twin_presses / HELD_OUT), "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{model}: {expected}" in err[0], err
    assert not (tmp_path / "o").exists()


def test_a_folder_of_presses_infers_its_presses_not_its_reference(trained, twin_presses, tmp_path, capsys):
    import shutil

    root = tmp_path / "presses"
    for name in ("reference", "press_a", "press_b"):
        shutil.copytree(twin_presses / name, root / name, ignore=shutil.ignore_patterns("nlips"))
    assert main(["infer", str(trained), str(root)]) == 0
    said = capsys.readouterr().err
    assert said.startswith("2 frame(s)")
    assert f"saved: 2 result folder(s) in each press's nlipsnet/ (e.g. {root / 'press_a' / 'nlipsnet'})" in said
    assert (root / "press_a" / "nlipsnet").is_dir() and not (root / "reference" / "nlipsnet").exists()
    assert main(["infer", str(trained), str(root / "reference")]) == 0  # named itself, it is inferred
    assert (root / "reference" / "nlipsnet" / "result.npz").is_file()


def test_two_inputs_for_one_result_folder_are_refused_before_inferring(trained, twin_presses, tmp_path, capsys, caplog):
    """Two presses of one name (two datasets) into one --out: the second silently replaced the first's result."""
    import logging
    import shutil

    other = tmp_path / "copy" / HELD_OUT
    shutil.copytree(twin_presses / HELD_OUT, other, ignore=shutil.ignore_patterns("nlips*"))
    out = tmp_path / "o"
    assert main(["infer", str(trained), str(twin_presses / HELD_OUT), str(other), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"would both be written to {out / HELD_OUT / 'nlipsnet'}" in err[0], err
    assert not out.exists()
    # without --out each press keeps its own result; a frame without --out is said to be written nowhere
    caplog.set_level(logging.WARNING)
    assert main(["infer", str(trained), str(other), str(other / "tricolor.png")]) == 0
    assert (other / "nlipsnet" / "result.npz").is_file()
    assert "image frames without --out: their results are not written" in caplog.text


def test_a_frame_whose_name_holds_a_percent_sign_is_a_still_not_a_sequence_pattern(
    trained, twin_presses, tmp_path, capsys
):
    import shutil

    frame = tmp_path / "press 50%.png"
    shutil.copy(twin_presses / HELD_OUT / "tricolor.png", frame)
    assert main(["infer", str(trained), str(frame), "--out", str(tmp_path / "o")]) == 0
    assert capsys.readouterr().err.startswith("1 frame(s)")  # the stills' summary, not a stream's
    assert (tmp_path / "o" / "press 50%" / "result.npz").is_file()


def test_nlipsnet_results_record_their_input_and_eval_refuses_another_press(
    trained, twin_presses, tmp_path, capsys, caplog
):
    """NLiPsNet results recorded no input, so `nlips eval PRESS --result` scored another press's result against
    PRESS's ground truth without a word. Now a press's result records the capture identity NLiPs records, an image
    frame's the file's, and eval refuses a mismatch in one line (--other-capture scores it anyway)."""
    import json
    import logging
    import shutil

    from nlipscalib.pipeline import capture_identity

    held, other = twin_presses / HELD_OUT, twin_presses / "press_a"
    out = tmp_path / "out"
    assert main(["infer", str(trained), str(held), str(other), "--out", str(out)]) == 0
    report = json.loads((out / HELD_OUT / "nlipsnet" / "report.json").read_text(encoding="utf-8"))
    assert report["provenance"]["inputs"] == {"press": capture_identity(held)}
    capsys.readouterr()
    assert main(["eval", str(held), "--result", str(out / HELD_OUT / "nlipsnet")]) == 0
    capsys.readouterr()  # its table (stdout) and what it scored (stderr): not the refusal's
    assert main(["eval", str(held), "--result", str(out / "press_a" / "nlipsnet")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "made from another capture (it names 'press_a'), not from" in err[0], err
    assert main(["eval", str(held), "--result", str(out / "press_a" / "nlipsnet"), "--other-capture"]) == 0
    # an image frame: its file's identity, the press's when it is that press's tri-colour image
    frames = tmp_path / "frames"
    frames.mkdir()
    shutil.copy(held / "tricolor.png", frames / "held.png")
    assert main(["infer", str(trained), str(frames), "--out", str(tmp_path / "f")]) == 0
    capsys.readouterr()
    assert main(["eval", str(held), "--result", str(tmp_path / "f" / "held")]) == 0
    assert main(["eval", str(other), "--result", str(tmp_path / "f" / "held")]) == 2
    assert "was made from the image frame 'held', not from" in capsys.readouterr().err
    # a result written before inputs were recorded: still scored, with a warning that it was not checked
    old = out / HELD_OUT / "nlipsnet" / "report.json"
    old.write_text(json.dumps({k: v for k, v in report.items() if k != "provenance"}), encoding="utf-8")
    caplog.set_level(logging.WARNING)
    assert main(["eval", str(held), "--result", str(old.parent)]) == 0
    assert "records no input identity (written by an older nlipscalib" in caplog.text


def test_a_damaged_frame_of_a_sequence_ends_the_stream_with_one_line_after_the_frames_before_it(
    trained, twin_presses, tmp_path, capsys
):
    """A damaged file in an image sequence used to end the stream as if the recording had ended, exit 0."""
    import shutil

    seq = tmp_path / "seq"
    seq.mkdir()
    for i in range(4):
        shutil.copy(twin_presses / HELD_OUT / "tricolor.png", seq / f"img_{i:04d}.png")
    (seq / "img_0002.png").write_bytes(b"damaged")
    out = tmp_path / "o"
    assert main(["infer", str(trained), str(seq / "img_%04d.png"), "--out", str(out)]) == 2  # bad input
    captured = capsys.readouterr()
    assert captured.err.startswith("2 frames in")  # the summary of the frames before it
    err = [line for line in captured.err.strip().splitlines() if "error" in line]
    assert len(err) == 1 and "img_0002.png: not a readable image (the stream stopped there, after 2 frames)" in err[0]
    assert (out / "stream.json").is_file()


def test_a_destination_holding_other_things_is_refused_and_another_models_result_is_named(
    trained, twin_presses, tmp_path, caplog, capsys
):
    """A result replaces its folder whole: a user's folder at PRESS/nlipsnet is refused before inferring (it
    used to be replaced); a result of another model is replaced, with a line naming that model."""
    import logging
    import shutil

    import torch

    press = tmp_path / "press"
    shutil.copytree(twin_presses / HELD_OUT, press, ignore=shutil.ignore_patterns("nlips*"))
    (press / "nlipsnet").mkdir()
    (press / "nlipsnet" / "notes.txt").write_text("mine", encoding="utf-8")
    assert main(["infer", str(trained), str(press)]) == 2
    err = capsys.readouterr().err
    assert f"{press / 'nlipsnet'}: exists and holds other things than a reconstruction (notes.txt)" in err
    assert (press / "nlipsnet" / "notes.txt").read_text(encoding="utf-8") == "mine"

    shutil.rmtree(press / "nlipsnet")
    payload = torch.load(trained, weights_only=True)
    payload["info"]["note"] = "another model"  # a copy of the same bytes is the same model: its result is kept
    other = tmp_path / "other.pt"
    torch.save(payload, other)
    caplog.set_level(logging.INFO)
    assert main(["infer", str(other), str(press)]) == 0
    assert "replacing the result of another model" not in caplog.text
    assert main(["infer", str(trained), str(press)]) == 0
    assert f"replacing the result of another model ({other.resolve()})" in caplog.text


def test_results_of_a_folder_of_presses_are_scored_against_their_presses(trained, twin_presses, tmp_path, capsys):
    """`nlips infer MODEL PRESSES --out DIR` writes DIR/PRESS/nlipsnet; `nlips eval DIR` found "no press folders"
    and nothing scored them together. Now `nlips eval PRESSES --result DIR` does, and eval DIR says so."""
    import shutil

    presses = tmp_path / "presses"
    presses.mkdir()
    for name in ("press_a", HELD_OUT):
        shutil.copytree(twin_presses / name, presses / name, ignore=shutil.ignore_patterns("nlips*"))
    out = tmp_path / "inferred"
    assert main(["infer", str(trained), str(presses), "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["eval", str(out)]) == 2
    err = capsys.readouterr().err
    assert "holds results" in err and f"nlips eval PRESSES --result {out}" in err
    shutil.copytree(twin_presses / "press_b", presses / "press_b", ignore=shutil.ignore_patterns("nlips*"))
    assert main(["eval", str(presses), "--result", str(out)]) == 0
    table, said = capsys.readouterr()  # stdout: the table alone; what it scored and left out, on stderr
    assert "press_a" in table and HELD_OUT in table and "mean" in table and "press_b" not in table
    assert (
        f"scoring {out}/*/nlipsnet against {presses}/*" in said
        and "no nlipsnet result (not inferred), skipped: press_b" in said
    )
    assert main(["eval", str(presses), "--result", str(tmp_path)]) == 2
    assert "holds no result of the presses" in capsys.readouterr().err


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    """A tiny model of the exact-data sensor (64x48, no rendering: seconds), with the presses it came from."""
    return tiny_model_and_presses(tmp_path_factory.mktemp("exposure_model"))


def tiny_model_and_presses(root: Path) -> tuple[Path, Path]:
    """(model file, folder of its presses): presses NAMES of the exact-data sensor solved, sampled and trained
    (tests/learn/test_resume's TINY net) under ``root``; tests/cli/test_infer_watch's model too."""
    from nlipscalib.learn.dataset import CalibrationDataset, build_dataset
    from nlipscalib.learn.train import train
    from nlipscalib.pipeline import solve_folder
    from nlipscalib.solver import SolverOptions
    from tests.learn.test_resume import NAMES, TINY
    from tests.solver import synth

    synth.make_press(root / "reference", "none", size=(64, 48))
    for name, kind in zip(NAMES, ("sphere", "cube", "sphere")):
        synth.make_press(root / name, kind, size=(64, 48))
        solve_folder(root / name, options=SolverOptions(max_iters=6), figures=False, progress=False)
    build_dataset([root / n for n in NAMES], root / "reference", root / "calib", progress=False)
    out = root / "m.pt"
    train(CalibrationDataset(root / "calib"), TINY, out, progress=False)
    return out, root


def test_a_model_file_names_its_dataset_by_name_and_samples_not_by_where_it_lay(tiny_model, tmp_path):
    """info.dataset held the dataset's absolute path: a training of the same data elsewhere wrote other bytes (another
    model digest, on which `nlips infer` keys its results), and a shared model told the lab's folder layout. Now the
    folder's name and the digest of the samples trained on; an older file (an absolute path there) still loads."""
    import shutil

    import torch

    from nlipscalib.learn.dataset import CalibrationDataset
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.train import train
    from tests.learn.test_resume import TINY

    model, root = tiny_model
    moved = tmp_path / "elsewhere" / "calib"
    shutil.copytree(root / "calib", moved)
    again = tmp_path / "again.pt"
    train(CalibrationDataset(moved), TINY, again, progress=False)
    first, second = (torch.load(path, weights_only=True)["info"] for path in (model, again))
    assert first["dataset"] == second["dataset"] == "calib"
    assert len(first["samples_digest"]) == 16 and first["samples_digest"] == second["samples_digest"]
    assert str(root).encode() not in model.read_bytes() and str(tmp_path).encode() not in again.read_bytes()

    payload = torch.load(model, weights_only=True)
    payload["info"] = {k: v for k, v in payload["info"].items() if k != "samples_digest"}
    payload["info"]["dataset"] = str((root / "calib").resolve())  # as written before 2026-12-06
    older = tmp_path / "older.pt"
    torch.save(payload, older)
    assert load_model(older).info["dataset"] == str((root / "calib").resolve())


def test_a_calibration_dataset_given_as_input_is_named_as_such(tiny_model, tmp_path, capsys):
    """`nlips infer MODEL DATASET/calibration` took the calibration dataset for a folder of frames: two warnings
    (no --out, coverage.png 8-bit), then "coverage.png: image is 1078x1100, the model was calibrated for ..."."""
    model, root = tiny_model
    out = tmp_path / "out"
    assert main(["--no-progress", "infer", str(model), str(root / "calib"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"nlips infer: error: {root / 'calib'}: a calibration dataset (`nlips calibrate`), not presses or frames: "
        f"infer the presses it was made from (e.g. {root}), or give the dataset to `nlips train`"
    ], err
    assert not out.exists()


def test_a_reconstruction_folder_given_as_input_names_its_press(tiny_model, tmp_path, capsys):
    """`nlips infer MODEL PRESS/nlips` took the result folder for a folder of frames: its figures inferred, or each
    refused by size ("normals.png: image is 54x57, the model was calibrated for 160x120 images"), exit 1 (s34-walk)."""
    from tests.learn.test_resume import NAMES

    model, root = tiny_model
    result = root / NAMES[0] / "nlips"
    (result / "normals.png").write_bytes((root / NAMES[0] / "tricolor.png").read_bytes())  # a figure of its size
    out = tmp_path / "out"
    assert main(["--no-progress", "infer", str(model), str(result), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"nlips infer: error: {result}: a reconstruction folder (result.npz: a solve's or an inference's maps), not "
        f"presses or frames: infer the press it was made from ({root / NAMES[0]})"
    ], err
    assert not out.exists()
    (result / "normals.png").unlink()


def test_black_and_saturated_frames_are_called_so_never_a_negative_brightness(tiny_model, tmp_path, caplog, capsys):
    """A black frame (all 0, below the calibration's dark frame) was "-0.037 times as bright"; a saturated one "2.3
    times as bright", with no word of clipping (the audit's frames_black, frames_sat, video_black.avi)."""
    import logging
    import re

    import cv2

    from nlipscalib.learn.infer import Frame, mismatch_warning

    model, root = tiny_model
    caplog.set_level(logging.WARNING)
    frames = {
        "black.png": np.zeros((48, 64, 3), np.uint16),
        "saturated.png": np.full((48, 64, 3), 65535, np.uint16),
        "saturated8.png": np.full((48, 64, 3), 255, np.uint8),  # an 8-bit frame's 255: 65280 once shifted up
    }
    for name, image in frames.items():
        cv2.imwrite(str(tmp_path / name), image)
    for name, expected in (
        ("black.png", "the frame is black (no light above the black level: LEDs off, lens cap, camera not streaming?)"),
        ("saturated.png", "100 % of the gel is saturated (at the white level), and it is"),
        ("saturated8.png", "100 % of the gel is saturated (at the white level)"),
    ):
        caplog.clear()
        assert main(["infer", str(model), str(tmp_path / name), "--out", str(tmp_path / name[:-4])]) == 0
        assert f"{name}: differs from the calibration's reference" in caplog.text and expected in caplog.text
        assert not re.search(r"-\d[\d.]* times as bright", caplog.text), caplog.text
    # both predictor paths measure it alike (the whole frame's too), and a frame made elsewhere never reads negative
    for full in (False, True):
        predictor = Predictor(model, full_frame=full)
        black = predictor.predict_stored(frames["black.png"])
        assert black.brightness == 0.0 and black.saturated == 0.0
        assert predictor.predict_stored(frames["saturated.png"]).saturated == 1.0
        press = load_press(root / "a_sphere")
        assert predictor.predict_stored(press.tricolor).saturated == 0.0  # measured only for a mismatched frame
    odd = Frame(*(np.zeros(1),) * 4, {}, brightness=-0.5, mismatch=1.0)
    assert "the frame is black" in mismatch_warning(odd, "x")
    dim = Frame(*(np.zeros(1),) * 4, {}, brightness=0.3, saturated=0.01, mismatch=1.0)
    assert "0.3 times as bright" in mismatch_warning(dim, "x") and "saturated" not in mismatch_warning(dim, "x")


def _stamps(folder):
    """(inode, mtime) of every file under ``folder``: a result kept as it was keeps both."""
    return {p.relative_to(folder): (p.stat().st_ino, p.stat().st_mtime_ns) for p in folder.rglob("*") if p.is_file()}


def _frames_and_a_press(tiny_model, tmp_path):
    """`nlips infer MODEL FRAMES PRESS --out OUT` on the tiny model: three frames and a press (four results)."""
    import shutil

    from tests.learn.test_resume import NAMES

    model, root = tiny_model
    frames = tmp_path / "frames"
    frames.mkdir()
    for name in NAMES:
        shutil.copy(root / name / "tricolor.png", frames / f"{name}.png")
    shutil.copytree(root / NAMES[0], tmp_path / "press", ignore=shutil.ignore_patterns("nlips*"))
    out = tmp_path / "out"
    return ["infer", str(model), str(frames), str(tmp_path / "press"), "--out", str(out)], out


def test_a_rerun_keeps_identical_results_untouched_and_counts_only_inferred_frames(tiny_model, tmp_path, capsys):
    """A re-run of `nlips infer MODEL FRAMES... --out DIR` inferred every frame again, so an interrupted long run
    did not resume. Now a result made from the same input with the same model file (its content: a copy elsewhere
    is the same model) and options is kept untouched, and the summary says how many were kept."""
    import json
    import shutil

    command, out = _frames_and_a_press(tiny_model, tmp_path)
    assert main(command) == 0
    assert capsys.readouterr().err.startswith("4 frame(s), torch")
    first = _stamps(out)
    assert len(first) == 17  # result.npz, report.json, normals.png, depth.png of three frames and a press (+ error.png)
    report = json.loads((out / "press" / "nlipsnet" / "report.json").read_text(encoding="utf-8"))
    assert set(report["provenance"]) == {"key", "software_version", "code", "libraries", "settings", "inputs"}
    from importlib import metadata  # the libraries that ran the network (torch backend) and integrated its depth

    versions = {name: metadata.version(name) for name in ("numpy", "torch", "scipy", "pyamg")}
    assert report["provenance"]["libraries"] == versions
    assert report["provenance"]["settings"]["depth"] is True and report["provenance"]["settings"]["ply"] is None
    assert main(command) == 0
    assert capsys.readouterr().err.startswith(
        "0 frame(s) inferred, 4 kept (identical results; --overwrite infers them again); whole command"
    )
    assert _stamps(out) == first
    copy = tmp_path / "copy.pt"
    shutil.copy(command[1], copy)
    assert main(["infer", str(copy), *command[2:]]) == 0
    assert capsys.readouterr().err.startswith("0 frame(s) inferred, 4 kept")
    assert _stamps(out) == first
    (out / "a_sphere" / "report.json").unlink()  # one result gone: only it is inferred, the rate is of it alone
    assert main(command) == 0
    assert " frames/s over the 1 inferred " in capsys.readouterr().err
    assert main([*command, "--overwrite"]) == 0  # --overwrite, as `nlips solve`'s: every result made again
    assert capsys.readouterr().err.startswith("4 frame(s), torch")
    again = _stamps(out)
    assert again.keys() == first.keys() and all(again[p] != first[p] for p in first)


def test_another_model_option_or_input_is_inferred_again_saying_what_changed(tiny_model, tmp_path, capsys, caplog):
    import logging
    import shutil
    from pathlib import Path

    import torch

    caplog.set_level(logging.INFO)
    command, out = _frames_and_a_press(tiny_model, tmp_path)
    model = command[1]
    assert main(command) == 0
    payload = torch.load(model, weights_only=True)
    payload["info"]["note"] = "retrained"  # another model file: another content
    other = tmp_path / "other.pt"
    torch.save(payload, other)
    capsys.readouterr()
    assert main(["infer", str(other), *command[2:]]) == 0
    assert capsys.readouterr().err.startswith("4 frame(s), torch")
    assert f"{out / 'b_cube'}: replacing the result of another model ({Path(model).resolve()})" in caplog.text
    caplog.clear()
    assert main([*command, "--no-depth", "--ply"]) == 0
    assert capsys.readouterr().err.startswith("4 frame(s), torch")
    assert "other options (depth True, now False, ply None, now 'points')" in caplog.text
    assert main([*command, "--no-depth", "--ply"]) == 0
    assert capsys.readouterr().err.startswith("0 frame(s) inferred, 4 kept")
    kept = _stamps(out)
    frames = tmp_path / "frames"
    shutil.copy(frames / "a_sphere.png", frames / "b_cube.png")  # another frame under that name
    caplog.clear()
    assert main([*command, "--no-depth", "--ply"]) == 0
    assert capsys.readouterr().err.startswith("1 frame(s) inferred, 3 kept")
    assert f"{out / 'b_cube'}: replacing the result of another input" in caplog.text
    now = _stamps(out)
    assert [p for p in kept if now[p] != kept[p]] == [p for p in kept if p.parts[0] == "b_cube"]
    from importlib import metadata  # another torch: a release moves numbers, so every result is inferred again

    from nlipscalib.core import libraries

    installed = libraries.installed_version
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(libraries, "installed_version", lambda name: "2.6.0" if name == "torch" else installed(name))
        caplog.clear()
        assert main([*command, "--no-depth", "--ply"]) == 0
    assert capsys.readouterr().err.startswith("4 frame(s), torch")
    assert f"{out / 'b_cube'}: replacing the result of torch {metadata.version('torch')} (now 2.6.0)" in caplog.text


def test_a_library_another_backend_ran_is_not_called_missing_when_the_backend_changes():
    """`nlips infer MODEL PRESS --backend torch` over an onnx result logged "replacing the result of other options
    (backend 'onnx', now 'torch'); torch not installed (now 2.13.0+cpu)": the onnx result records onnxruntime, not
    torch, which was installed all along. Now the backend alone is named; a library both record still is."""
    from nlipscalib.cli.infer import _what_changed

    def report(backend, libraries):
        settings = {"model_digest": "m", "backend": backend, "depth": True}
        provenance = {"key": backend + str(libraries), "settings": settings, "inputs": {"frame": "f"}}
        provenance |= {"software_version": "0.1.0", "code": "c", "libraries": libraries}
        return {"model": "/m.pt", "provenance": provenance}

    onnx = report("onnx", {"numpy": "2.4.6", "onnxruntime": "1.32.0", "scipy": "1.17.1"})
    torch = report("torch", {"numpy": "2.4.6", "torch": "2.13.0+cpu", "scipy": "1.17.1"})
    assert _what_changed(onnx, torch) == ["other options (backend 'onnx', now 'torch')"]
    assert _what_changed(torch, onnx) == ["other options (backend 'torch', now 'onnx')"]
    newer = report("torch", {"numpy": "2.4.7", "torch": "2.13.0+cpu", "scipy": "1.17.1"})
    assert _what_changed(torch, newer) == ["numpy 2.4.6 (now 2.4.7)"]
    gone = report("torch", {"numpy": "2.4.6", "torch": None, "scipy": "1.17.1"})
    assert _what_changed(torch, gone) == ["torch 2.13.0+cpu (now not installed)"]


def test_an_interrupted_run_infers_again_only_what_it_did_not_finish(tiny_model, tmp_path, capsys, caplog):
    """A result missing, a killed write's temporary folder beside one, a damaged one, a missing points.ply."""
    import logging
    import shutil
    import subprocess
    import sys

    from nlipscalib.core.claims import HOST

    caplog.set_level(logging.INFO)
    command, out = _frames_and_a_press(tiny_model, tmp_path)
    command.append("--ply")
    assert main(command) == 0
    first = _stamps(out)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    leftover = out / f".tmp-c_sphere_deep~{HOST}~{int(dead.stdout)}~x1y2"  # a run killed while writing it
    leftover.mkdir()
    (leftover / "report.json").write_text("{", encoding="utf-8")
    shutil.rmtree(out / "a_sphere")  # not written yet when the run was stopped
    (out / "b_cube" / "points.ply").unlink()
    with open(out / "press" / "nlipsnet" / "result.npz", "r+b") as f:
        f.truncate(100)
    capsys.readouterr()
    assert main(command) == 0
    assert capsys.readouterr().err.startswith("4 frame(s), torch")
    assert f"{out / 'c_sphere_deep'}: an interrupted write of it lies beside it; inferring it again" in caplog.text
    assert f"{out / 'b_cube'}: its points.ply is missing; inferring it again" in caplog.text
    assert "result.npz: damaged or truncated reconstruction" in caplog.text
    assert not leftover.exists()
    assert main(command) == 0
    assert capsys.readouterr().err.startswith("0 frame(s) inferred, 4 kept")
    shutil.rmtree(out / "a_sphere")
    again = _stamps(out)
    assert main(command) == 0  # only the missing one: the others keep their files
    assert capsys.readouterr().err.startswith("1 frame(s) inferred, 3 kept")
    now = _stamps(out)
    assert {p: now[p] for p in again} == again and len(now) == len(first)


FINISHED_RUN = """
import sys

from nlipscalib.cli import main

code = main(sys.argv[1:])
print(sorted({"torch", "onnxruntime"} & set(sys.modules)))  # what the run imported of the network runtimes
sys.exit(code)
"""


@pytest.mark.parametrize("backend", ["torch", "onnx"])
def test_a_finished_run_again_says_so_without_loading_the_model(tiny_model, tmp_path, capsys, backend):
    """`nlips infer MODEL FRAMES --out OUT` again once every result is there loaded the model, and torch or
    onnxruntime with it (seconds), before finding that every result was kept. Now it looks at the results first
    (the model known by its file's digest, the runtime by the files beside it, as the loaded model records them)
    and says so at once, importing neither runtime; a run with a result to make still loads the model."""
    import os
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    command, out = _frames_and_a_press(tiny_model, tmp_path)
    model = tmp_path / "m.pt"  # a copy: the export below must not change the module's model for other tests
    shutil.copy(command[1], model)
    command[1] = str(model)
    if backend == "onnx":
        assert main(["export", str(model)]) == 0  # MODEL.onnx beside it: --backend auto runs onnxruntime
    assert main(command) == 0
    assert f"4 frame(s), {backend}" in capsys.readouterr().err
    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))

    def again(*extra):
        run = subprocess.run(
            [sys.executable, "-c", FINISHED_RUN, *command, *extra], capture_output=True, text=True, env=env
        )
        assert run.returncode == 0, run.stderr
        said = [line for line in run.stderr.splitlines() if not line.startswith(("INFO ", "WARNING "))]
        return said, run.stdout.splitlines()  # stdout: the result folders, then the runtimes imported

    lines, printed = again()
    assert lines[0].startswith("0 frame(s) inferred, 4 kept (identical results; --overwrite infers them again)")
    assert lines[1].startswith("kept: 4 result folder(s) as they were (nothing written)"), lines
    assert len(printed) == 5 and printed[-1] == "[]", printed
    shutil.rmtree(out / "c_sphere_deep")  # one result to make: the model is loaded, the others still kept
    lines, printed = again()
    assert lines[0].startswith("1 frame(s) inferred, 3 kept") and printed[-1] != "[]", lines
    assert lines[1].startswith("saved: 1 result folder(s), kept 3 as they were; all 4: 3 for frames in "), lines


def test_a_result_another_run_is_inferring_is_waited_for_and_kept_not_inferred_twice(
    tiny_model, tmp_path, monkeypatch, capsys, caplog
):
    """Three `nlips infer MODEL DS --out O` at once each inferred the results the others were inferring and published
    over one another (whole folders: the last one's left). Now each result folder is claimed (core.claims) while it
    is inferred and saved: a run that finds another holding it waits, then keeps what that one made (the same
    input, model and options), or infers it itself when the other left none (killed, failed). A thread holding the
    claim stands for the other process here."""
    import logging
    import shutil
    import threading
    import time

    from nlipscalib.core import claims

    monkeypatch.setattr(claims, "CLAIM_POLL_S", 0.05)
    caplog.set_level(logging.INFO, logger="nlipscalib")
    command, out = _frames_and_a_press(tiny_model, tmp_path)
    assert main(command) == 0
    capsys.readouterr()
    folder, made = out / "b_cube", tmp_path / "made_by_the_other"
    shutil.move(folder, made)  # what the other run is about to publish
    released = []

    def other_run(publish: bool) -> threading.Thread:
        held = threading.Event()

        waits_before = caplog.text.count("waiting for it")

        def run() -> None:
            with claims.claim(folder) as mine:
                assert mine
                held.set()
                # held until the command says it waits (a fixed sleep let a slow, loaded start miss the claim)
                deadline = time.time() + 300
                while caplog.text.count("waiting for it") == waits_before and time.time() < deadline:
                    time.sleep(0.02)
                if publish:
                    shutil.copytree(made, folder)
                released.append(time.time())

        thread = threading.Thread(target=run)
        thread.start()
        held.wait(5)
        return thread

    thread = other_run(publish=True)
    assert main(command) == 0
    thread.join()
    said = capsys.readouterr().err.splitlines()
    assert said[0].startswith("0 frame(s) inferred, 4 kept"), said
    assert f"{folder}: being inferred by process " in caplog.text and "waiting for it" in caplog.text
    assert (
        f"{folder}: inferred by process " in caplog.text
        and "meanwhile (the same input, model and options); kept" in caplog.text
    )

    shutil.rmtree(folder)
    thread = other_run(publish=False)  # the other run ends without a result: this one infers it, after it
    assert main(command) == 0
    thread.join()
    assert capsys.readouterr().err.startswith("1 frame(s) inferred, 3 kept")
    assert (folder / "result.npz").stat().st_mtime >= released[-1]


def test_overwrite_is_refused_for_a_stream(capsys):
    """A stream never resumes (STREAM_STOPPED): --overwrite would change nothing there, so it is refused."""
    assert main(["infer", "m.pt", "--camera", "0", "--overwrite"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--overwrite is for press folders and image frames" in err[0], err


def test_a_frame_and_a_press_of_one_name_are_refused_before_anything_is_written(tiny_model, tmp_path, capsys):
    """`nlips infer MODEL FRAMES PRESSES --out OUT` with frames/a_sphere.png and presses/a_sphere wrote the press's
    result into OUT/a_sphere/nlipsnet inside the frame's OUT/a_sphere (exit 0); the next run then refused OUT/a_sphere
    as holding "other things than a reconstruction". Now one line names both inputs and nothing is written, in
    either order; results of an earlier run nest neither (each way: one line naming the input, nothing written)."""
    import shutil

    command, out = _frames_and_a_press(tiny_model, tmp_path)
    model, frames = command[1], command[2]
    press = tmp_path / "presses" / "a_sphere"
    shutil.copytree(tmp_path / "press", press)
    for inputs in ([frames, str(press)], [str(press), frames]):
        assert main(["infer", model, *inputs, "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{tmp_path / 'frames' / 'a_sphere.png'} and {press} would be written one " in err[0]
        assert f"({out / 'a_sphere' / 'nlipsnet'} inside {out / 'a_sphere'}: a frame and a press of one" in err[0]
        assert not out.exists()
    assert main(["infer", model, frames, "--out", str(out)]) == 0  # the frames first, the press in a later run
    capsys.readouterr()
    first = _stamps(out)
    assert main(["infer", model, str(press), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    nested = out / "a_sphere" / "nlipsnet"
    assert len(err) == 1 and f"{press}: its result {nested} would lie inside the result folder" in err[0], err
    assert _stamps(out) == first
    shutil.rmtree(out)  # the press first, the frame in a later run
    assert main(["infer", model, str(press), "--out", str(out)]) == 0
    capsys.readouterr()
    first = _stamps(out)
    assert main(["infer", model, frames, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "a_sphere.png: its result would replace" in err[0] and "holds a press's result" in err[0]
    assert _stamps(out) == first


def test_the_saved_line_says_where_frames_and_presses_results_are(tiny_model, tmp_path, capsys):
    """A mix of frames and a press said "saved: 4 result folder(s) in each press's a_sphere/ (e.g. OUT/a_sphere)",
    a frame's folder named as a press's. Now frames and presses are said apart, inferred or all kept; a re-run that
    keeps every result says so (it said "saved: 4 result folder(s)" of results it did not write)."""
    command, out = _frames_and_a_press(tiny_model, tmp_path)
    where = f": 3 for frames in {out}/, 1 for presses in {out / 'press' / 'nlipsnet'}/ (result.npz, "
    for counts in ("saved: 4 result folder(s)", "kept: 4 result folder(s) as they were (nothing written)"):
        assert main(command) == 0  # inferred, then all kept (said without loading the model)
        assert capsys.readouterr().err.splitlines()[1].startswith(counts + where)


def test_stills_show_a_bar_on_a_terminal_and_none_elsewhere(tiny_model, tmp_path, capsys, as_terminal):
    """`nlips infer MODEL FRAMES --out DIR` on a folder of 300 frames ran 10 s on a terminal without a sign of
    life. Now a bar counts the inputs there (stderr a terminal), and nothing of it reaches a pipe or a log."""
    command, out = _frames_and_a_press(tiny_model, tmp_path)
    assert main(command) == 0
    assert "\r" not in capsys.readouterr().err  # not a terminal: no bar
    tty = as_terminal()
    assert main([*command, "--overwrite"]) == 0
    assert "\r" in tty.getvalue() and "inferring: 100%" in tty.getvalue() and "4/4" in tty.getvalue(), tty.getvalue()


def test_a_damaged_input_among_many_is_said_and_the_others_are_inferred(tiny_model, tmp_path, capsys, caplog):
    """`nlips infer MODEL DATASET` stopped at the first damaged press or frame (one line, exit 2), leaving every
    input after it undone, where `nlips solve DATASET` solves the others. Now each damaged input is one line, the
    others are inferred, the closing lines count them apart and the exit status is 1; a re-run keeps what was
    made. A single damaged input is still the one line, exit 2."""
    from tests.learn.test_resume import NAMES

    command, out = _frames_and_a_press(tiny_model, tmp_path)
    damaged = tmp_path / "frames" / f"{NAMES[0]}.png"  # the first input: every other one came after it
    damaged.write_bytes(damaged.read_bytes()[:300])
    assert main(command) == 1
    said = capsys.readouterr()
    lines = said.err.splitlines()
    assert len(said.out.splitlines()) == 3  # stdout: the three result folders written, alone
    assert lines[0].startswith("3 frame(s), torch") and lines[1].startswith("saved: 3 result folder(s): 2 for frames")
    assert lines[2] == "failed: 1 of 4 input(s), not inferred (run again once fixed: the rest is kept)", lines
    assert lines[3] == f"  {damaged}: truncated PNG image (cut short: copy or capture it again)", lines
    assert f"{damaged}: truncated PNG image" in caplog.text and "Traceback" not in said.err + caplog.text
    assert sorted(p.name for p in out.iterdir()) == sorted([*NAMES[1:], "press"])
    assert (out / "press" / "nlipsnet" / "result.npz").is_file()
    assert main(command) == 1  # again: the others kept, the damaged one said again
    assert capsys.readouterr().err.splitlines()[1].startswith("kept: 3 result folder(s) as they were")
    assert main(["infer", command[1], str(damaged), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"nlips infer: error: {damaged}: truncated PNG image (cut short: copy or capture it again)"], err


def test_a_missing_model_with_frames_without_out_is_the_one_error_line(tiny_model, tmp_path, capsys, caplog):
    """`nlips infer nomodel.pt frame.png` warned "image frames without --out: their results are not written" and
    then failed on the model: a warning about results of a run that could not start. Now the one error line alone;
    the warning still comes when the model loads."""
    _, root = tiny_model
    frame = root / "a_sphere" / "tricolor.png"
    assert main(["infer", str(tmp_path / "nomodel.pt"), str(frame)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("nlips infer: error: ") and "nomodel.pt" in err[0], err
    assert "without --out" not in caplog.text
    assert main(["infer", str(tiny_model[0]), str(frame)]) == 0
    assert "image frames without --out: their results are not written" in caplog.text


def test_a_press_folder_as_out_is_refused_before_anything_is_written(tiny_model, tmp_path, capsys):
    """`nlips infer MODEL FRAMES --out PRESS` wrote the frames' result folders (a stream: its frame_N.npz files)
    in among the press's images, exit 0, as `nlips capture`, `dataset` and `demo` no longer do. Now one line."""
    import shutil

    from tests.learn.test_resume import NAMES

    model, root = tiny_model
    press = tmp_path / "press"
    shutil.copytree(root / NAMES[0], press, ignore=shutil.ignore_patterns("nlips*"))
    before = sorted(p.name for p in press.iterdir())
    frame = str(root / NAMES[1] / "tricolor.png")
    for inputs in ([frame], ["--camera", str(root / NAMES[1] / "tricolor.png")]):
        assert main(["infer", str(model), *inputs, "--out", str(press)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{press}: is a press folder (it has meta.json); write the results into" in err[0]
        assert sorted(p.name for p in press.iterdir()) == before


def test_eval_of_a_folder_of_frames_results_says_how_to_score_one(tiny_model, tmp_path, capsys):
    """`nlips infer MODEL FRAMES --out DIR` said "nlips eval scores them", and `nlips eval DIR` then said only "DIR:
    no press folders found". Now the saved line and eval's error both name the way: `nlips eval PRESS --result`."""
    command, _ = _frames_and_a_press(tiny_model, tmp_path)
    out = tmp_path / "frames-out"
    assert main(["infer", command[1], command[2], "--out", str(out)]) == 0
    said = capsys.readouterr().err
    assert "nlips eval scores them" not in said  # `nlips eval OUT` refuses a folder of frames' results
    assert f"no ground truth: score one against the press it shows with nlips eval PRESS --result {out}/" in said
    assert main(["eval", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        len(err) == 1 and f"{out}: no press folders found ({out} holds results of image frames, e.g. a_sphere" in err[0]
    )
    assert f"`nlips eval PRESS --result {out / 'a_sphere'}`" in err[0], err
    # the frames' results given as the results of a folder of presses, or of one press (s34-leftovers: "holds no
    # result of the presses" / "no reconstruction there", no hint that these are a frame's, scored one at a time)
    _, root = tiny_model
    assert main(["eval", str(root), "--result", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--result {out}: holds results of image frames" in err[0], err
    assert f"`nlips infer MODEL {root} --out DIR`, then `nlips eval {root} --result DIR`" in err[0]
    assert main(["eval", str(root / "a_sphere"), "--result", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"`nlips eval {root / 'a_sphere'} --result {out / 'a_sphere'}`" in err[0], err


def test_eval_of_one_press_results_and_of_a_streams_frames_names_the_command_for_each(tiny_model, tmp_path, capsys):
    """The other layouts `nlips infer` writes: one press with --out (OUT/PRESS/nlipsnet), where `nlips eval PRESS
    --result OUT` said "no reconstruction there (result.npz)" and `nlips eval OUT` advised `nlips eval PRESSES
    --result OUT`, which then said it too; a stream's frames (`nlips infer MODEL VIDEO --out OUT`:
    OUT/frame_NNNNNN.npz, as `nlips live --out`), of which eval said "no press folders found" / "no reconstruction
    there" / "holds no result of the presses", as of an empty folder. Now each names the command that scores them."""
    import shutil

    from tests.learn.test_resume import NAMES

    model, root = tiny_model
    press = tmp_path / NAMES[0]
    shutil.copytree(root / NAMES[0], press, ignore=shutil.ignore_patterns("nlips*"))
    out = tmp_path / "out"
    assert main(["infer", str(model), str(press), "--out", str(out), "--no-figures"]) == 0
    result = out / NAMES[0] / "nlipsnet"
    assert (result / "result.npz").is_file()
    capsys.readouterr()
    for given in (out, out / NAMES[0]):  # the --out folder, or the press's folder in it
        assert main(["eval", str(press), "--result", str(given)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"--result {given}: holds {NAMES[0]}'s result below it" in err[0], err
        assert err[0].endswith(f"score it with `nlips eval {press} --result {result}`"), err
    assert main(["eval", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"score it against its press with `nlips eval PRESS --result {result}`" in err[0], err
    assert main(["eval", str(press), "--result", str(result)]) == 0  # the command named scores it

    frames = tmp_path / "frames"
    frames.mkdir()
    for i, name in enumerate(NAMES):
        shutil.copy(root / name / "tricolor.png", frames / f"f{i}.png")
    stream = tmp_path / "stream"
    assert main(["infer", str(model), str(frames / "f%d.png"), "--out", str(stream)]) == 0
    assert (stream / "frame_000000.npz").is_file()
    capsys.readouterr()
    said = {
        (str(stream),): f"{stream}: no press folders found ({stream} holds a stream's saved frames (e.g. "
        "frame_000000.npz: what `nlips infer MODEL VIDEO --out DIR` and `nlips live --out DIR` write",
        (str(press), "--result", str(stream)): f"--result {stream}: holds a stream's saved frames (e.g. frame_000000",
        (str(press), "--result", str(stream / "frame_000001.npz")): "frame_000001.npz: is a stream's saved frame (",
        (str(root), "--result", str(stream)): f"not results of the presses of {root}: infer the presses themselves "
        f"(`nlips infer MODEL {root} --out DIR`, then `nlips eval {root} --result DIR`)",
    }
    for argv, line in said.items():
        assert main(["eval", *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and line in err[0], (argv, err)
        if argv[0] == str(press):
            assert err[0].endswith(
                f"infer the press itself (`nlips infer MODEL {press}`, then `nlips eval {press} --method nlipsnet`)"
            ), err


def test_a_press_whose_tricolor_frame_was_copied_over_is_refused_unless_allowed(tiny_model, tmp_path, capsys):
    """`nlips infer` read a press's tri-colour frame without its checksums.json (s34-checksums added the size check
    to solve, calibrate and train): another press's frame copied over it was inferred and saved under the press's
    name without a word. Now one line naming the file, exit 2, nothing written; --allow-edited infers it as it is.
    An LED image copied over is no reason: the inference reads none."""
    import shutil

    from tests.learn.test_resume import NAMES

    model, root = tiny_model
    press = tmp_path / "press"
    shutil.copytree(root / NAMES[0], press, ignore=shutil.ignore_patterns("nlips*"))
    (press / "led_04.png").write_bytes((root / NAMES[1] / "led_04.png").read_bytes())
    assert (press / "led_04.png").stat().st_size != (root / NAMES[0] / "led_04.png").stat().st_size
    assert main(["infer", str(model), str(press), "--no-figures"]) == 0
    shutil.rmtree(press / "nlipsnet")
    frame = press / "tricolor.png"
    frame.write_bytes((root / NAMES[1] / "tricolor.png").read_bytes())
    capsys.readouterr()
    assert main(["infer", str(model), str(press), "--no-figures"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"error: {frame}: changed since it was written (" in err[0] and "--allow-edited" in err[0]
    assert not (press / "nlipsnet").exists()
    assert main(["infer", str(model), str(press), "--no-figures", "--allow-edited"]) == 0
    assert (press / "nlipsnet" / "result.npz").is_file()
    capsys.readouterr()  # the press as --reference FRAME: its frame is read as the undeformed one, checked alike
    argv = ["infer", str(model), str(root / NAMES[2]), "--out", str(tmp_path / "o"), "--reference", str(press)]
    assert main(argv) == 2
    assert f"error: {frame}: changed since it was written (" in capsys.readouterr().err


def test_a_folder_holding_only_a_copied_tricolor_png_is_a_folder_of_frames(tiny_model, tmp_path, capsys):
    """A folder holding one press's tricolor.png copied alone (the lab-2 walk: a held-out frame of another design)
    was refused as "looks like a press folder (dark.png, led_*.png) without its meta.json", neither of which it held.
    """
    import shutil

    model, root = tiny_model
    frames = tmp_path / "frames"
    frames.mkdir()
    shutil.copy(root / "reference" / "tricolor.png", frames / "tricolor.png")
    out = tmp_path / "out"
    assert main(["--no-progress", "infer", str(model), str(frames), "--out", str(out)]) == 0
    assert "1 frame(s)" in capsys.readouterr().err
    assert (out / "tricolor" / "result.npz").is_file()
    shutil.copy(root / "reference" / "dark.png", frames / "dark.png")  # a press's own images: still refused
    assert main(["--no-progress", "infer", str(model), str(frames), "--out", str(tmp_path / "o2")]) == 2
    assert "without its meta.json" in capsys.readouterr().err


def test_a_press_of_another_dome_is_refused_as_another_sensor(tiny_model, tmp_path, capsys):
    """The lab-2 walk: a design of one's own (the fingertip with its dome 4 mm lower, camera and LEDs as they were)
    passed the model's camera and LED check; `nlips infer` only warned "captured with other settings" and wrote a
    result 16 deg and 3.3 mm off, exit 0. The undeformed surface is compared too, as `nlips solve --reference` does."""
    import shutil

    from nlipscalib.core.capture import Reference
    from tests.learn.test_resume import NAMES
    from tests.solver.twin_helpers import recorded_anew

    model, root = tiny_model
    press = tmp_path / "other_dome"
    shutil.copytree(root / NAMES[0], press, ignore=shutil.ignore_patterns("nlips"))
    ref = Reference.load(press / "reference.npz", load_press(press).camera.shape)
    Reference(depth=ref.depth * 1.05, normals=ref.normals).save(press / "reference.npz")  # a dome 5 % larger
    recorded_anew(press)  # captured so: its record names the files as they are (not an edit after capture)
    out = tmp_path / "out"
    assert main(["--no-progress", "infer", str(model), str(press), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"nlips infer: error: {press}: captured with another sensor than the model was calibrated")
    assert "undeformed surfaces" in err[0] and "mm apart (median)" in err[0], err
    assert not (out / press.name / "nlipsnet").exists()
    assert main(["--no-progress", "infer", str(model), str(root / NAMES[0]), "--out", str(out)]) == 0  # its own dome


def test_normals_only_frames_carry_the_undeformed_surface_made_once_not_per_frame(tiny_model, monkeypatch):
    """`--no-depth` ("skip the integration") recomputed the dome's points from its depth on every frame: its
    "integrate" stage took 2-8 ms a 640x480 frame, more than integrating the changed pixels did with depth."""
    import nlipscalib.learn.infer as infer
    from nlipscalib.core.camera import depth_to_points

    model, root = tiny_model
    predictor = Predictor(model, depth=False)
    calls = []
    monkeypatch.setattr(infer, "depth_to_points", lambda *a: calls.append(a) or depth_to_points(*a))
    tricolor = load_press(root / "b_cube").tricolor
    first, second = (predictor.predict_stored(tricolor) for _ in range(2))
    assert not calls  # the surface was made when the predictor was
    np.testing.assert_allclose(first.depth, predictor.ref_depth, rtol=1e-6)
    np.testing.assert_allclose(first.points, depth_to_points(predictor.ref_depth, predictor.camera.rays), rtol=1e-6)
    first.depth[...] = 0  # each frame's arrays are its own: changing one changes no other frame's
    assert np.isfinite(second.depth).all() and not np.all(second.depth == 0)
    np.testing.assert_allclose(predictor.predict_stored(tricolor).depth, predictor.ref_depth, rtol=1e-6)


def test_the_exposure_of_mismatched_frames_is_measured_against_constants_made_once(tiny_model, monkeypatch):
    """Each frame unlike the calibration's (a dimmer exposure, the emulator of another render) remade the reference
    frame's median brightness and the clipping levels: 11 of the 31 ms the check added to a 640x480 frame, while
    the stage times said the frame took 3.6 ms (the s24 live walk's emulated stream: 11.6 frames/s)."""
    import nlipscalib.learn.infer as infer

    model, root = tiny_model
    predictor = Predictor(model)
    dim = (load_press(root / "b_cube").tricolor * 0.5).astype(np.uint16)
    first = predictor.predict_stored(dim)
    assert first.mismatch > infer.FRAME_MISMATCH_FRACTION and 0.3 < first.brightness < 0.7
    linear = predictor.linear(dim)  # before the patch: the frame's own linearisation is not what is checked
    remade = []
    monkeypatch.setattr(infer, "linearise", lambda *a: remade.append(a) or pytest.fail("a constant was remade"))
    again = predictor.predict(linear)
    assert not remade and (again.brightness, again.saturated) == (first.brightness, first.saturated)


def test_a_stored_frames_seconds_time_its_linearisation_and_exposure_check_inside_its_total(tiny_model, monkeypatch):
    """The linearisation of a stored frame and the exposure check of a frame unlike the calibration's ran outside
    the timed stages (~20 ms of a 640x480 frame in a stream, s24 live walk): each is made slow here (a sleep)."""
    import time

    import nlipscalib.learn.infer as infer

    model, root = tiny_model
    predictor = Predictor(model)
    dim = (load_press(root / "b_cube").tricolor * 0.5).astype(np.uint16)
    linear, exposure = infer.Predictor.linear, infer.Predictor._exposure
    monkeypatch.setattr(infer.Predictor, "linear", lambda *a: time.sleep(0.02) or linear(*a))
    monkeypatch.setattr(infer.Predictor, "_exposure", lambda *a: time.sleep(0.03) or exposure(*a))
    seconds = predictor.predict_stored(dim).seconds
    assert list(seconds) == ["linearise", "change", "network", "integrate", "check", "total"]
    assert seconds["linearise"] >= 0.02 and seconds["check"] >= 0.03  # a sleep is never shorter than asked
    assert sum(v for k, v in seconds.items() if k != "total") <= seconds["total"]
    like = predictor.predict(predictor.ref_tricolor).seconds  # a frame like the calibration's: nothing to check
    assert like["check"] < 0.03 and sum(v for k, v in like.items() if k != "total") <= like["total"]


def test_predictor_threads_are_the_calls_own_not_the_processs(trained, twin_presses, monkeypatch):
    """Predictor(threads=N) runs the network on N torch threads and leaves the process's count as it was: a
    notebook's own torch work after making a predictor ran on the predictor's count before (set at construction)."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(3)
    try:
        predictor = Predictor(trained, backend="torch", threads=1)
        assert torch.get_num_threads() == 3
        seen = []
        monkeypatch.setattr(torch.nn.Module, "__call__", _counting_call(torch.nn.Module.__call__, seen))
        press = load_press(twin_presses / HELD_OUT)
        frame = predictor.predict(press.linear(press.tricolor))
        assert frame.changed.sum() > 0 and seen and set(seen) == {1}, seen
        assert torch.get_num_threads() == 3
    finally:
        torch.set_num_threads(before)


def _counting_call(call, seen: list):
    """torch.nn.Module.__call__ that notes torch's thread count at each call."""
    import torch

    def counted(self, *args, **kwargs):
        seen.append(torch.get_num_threads())
        return call(self, *args, **kwargs)

    return counted


def _png_size(path):
    """(width, height) of a PNG, from its header."""
    import struct

    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n", path
    return struct.unpack(">II", head[16:24])


def test_the_line_of_where_frames_results_are_lists_no_error_map(tmp_path):
    """`nlips infer MODEL frames/ --out OUT` ended "saved: 3 result folder(s) in OUT/ (result.npz, report.json,
    normals.png, depth.png, error.png with ground truth; ...)": a frame has no ground truth, and no error.png is
    written beside it (s34-walk). A press's result still lists it."""
    from nlipscalib.cli.infer import _where_saved

    frames = [(tmp_path / "out" / f"f{i}", False) for i in range(3)]
    frame_line = _where_saved(frames, set(), ply=False, figures="maps")
    frame = tmp_path / "out" / "f0"
    assert frame_line.endswith(
        "(result.npz, report.json, normals.png, depth.png; no ground truth: score one against the press it shows "
        f"with nlips eval PRESS --result {frame})"
    ), frame_line
    press = tmp_path / "p"  # its result beside its captures: scored with --method (without it eval scored NLiPs')
    press.mkdir()
    (press / "meta.json").write_text("{}", encoding="utf-8")
    press_line = _where_saved([(press / "nlipsnet", True)], set(), ply=False, figures="maps")
    assert press_line.endswith(
        "normals.png, depth.png, error.png with ground truth; nlips eval PRESS --method nlipsnet scores them)"
    ), press_line
    elsewhere = _where_saved([(tmp_path / "o" / "p" / "lut", True)], set(), ply=False, figures="maps")
    assert elsewhere.endswith(f"; nlips eval PRESSES --result {tmp_path / 'o'} scores them)"), elsewhere
    both = _where_saved([*frames, (press / "nlipsnet", True)], set(), ply=False, figures="maps")
    assert both.endswith(
        "nlips eval PRESS --method nlipsnet scores the presses'; a frame's against the press it shows: "
        f"nlips eval PRESS --result {frame})"
    ), both


def test_a_press_and_a_frame_get_the_solves_figures_beside_their_results(tiny_model, tmp_path, capsys, monkeypatch):
    """`nlips infer` of presses and stills wrote arrays only (the s25-figs audit): a lab inferring a still wants to
    look at it. Now the figures `nlips solve` writes: normals.png, depth.png (indentation, mm) and, for a press with
    ground truth, error.png; no residual.png (NLiPsNet has no residual); --figures full adds summary.png, whose error
    title gives the AAE and the contact AAE `nlips eval` prints."""
    from nlipscalib.report import figures
    from nlipscalib.report.maps import BAR_WIDTH

    command, out = _frames_and_a_press(tiny_model, tmp_path)
    assert main(command) == 0
    assert "normals.png, depth.png, error.png with ground truth;" in capsys.readouterr().err
    press, frame = out / "press" / "nlipsnet", out / "a_sphere"
    assert {p.name for p in press.glob("*.png")} == {"normals.png", "depth.png", "error.png"}
    assert {p.name for p in frame.glob("*.png")} == {"normals.png", "depth.png"}  # no ground truth beside a frame
    rec = load_reconstruction(press)
    rows, cols = np.nonzero(rec.mask)
    h, w = rows.max() - rows.min() + 1, cols.max() - cols.min() + 1  # the gel's box, at the image's resolution
    assert _png_size(press / "normals.png") == (w, h)
    assert _png_size(press / "depth.png")[0] == w + BAR_WIDTH  # the map and its colour bar in mm
    sheets = {}
    draw = figures.contact_sheet
    monkeypatch.setattr(
        figures, "contact_sheet", lambda rows, path, **kw: sheets.update(rows=rows, **kw) or draw(rows, path, **kw)
    )
    assert main([*command[:3], "--out", str(out), "--figures", "full", "--overwrite"]) == 0  # the frames
    assert {p.name for p in frame.glob("*.png")} == {"normals.png", "depth.png", "summary.png"}
    assert [p.title for p in sheets["rows"][0][1]] == ["normals", "indentation"]
    press_only = ["infer", command[1], command[3], "--out", str(out)]
    assert main([*press_only, "--figures", "full", "--overwrite"]) == 0
    assert (press / "summary.png").stat().st_size > 10_000
    panels = sheets["rows"][0][1]
    assert [p.title.split("\n")[0] for p in panels] == ["normals", "indentation", "angular error"]
    assert sheets["title"] == "press, NLiPsNet" and panels[1].label == "indentation, mm"
    scores = evaluate(load_reconstruction(press), load_press(tmp_path / "press").ground_truth)
    assert f"AAE {scores['all']['aae_deg']:.2f} deg, contact {scores['contact']['aae_deg']:.2f} deg" in panels[2].title


def test_figures_none_writes_no_picture_and_a_result_lacking_the_figures_asked_is_inferred_again(
    tiny_model, tmp_path, capsys
):
    command, out = _frames_and_a_press(tiny_model, tmp_path)
    assert main([*command, "--no-figures"]) == 0
    capsys.readouterr()
    assert not list(out.rglob("*.png"))
    assert main([*command, "--figures", "none"]) == 0  # the same request: all kept
    assert capsys.readouterr().err.startswith("0 frame(s) inferred, 4 kept")
    assert main(command) == 0  # the maps asked now: each result made again, with them
    assert capsys.readouterr().err.startswith("4 frame(s), torch")
    assert len(list(out.rglob("normals.png"))) == 4
    assert main(command) == 0
    assert capsys.readouterr().err.startswith("0 frame(s) inferred, 4 kept")


def test_figures_are_refused_for_a_stream(capsys):
    """A stream keeps its frames' normal maps (--out): --figures, for presses and stills, is refused there."""
    for flag in (["--figures", "maps"], ["--no-figures"]):
        assert main(["infer", "m.pt", "--camera", "0", *flag]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--figures is for press folders and image files" in err[0], err


def test_sigterm_ends_a_stream_with_its_summary_and_stream_json_then_143(tiny_model, tmp_path):
    """`kill` (SIGTERM: systemd, `timeout`, a job scheduler) of `nlips infer` on a stream ended it at once with one
    line, exit 143: the frame count, rate, stage line and stream.json were lost, where Ctrl-C keeps them (s25-soak).
    Now it ends as Ctrl-C does -- the frame under way finished and saved whole -- then the line, still exit 143."""
    import json
    import os
    import shutil
    import signal
    import sys
    from pathlib import Path

    from tests.learn.test_resume import NAMES
    from tests.processes import terminate_once_started

    model, root = tiny_model
    seq = tmp_path / "seq"
    seq.mkdir()
    for i in range(300):
        shutil.copy(root / NAMES[i % len(NAMES)] / "tricolor.png", seq / f"img_{i:04d}.png")
    started, out = tmp_path / "started", tmp_path / "out"
    code = (
        "import sys, time; from nlipscalib.cli import main; from nlipscalib.learn.watch import MismatchWatch\n"
        "call = MismatchWatch.__call__\n"
        "def slow(self, frame):\n"
        f"    open({str(started)!r}, 'w').close(); time.sleep(0.05); return call(self, frame)\n"
        "MismatchWatch.__call__ = slow\n"
        "sys.exit(main(sys.argv[1:]))"
    )
    argv = [sys.executable, "-c", code, "--no-progress", "infer", str(model), str(seq / "img_%04d.png")]
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    returncode, stdout, stderr = terminate_once_started(argv + ["--out", str(out)], started, env, wait=120)
    assert returncode == 128 + signal.SIGTERM, stderr
    assert stderr.splitlines()[-1] == (
        "nlips infer: terminated; the stream stopped (a stream does not resume; frames already saved with --out are "
        "kept)"
    )
    assert stdout == f"{out}\n", stdout  # where the frames went, alone; the summary on stderr
    lines = [line for line in stderr.splitlines() if not line.startswith(("INFO ", "WARNING "))]
    n = int(lines[0].split()[0])
    assert 1 <= n < 300 and lines[0].startswith(f"{n} frames in "), stderr
    assert any(line.startswith(f"saved: {n} of {n} frames' ") for line in lines), stderr
    assert json.loads((out / "stream.json").read_text(encoding="utf-8"))["frames"] == n
    assert sorted(p.name for p in out.glob("*.npz")) == [f"frame_{i:06d}.npz" for i in range(n)]


def test_a_folder_of_frames_all_unlike_the_reference_warns_three_times_then_counts(tiny_model, tmp_path, capsys):
    """`nlips --log-file F infer MODEL frames/` of 30 frames taken at another exposure wrote the same 500-character
    warning 30 times (54,000 an hour of a 15 frames/s recording), in F and on stderr."""
    import cv2

    from nlipscalib import progress

    model, root = tiny_model
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(8):
        cv2.imwrite(str(frames / f"f{i}.png"), np.zeros((48, 64, 3), np.uint16))  # black: LEDs off
    log = tmp_path / "lab.log"
    try:
        assert main(["--log-file", str(log), "infer", str(model), str(frames), "--out", str(tmp_path / "o")]) == 0
    finally:
        progress.configure(progress=True)
    warnings = [
        line.split(" WARNING ", 1)[1] for line in log.read_text(encoding="utf-8").splitlines() if " WARNING " in line
    ]
    full = [line for line in warnings if ": differs from the calibration's reference" in line]
    assert [line.split(": differs")[0].rsplit("/", 1)[1] for line in full] == ["f0.png", "f1.png", "f2.png"]
    assert len(warnings) == 5, warnings
    assert "repeated 5 more times in the last" in warnings[3] and "(the latest: " in warnings[3]
    assert "f7.png" in warnings[3] and "8 of 8 inputs differed" in warnings[4]


def test_an_older_result_recording_a_relative_model_path_is_not_said_to_be_another_models():
    """An NLiPsNet result of 754bd8b records the model as typed ("model/m.pt", relative to a working folder no record
    names) and no options: inferring it again with that same model said "replacing the result of another model
    (model/m.pt)". Only an absolute path that differs says another model."""
    from nlipscalib.cli.infer import _what_changed

    new = {"model": "/lab/model/m.pt", "provenance": {"settings": {}}}
    older = "an older nlipscalib (it records no options)"
    assert _what_changed({"model": "model/m.pt"}, new) == [older]
    assert _what_changed({"model": "/lab/other.pt"}, new) == ["another model (/lab/other.pt)", older]
    assert _what_changed({"model": "/lab/model/m.pt"}, new) == [older]


def _infer_in_a_process(command):
    """`nlips infer ...` run as another process (its own pid: a run of its own), returning (exit status, stderr)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (root, os.environ.get("PYTHONPATH"))))}
    done = subprocess.run(
        [sys.executable, "-m", "nlipscalib", "--no-progress", *command], capture_output=True, text=True, env=env
    )
    return done.returncode, done.stderr


def test_a_run_of_another_model_into_the_folders_a_live_run_holds_is_refused_and_one_of_the_same_shares(
    tiny_model, tmp_path, monkeypatch, capsys
):
    """Two `nlips infer` of two models into one --out at once both exited 0, each publishing over the other press by
    press (the QA walk: every result the first model's, while the second said "saved: 6 result folders"). Now a run
    holds its result folders for its model and options from start to end, as `nlips solve` holds its results: a
    run of another model is refused in one line naming the folder and this process, before anything is written;
    a run of the same model shares the folders. The other runs are processes of their own, started while this
    one holds its folders and loads its model."""
    import json
    import os
    from pathlib import Path

    import torch

    from nlipscalib.cli import _stream

    command, out = _frames_and_a_press(tiny_model, tmp_path)
    model = command[1]
    payload = torch.load(model, weights_only=True)
    payload["info"]["note"] = "retrained"  # another model: another content
    other = tmp_path / "other.pt"
    torch.save(payload, other)
    others = {}
    load = _stream.nlipsnet_predictor

    def load_meanwhile(*args, **kwargs):  # this run holds its folders now; it has inferred nothing yet
        if not others:
            others["another model"] = _infer_in_a_process(["infer", str(other), *command[2:]])
            others["the same model"] = _infer_in_a_process(command)
        return load(*args, **kwargs)

    monkeypatch.setattr(_stream, "nlipsnet_predictor", load_meanwhile)
    assert main(command) == 0
    said = capsys.readouterr().err
    code, err = others["another model"]
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert f"{out}: another run is inferring into it with its model ({Path(model).resolve()})" in lines[0]
    assert f"(process {os.getpid()} on " in lines[0] and "left to it: run again once it has ended" in lines[0]
    assert others["the same model"][0] == 0, others["the same model"][1]  # it inferred them: this run kept them
    assert said.startswith("0 frame(s) inferred, 4 kept"), said
    from nlipscalib.learn.onnx_export import file_digest

    reports = sorted(out.rglob("report.json"))
    assert len(reports) == 4
    made_by = {json.loads(r.read_text(encoding="utf-8"))["provenance"]["settings"]["model_digest"] for r in reports}
    assert made_by == {file_digest(model)}  # nothing of the other model's, nothing mixed
    assert not list(tmp_path.rglob(".claim-*"))


def test_a_killed_runs_hold_on_the_result_folders_neither_blocks_nor_stays(tiny_model, tmp_path, capsys):
    """A run of another model killed (SIGKILL, a power cut) while it held its outputs leaves its claims (the frames'
    --out folder's ``.claim-out~run~KEY~TOKEN`` beside it, and the short ``.claim-nlipsnet~run`` it took to join the
    press's result's holders): they are a dead process's, so the next run infers as it would have (all four
    results) and removes them as it ends."""
    import json

    from nlipscalib.core.claims import HOST
    from tests.core.test_atomic import _dead_pid

    command, out = _frames_and_a_press(tiny_model, tmp_path)
    dead = {"host": HOST, "pid": _dead_pid(), "token": "k9"}
    note = {"model": "/elsewhere/m.pt", "provenance": {"key": "0123456789abcdef", "settings": {}}}
    (out / "press").mkdir(parents=True)
    left = [tmp_path / ".claim-out~run~0123456789abcdef~k9", out / "press" / ".claim-nlipsnet~run"]
    left[0].write_text(json.dumps(dead | {"note": note}), encoding="utf-8")
    left[1].write_text(json.dumps(dead), encoding="utf-8")
    assert main(command) == 0
    assert capsys.readouterr().err.startswith("4 frame(s), torch")
    assert len(list(out.rglob("report.json"))) == 4
    assert not list(tmp_path.rglob(".claim-*"))


def test_a_stream_into_a_folder_another_stream_saves_into_is_refused_before_the_model_loads(
    tiny_model, tmp_path, capsys
):
    """`nlips infer` of a video, an image sequence or a camera with --out holds its folder as `nlips live` does
    (cli._stream.held_stream_folder): while another stream saves there it is one line naming the folder, exit 2,
    nothing written. The other stream is held here by this process (the mechanism is a process's claim; the test of
    two processes is tests/device/test_live.py's)."""
    import shutil

    from nlipscalib.cli._stream import held_stream_folder
    from tests.learn.test_resume import NAMES

    model, root = tiny_model
    sequence = tmp_path / "seq"
    sequence.mkdir()
    for k, name in enumerate(NAMES):
        shutil.copy(root / name / "tricolor.png", sequence / f"img_{k:04d}.png")
    out = tmp_path / "maps"
    command = ["infer", str(model), str(sequence / "img_%04d.png"), "--out", str(out)]
    with held_stream_folder(str(out), "nlips live"):
        assert main(command) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and f"{out}: another run (nlips live, process " in lines[0], lines
    assert not out.exists()
    assert main(command) == 0  # released: the stream runs
    assert len(list(out.glob("frame_*.npz"))) == len(NAMES)


def test_frames_results_are_refused_a_folder_a_stream_saves_into_also_when_only_the_loaded_model_tells_the_settings(
    tiny_model, tmp_path, capsys
):
    """With --full-frame (or on a GPU) only the loaded model tells a run's settings, so its outputs are held once
    it has loaded: a folder another live run holds (here a stream saving into it, held by this process) is refused
    then, in one line, and nothing is written; released, the same command infers all four."""
    from nlipscalib.cli._stream import held_stream_folder

    command, out = _frames_and_a_press(tiny_model, tmp_path)
    with held_stream_folder(str(out), "nlips live"):
        assert main([*command, "--full-frame"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and f"{out}: another run (nlips live, process " in lines[0], lines
    assert "is saving into it; left to it: run again once it has ended, or infer into another --out" in lines[0]
    assert not out.exists()
    assert main([*command, "--full-frame"]) == 0
    assert len(list(out.rglob("report.json"))) == 4


def test_a_frame_of_another_kind_than_predict_or_predict_stored_takes_is_one_clear_error(tiny_model):
    """A stored uint16 frame given to `predict` (a camera's `read()`) was taken for light up to 65535x full scale,
    and a linear float or an 8-bit frame given to `predict_stored` for 16-bit stored values: normals either way,
    without a word. Now ShapeError naming the other method."""
    from nlipscalib.core.errors import ShapeError
    from nlipscalib.learn.infer import Predictor

    model, _ = tiny_model
    predictor = Predictor(model, depth=False)
    H, W = predictor.shape
    with pytest.raises(ShapeError, match="tri-colour frame is uint16: predict takes the linear frame .*predict_stored"):
        predictor.predict(np.zeros((H, W, 3), np.uint16))
    with pytest.raises(ShapeError, match="tri-colour frame is a list, not an array"):
        predictor.predict([[0.0]])
    for dtype in (np.float32, np.uint8):
        with pytest.raises(ShapeError, match=f"frame: {np.dtype(dtype)} values, not the stored frame's"):
            predictor.predict_stored(np.zeros((H, W, 3), dtype))
    assert predictor.predict(np.zeros((H, W, 3), np.float64)).normals.shape == (H, W, 3)  # any float: light


@pytest.mark.parametrize(
    ("options", "said", "not_said"),
    [
        ({"device": "tpu"}, "device='tpu': not a torch device", "--device"),
        ({"device": "cuda", "backend": "onnx"}, "backend='onnx' runs on the CPU alone: device='cuda' runs", "--"),
        ({"full_frame": True, "backend": "onnx-int8"}, "full_frame=True runs PyTorch (backend='torch')", "--"),
        ({"full_frame": True, "backend": "onnx", "device": "cuda"}, "device='cuda' and full_frame=True run", "--"),
    ],
)
def test_a_predictors_device_errors_name_its_keywords(tmp_path, options, said, not_said):
    """Predictor(device=...) was told "use --device cpu", a flag a Python caller cannot give; checked before the
    model loads (none here)."""
    with pytest.raises(ConfigError) as caught:
        Predictor(tmp_path / "none.pt", **options)
    assert said in str(caught.value) and not_said not in str(caught.value)


def test_a_model_path_of_another_kind_is_one_error():
    from nlipscalib.core.errors import ShapeError

    with pytest.raises(ShapeError, match="model_path must be the model file's path"):
        Predictor(3)


@pytest.mark.parametrize("backend", ["torch", "onnx"])
def test_a_model_of_colour_ratios_is_given_the_colours_over_its_reference(trained_ratio, twin_presses, backend):
    """`nlips infer`'s CPU path (PyTorch and ONNX) divides the filtered colours by the filtered reference the model
    file carries, as its training and scoring did (net_predict): the same normals at the changed pixels."""
    import copy

    from nlipscalib.learn.evaluate import net_predict
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.onnx_export import export_onnx

    if backend == "onnx":
        pytest.importorskip("onnxruntime")
        onnx = pytest.importorskip("onnx")

        export_onnx(load_model(trained_ratio), trained_ratio.with_suffix(".onnx"))
        meta = {p.key: p.value for p in onnx.load(trained_ratio.with_suffix(".onnx")).metadata_props}
        assert meta["colour_input"] == "ratio"
    predictor = Predictor(trained_ratio, backend=backend)
    press = load_press(twin_presses / HELD_OUT)
    tri = press.linear(press.tricolor)
    frame = predictor.predict(tri)
    rows, cols = np.nonzero(frame.changed)
    assert len(rows) > 50
    model = predictor.model
    colours = Prefilter(predictor.valid, model.smoothing_px, model.smoothing_colour)(tri)[rows, cols]
    want = net_predict(model, np.stack([cols, rows], 1), colours)
    np.testing.assert_allclose(frame.normals[rows, cols], want, atol=2e-4)  # fused / ONNX float32 rounding
    # without the division the network would see linear colours: normals far from these
    as_linear = copy.copy(model)
    as_linear.input_reference = None
    linear = net_predict(as_linear, np.stack([cols, rows], 1), colours)
    assert np.abs(linear - want).max() > 0.05


def test_nlips_export_checks_a_ratio_model_on_the_linear_colours_it_divides(trained_ratio, tmp_path, monkeypatch):
    """`nlips export`'s parity check gives the ONNX file the inputs inference gives it, the reference's linear colours
    (10 % darker, as they are, brighter), which a ratio model's graph divides by its reference itself (PyTorch is given
    them divided: 0.9, 1, 1.1)."""
    import shutil

    from nlipscalib.learn import onnx_export
    from nlipscalib.learn.model import load_model

    model = tmp_path / "ratio.pt"
    shutil.copy(trained_ratio, model)
    seen = []
    check = onnx_export.checked_parity
    monkeypatch.setattr(onnx_export, "checked_parity", lambda m, p, x, **kw: seen.append(x) or check(m, p, x, **kw))
    assert main(["export", str(model)]) == 0
    (x,) = seen
    divide = load_model(model).input_reference
    # the three blocks (darker, as they are, brighter): linear colours, about 0.9, 1, 1.1 times the filtered reference's
    # (the raw colours over the filtered ones)
    ratios = [block[:, 2:] / divide[block[:, 1].astype(int), block[:, 0].astype(int)] for block in np.split(x, 3)]
    np.testing.assert_allclose([float(np.median(r)) for r in ratios], [0.9, 1.0, 1.1], atol=0.01)
    assert float(np.median(np.split(x, 3)[1][:, 2:])) < 0.9  # not the ratios: the linear colours (gel's 0.3-0.9)
