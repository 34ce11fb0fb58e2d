"""A model records the camera response of its calibration's captures, and ``nlips infer`` undoes it on the stills
and streams it is given (they declare none); a calibration mixing responses is refused in one line."""

import json
import shutil

import numpy as np
import pytest

from nlipscalib.core.errors import CaptureError, ConfigError


def _srgb_encoded(stored: np.ndarray, black: float, white: float) -> np.ndarray:
    """Linear stored values encoded with the sRGB curve of IEC 61966-2-1 (the forward curve, which the package has
    no use for: written out here so the test does not check the package's inverse against itself)."""
    x = np.minimum((stored.astype(np.float64) - black) / (white - black), 1)  # noise under black kept, as the
    v = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.maximum(x, 0) ** (1 / 2.4) - 0.055)  # package's inverse does
    return np.clip(np.rint(black + (white - black) * v), 0, 65535).astype(np.uint16)


def _declared(model_path, out, response="srgb"):
    """A copy of the model file ``model_path`` at ``out`` whose sensor records ``response`` (None: no key, as
    a model from before it was recorded)."""
    import torch

    payload = torch.load(model_path, weights_only=False)
    payload["sensor"] = {k: v for k, v in payload["sensor"].items() if k != "camera_response"}
    if response is not None:
        payload["sensor"]["camera_response"] = response
    torch.save(payload, out)
    return out


def _declare(folder, response="srgb"):
    meta_path = folder / "meta.json"
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    meta["sensor"]["camera_response"] = response
    meta["format_version"] = 2
    meta_path.write_text(json.dumps(meta), encoding="utf-8")


def test_a_sensor_record_holds_a_declared_response_and_old_records_read_linear():
    from nlipscalib.core.camera import Camera
    from nlipscalib.core.leds import Led
    from nlipscalib.core.sensor_record import camera_response_of, check_sensor_record, describe_sensor
    from nlipscalib.core.sensor_response import SensorResponse

    camera = Camera(fx=100.0, fy=100.0, cx=16.0, cy=12.0, width=32, height=24)
    leds = [Led(position=(10.0 * np.cos(a), 10.0 * np.sin(a), 5.0), direction=(0, 0, -1)) for a in range(3)]
    linear = describe_sensor(camera, leds, SensorResponse())
    srgb = describe_sensor(camera, leds, SensorResponse(camera_response="srgb"))
    assert "camera_response" not in linear and camera_response_of(linear) == "linear"  # written as before
    assert srgb["camera_response"] == "srgb" and camera_response_of(srgb) == "srgb"
    assert check_sensor_record(srgb, "m.pt") is srgb
    with pytest.raises(CaptureError, match=r"^m\.pt: 'sensor' is not .*camera_response must be one of .*'gamma'"):
        check_sensor_record(srgb | {"camera_response": "gamma"}, "m.pt")


def test_a_model_records_its_calibrations_response_and_infer_undoes_it_on_stored_frames(
    trained, twin_presses, tmp_path
):
    """The same light given as linear frames to the linear model and as sRGB-encoded frames to the model that
    records the sRGB response: the same linear frame (within the 16-bit rounding of the curve) and the same
    normals. A model without the record (older files) is linear and touches no value."""
    from nlipscalib.core import load_press
    from nlipscalib.learn.infer import Predictor

    old = Predictor(_declared(trained, tmp_path / "old.pt", None))
    assert old.camera_response == "linear" and old.tone_curve is None
    srgb = Predictor(_declared(trained, tmp_path / "srgb.pt"))
    assert srgb.camera_response == "srgb" and srgb.tone_curve is not None

    press = load_press(twin_presses / "press_a")
    stored = press.tricolor.copy()
    black, white = press.response.black_level, press.response.white_level
    encoded = _srgb_encoded(stored, black, white)
    given = encoded.copy()
    linear_from_srgb = srgb.linear(encoded)
    assert np.array_equal(encoded, given)  # the caller's frame is not changed
    expected = old.linear(stored)
    assert np.array_equal(expected, srgb._linearise(stored))  # one conversion once the curve is undone
    # the curve's 16-bit rounding, at its steepest (near black), a few stored steps of the 12-bit sensor
    assert np.abs(linear_from_srgb - expected).max() < 3e-4
    # undone nowhere else: the encoded frame read as linear is far off (why the stills were wrong without a word)
    assert np.abs(old.linear(encoded) - expected).max() > 0.05

    want, got = old.predict_stored(stored), srgb.predict_stored(encoded)
    valid = old.valid
    cos = np.clip((want.normals[valid] * got.normals[valid]).sum(-1), -1, 1)
    assert np.median(np.degrees(np.arccos(cos))) < 0.05
    assert np.array_equal(want.changed, got.changed) or (want.changed ^ got.changed).sum() < 0.01 * valid.sum()


def test_a_press_folder_is_linearised_by_its_own_declaration_whatever_the_models(trained, twin_presses, tmp_path):
    """A press folder declares how its images are encoded: read by that, not by the model's response (the model's
    is for stills and streams, which declare nothing), so an sRGB press infers as its linear twin with either
    model."""
    from nlipscalib.core import load_press
    from nlipscalib.learn.infer import load_tricolor

    folder = tmp_path / "press_a"
    shutil.copytree(twin_presses / "press_a", folder)
    press = load_press(folder)
    black, white = press.response.black_level, press.response.white_level
    from nlipscalib.core.imageio import write_png16

    meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
    for key in ("tricolor", "dark"):
        stored = getattr(press, key)
        write_png16(folder / meta["images"][key], _srgb_encoded(stored, black, white))
    _declare(folder)
    linear, _ = load_tricolor(twin_presses / "press_a")
    undone, sensor = load_tricolor(folder)
    assert sensor["camera_response"] == "srgb"
    assert np.abs(undone - linear).max() < 3e-4


def test_a_calibration_mixing_camera_responses_is_refused_in_one_line(twin_presses, tmp_path):
    """Before any solve (nlips calibrate's check of the folders), and when a dataset is built from solved presses:
    the press that declares another response than the undeformed capture is named."""
    from nlipscalib.cli.calibration import responses_agree
    from nlipscalib.learn.dataset import build_dataset

    root = tmp_path / "presses"
    for name in ("reference", "press_a", "press_b"):
        shutil.copytree(twin_presses / name, root / name)
    responses_agree(root / "reference", [root / "press_a", root / "press_b"])  # alike: nothing said
    _declare(root / "press_b")
    with pytest.raises(ConfigError) as refused:
        responses_agree(root / "reference", [root / "press_a", root / "press_b"])
    line = str(refused.value)
    assert "\n" not in line and line.startswith(f"{root / 'press_b'}: camera response srgb")
    assert f"--reference {root / 'reference'} linear" in line
    with pytest.raises(CaptureError, match=r"press_b: camera response srgb .*the reference's linear"):
        build_dataset([root / "press_a", root / "press_b"], root / "reference", tmp_path / "calib", progress=False)


def test_eight_bit_srgb_frames_are_undone_in_one_lookup_with_the_tables_numbers(trained, twin_presses, tmp_path):
    """An 8-bit sRGB frame's curve is undone as it is converted (a 256-entry lookup on its uint8 values, on the
    stream's reader threads), and not again by the predictor: the same linear frame, bit for bit, as the 65536-entry
    table on the shifted frame (the way before), for a still and an image sequence; `nlips infer`'s stream saves the
    normals of that frame (undone twice or not at all, they would be another frame's)."""
    import cv2

    from nlipscalib.cli import main
    from nlipscalib.cli.infer import read_still
    from nlipscalib.core import load_press
    from nlipscalib.device.camera import SequenceSource
    from nlipscalib.learn.infer import Predictor

    srgb = Predictor(_declared(trained, tmp_path / "srgb.pt"))
    press = load_press(twin_presses / "press_a")
    encoded = _srgb_encoded(press.tricolor, press.response.black_level, press.response.white_level)
    eight = (encoded >> 8).astype(np.uint8)
    seq = tmp_path / "seq"
    seq.mkdir()
    for i in range(2):
        cv2.imwrite(str(seq / f"img_{i:04d}.png"), np.ascontiguousarray(eight[..., ::-1]))
    stored = eight.astype(np.uint16) << 8  # what the frame was converted to before, its curve undone by the model
    expected = srgb.linear(stored)
    frame = SequenceSource(str(seq / "img_%04d.png"), tone_curve=srgb.tone_curve).read()
    assert np.array_equal(srgb.linear(frame, in_light=True), expected)
    still = read_still(seq / "img_0000.png", tone_curve=srgb.tone_curve)
    assert np.array_equal(srgb.linear(still, in_light=True), expected)
    assert np.abs(srgb.linear(frame) - expected).max() > 0.05  # undone twice: far off (what in_light prevents)

    out = tmp_path / "stream"
    assert main(["infer", str(tmp_path / "srgb.pt"), str(seq / "img_%04d.png"), "--out", str(out)]) == 0
    saved = np.load(out / "frame_000000.npz")["normals"]
    want = srgb.predict_stored(stored).normals
    assert np.allclose(np.nan_to_num(saved), want, atol=1e-5)


def test_a_model_of_a_measured_response_undoes_its_curve_on_stored_frames(trained, twin_presses, tmp_path):
    """A calibration of captures declaring a measured curve (``nlips calibrate-camera-response``): the model records
    its name and values and undoes them on stills and streams, as it does sRGB; a hand-edited curve is refused."""
    import torch

    from nlipscalib.core import load_press
    from nlipscalib.core.response_curve import curve_id
    from nlipscalib.learn.infer import Predictor

    curve = [float(v) for v in np.linspace(0, 1, 256) ** 2.2]
    payload = torch.load(trained, weights_only=False)
    payload["sensor"] |= {"camera_response": curve_id(curve), "response_curve": curve}
    torch.save(payload, tmp_path / "measured.pt")
    measured = Predictor(tmp_path / "measured.pt")
    old = Predictor(_declared(trained, tmp_path / "old.pt", None))
    assert measured.camera_response == curve_id(curve) and measured.tone_curve is not None

    press = load_press(twin_presses / "press_a")
    stored = press.tricolor.copy()
    black, white = press.response.black_level, press.response.white_level
    x = np.clip((stored.astype(np.float64) - black) / (white - black), 0, 1)
    encoded = np.rint(black + (white - black) * x ** (1 / 2.2)).astype(np.uint16)  # the camera's gamma 2.2
    expected = old.linear(stored)
    # the 256-entry curve interpolated on 16-bit values: within a few 12-bit steps at its steepest
    assert np.abs(measured.linear(encoded) - expected).max() < 1e-3
    assert np.abs(old.linear(encoded) - expected).max() > 0.05

    payload["sensor"]["response_curve"][200] += 1e-7
    torch.save(payload, tmp_path / "edited.pt")
    with pytest.raises(CaptureError, match="edited or damaged"):
        Predictor(tmp_path / "edited.pt")


def test_a_model_of_a_per_channel_response_undoes_each_channels_curve(trained, twin_presses, tmp_path):
    """A calibration of captures declaring a curve per channel (s31-respcam: a webcam whose R, G, B respond
    differently): the model undoes each channel's own on stills and streams, and its exposure check reads each
    channel's clipping level through that channel's curve."""
    import torch

    from nlipscalib.core import load_press
    from nlipscalib.core.response_curve import curve_id
    from nlipscalib.learn.infer import Predictor

    gammas = (2.0, 2.2, 2.4)
    curves = [[float(v) for v in np.linspace(0, 1, 256) ** g] for g in gammas]
    payload = torch.load(trained, weights_only=False)
    payload["sensor"] |= {"camera_response": curve_id(curves), "response_curve": curves}
    torch.save(payload, tmp_path / "rgb.pt")
    measured = Predictor(tmp_path / "rgb.pt")
    old = Predictor(_declared(trained, tmp_path / "old.pt", None))
    assert measured.tone_curve.shape == (65536, 3)

    press = load_press(twin_presses / "press_a")
    stored = press.tricolor.copy()
    black, white = press.response.black_level, press.response.white_level
    x = np.clip((stored.astype(np.float64) - black) / (white - black), 0, 1)
    encoded = np.rint(black + (white - black) * x ** (1 / np.asarray(gammas))).astype(np.uint16)
    expected = old.linear(stored)
    assert np.abs(measured.linear(encoded) - expected).max() < 1e-3
    # one curve for all three (gamma 2.2's, on red and blue too): far off
    one = [float(v) for v in np.linspace(0, 1, 256) ** 2.2]
    payload["sensor"] |= {"camera_response": curve_id(one), "response_curve": one}
    torch.save(payload, tmp_path / "one.pt")
    assert np.abs(Predictor(tmp_path / "one.pt").linear(encoded) - expected).max() > 0.01
    got, want = measured.predict_stored(encoded).normals, old.predict_stored(stored).normals
    both = np.isfinite(got).all(-1) & np.isfinite(want).all(-1)
    assert both.mean() > 0.5 and np.median(np.abs(got - want)[both]) < 1e-3
    # the exposure check of a frame unlike the calibration's: each channel clips at its curve's white (the level)
    assert measured._exposure(expected) == pytest.approx(old._exposure(expected))
