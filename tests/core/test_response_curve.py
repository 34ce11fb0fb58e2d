"""A measured camera response (``core.response_curve``): its file, its name in meta.json (``measured:<hash>``, the
curve beside it), the table it undoes, and the captures of "linear" and "srgb" cameras written as before.

Why: a webcam with neither a gamma-off switch nor an exact sRGB curve (gamma 2.2, a vendor curve) could only be
captured wrongly; its curve is now measured once (``nlips calibrate-camera-response``) and every capture undoes
it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nlipscalib.core import Camera, load_press, write_press
from nlipscalib.core.errors import CaptureError
from nlipscalib.core.leds import Led
from nlipscalib.core.response_curve import (
    MeasuredResponse,
    check_curve,
    curve_id,
    measured_table,
    read_response_file,
    write_response_file,
)
from nlipscalib.core.sensor_record import check_sensor_record, describe_sensor, response_table_of
from nlipscalib.core.sensor_response import SensorResponse, tone_curve_table

GAMMA = 2.2


def _gamma_curve(n: int = 256) -> tuple[float, ...]:
    """The light each encoded fraction of a gamma 2.2 camera stands for."""
    return tuple(float(v) for v in np.linspace(0, 1, n) ** GAMMA)


def _response(curve=None) -> SensorResponse:
    curve = _gamma_curve() if curve is None else curve
    return SensorResponse(
        bit_depth=8,
        black_level=0.0,
        white_level=65280.0,
        camera_response=curve_id(curve),
        response_curve=curve,
    )


def test_a_measured_table_undoes_the_curve_and_keeps_black_white_and_clipped_values():
    curve = _gamma_curve()
    table = tone_curve_table(curve_id(curve), 0.0, 65280.0, curve)
    codes = np.arange(256)
    # an 8-bit camera's stored values (DN << 8) fall on the curve's entries exactly
    assert np.array_equal(table[codes << 8], np.rint(65280.0 * (codes / 255) ** GAMMA).astype(np.uint16))
    assert table[0] == 0 and table[65280] == 65280 and table[65535] == 65535
    assert np.all(np.diff(table.astype(int)) >= 0)
    # a 12-bit camera with a black level: the curve spans black to white, below black values stay as they are
    table12 = measured_table(curve, 1024.0, 65520.0)
    assert table12[1024] == 1024 and table12[65520] == 65520 and table12[1000] == 1000
    mid = 1024 + (65520 - 1024) // 2
    assert table12[mid] == pytest.approx(1024 + (65520 - 1024) * 0.5**GAMMA, abs=300)  # 256-entry interpolation
    assert tone_curve_table("linear", 0.0, 65280.0) is None


def test_a_curve_is_checked_and_named_by_its_hash():
    curve = _gamma_curve()
    assert curve_id(curve).startswith("measured:") and curve_id(curve) == curve_id(list(curve))
    assert curve_id(curve) != curve_id(_gamma_curve(65536))
    assert check_curve(curve, curve_id(curve)) == curve
    falling = list(curve)
    falling[100] = falling[99] - 0.01
    bad = {
        "entries": list(curve[:200]),
        "from 0": [0.1, *curve[1:]],
        "to 1": [*curve[:-1], 0.9],
        "falls at entry 100": falling,
        "numbers": ["x"] * 256,
    }
    for why, values in bad.items():
        with pytest.raises(ValueError, match=why):
            check_curve(values)
    edited = list(curve)
    edited[50] += 1e-6
    with pytest.raises(ValueError, match="edited or damaged"):
        check_curve(edited, curve_id(curve))


def test_a_response_file_round_trips_and_a_damaged_one_is_one_line_naming_it(tmp_path):
    response = MeasuredResponse(_gamma_curve(), {"camera": "camera 0", "fit_residual": 0.005})
    path = write_response_file(tmp_path / "response.json", response)
    back = read_response_file(path)
    assert back == response and back.name == curve_id(response.curve)
    doc = json.loads(path.read_text(encoding="utf-8"))
    doc["response_curve"][10] = 0.9  # falls after it
    (tmp_path / "damaged.json").write_text(json.dumps(doc), encoding="utf-8")
    (tmp_path / "other.json").write_text(json.dumps({"format": "nlipscalib.press"}), encoding="utf-8")
    for name, problem in (
        ("damaged.json", "falls at entry"),
        ("other.json", "'format' must be"),
        ("no.json", "missing"),
    ):
        with pytest.raises(CaptureError) as err:
            read_response_file(tmp_path / name)
        assert str(err.value).startswith(str(tmp_path / name)) and problem in str(err.value)
        assert "\n" not in str(err.value)


def test_sensor_response_carries_the_curve_its_name_makes_and_no_other():
    response = _response()
    assert isinstance(response.response_curve, tuple)
    assert response.tone_curve()[128 << 8] == round(65280 * (128 / 255) ** GAMMA)
    name = curve_id(_gamma_curve())
    with pytest.raises(CaptureError, match="response_curve is missing"):
        SensorResponse(camera_response=name)
    with pytest.raises(CaptureError, match="not a measured curve"):
        SensorResponse(camera_response="srgb", response_curve=_gamma_curve())
    with pytest.raises(CaptureError, match="edited or damaged"):
        SensorResponse(camera_response=name, response_curve=_gamma_curve(65536))
    with pytest.raises(CaptureError, match="measured:<hash>"):
        SensorResponse(camera_response="gamma2.2")


def _camera_leds():
    camera = Camera.from_fov(16, 12, 100.0, "fisheye", (0.0, 0.0, 0.0, 0.0))
    leds = [Led(position=(np.cos(a) * 5, np.sin(a) * 5, 0.0)) for a in np.linspace(0, 6, 3)]
    return camera, leds


def _write(folder, response, codes):
    camera, leds = _camera_leds()
    stored = (np.asarray(codes, np.uint16) << 8) * np.ones((12, 16, 3), np.uint16)
    return write_press(folder, camera, leds, response, stored, np.stack([stored] * 3), stored)


def test_a_measured_capture_records_its_curve_and_loads_linear(tmp_path):
    _write(tmp_path / "p", _response(), 128)
    meta = json.loads((tmp_path / "p" / "meta.json").read_text(encoding="utf-8"))
    assert meta["format_version"] == 2 and meta["sensor"]["camera_response"] == curve_id(_gamma_curve())
    assert meta["sensor"]["response_curve"] == list(_gamma_curve())
    press = load_press(tmp_path / "p")
    assert press.led_images[0, 0, 0, 0] == round(65280 * (128 / 255) ** GAMMA)
    # the curve travels with the sensor record into datasets and models, and is undone from there
    record = describe_sensor(press.camera, press.leds, press.response)
    assert record["response_curve"] == list(_gamma_curve())
    assert np.array_equal(response_table_of(record), press.response.tone_curve())
    check_sensor_record(record, "model.pt")
    record["response_curve"][200] += 1e-7
    with pytest.raises(CaptureError, match="model.pt: 'sensor' is not a sensor description .*edited or damaged"):
        check_sensor_record(record, "model.pt")
    # a hand-edited curve in meta.json: one line naming the file
    meta["sensor"]["response_curve"][200] += 1e-7
    (tmp_path / "p" / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    with pytest.raises(CaptureError, match=r"p[/\\]meta.json: .*edited or damaged"):
        load_press(tmp_path / "p")


def test_linear_and_srgb_captures_are_written_as_before(tmp_path):
    """No response_curve key (meta.json and sensor records bit for bit as before: their hashes unchanged)."""
    for name in ("linear", "srgb"):
        response = SensorResponse(bit_depth=8, black_level=0.0, white_level=65280.0, camera_response=name)
        _write(tmp_path / name, response, 100)
        meta = json.loads((tmp_path / name / "meta.json").read_text(encoding="utf-8"))
        assert "response_curve" not in meta["sensor"]
        assert meta["format_version"] == (1 if name == "linear" else 2)
        assert "response_curve" not in describe_sensor(*_camera_leds(), response)


def test_the_srgb_encoding_is_the_loaders_inverse():
    """The emulated sRGB camera encodes with ``linear_to_srgb``; the loader undoes ``srgb_to_linear``."""
    from nlipscalib.core.sensor_response import linear_to_srgb, srgb_to_linear

    x = np.linspace(0, 1, 10001, dtype=np.float32)
    assert np.abs(srgb_to_linear(linear_to_srgb(x)) - x).max() < 1e-6
    assert linear_to_srgb(np.float32(0.5)) == pytest.approx(0.735357, abs=1e-6)  # IEC 61966-2-1's mid grey


GAMMAS = (2.0, 2.2, 2.4)
"""A webcam whose red, green and blue respond differently (the emulator's ``rgb-gammas``)."""


def _rgb_curve() -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(float(v) for v in np.linspace(0, 1, 256) ** g) for g in GAMMAS)


def test_a_per_channel_curve_is_checked_and_its_file_is_version_2_while_one_curve_stays_version_1(tmp_path):
    """Why: one curve per channel (s31-respcam); version 1 files (one curve) are written and read as before, and a
    version 1 file holding three curves is no file an older nlipscalib wrote."""
    curves = _rgb_curve()
    assert check_curve(curves, curve_id(curves)) == curves and curve_id(curves) != curve_id(curves[1])
    falling = [list(c) for c in curves]
    falling[2][100] = falling[2][99] - 0.01
    with pytest.raises(ValueError, match=r"response_curve \(B\) falls at entry 100"):
        check_curve(falling)
    with pytest.raises(ValueError, match=r"three such lists\), got \(2, 256\)"):
        check_curve(curves[:2])
    for curve, version in ((curves, 2), (_gamma_curve(), 1)):
        path = write_response_file(tmp_path / f"v{version}.json", MeasuredResponse(curve, {"camera": "camera 0"}))
        doc = json.loads(path.read_text(encoding="utf-8"))
        assert doc["format_version"] == version and read_response_file(path).curve == curve
    doc = json.loads((tmp_path / "v2.json").read_text(encoding="utf-8"))
    doc["format_version"] = 1
    (tmp_path / "mislabelled.json").write_text(json.dumps(doc), encoding="utf-8")
    with pytest.raises(CaptureError, match=r"mislabelled.json: .*three curves, which format_version 1 does not"):
        read_response_file(tmp_path / "mislabelled.json")


def test_a_per_channel_table_undoes_each_channel_with_its_curve_in_captures_and_streams(tmp_path):
    """The capture loader (a 65536-entry table per channel), and a live or recorded stream's 8-bit frames
    (``device.camera.to_stored``: one ``cv2.LUT`` of a table per channel), bit for bit alike."""
    from nlipscalib.core.sensor_response import eight_bit_table, undo_tone_curve
    from nlipscalib.device.camera import to_stored

    curves = _rgb_curve()
    table = measured_table(curves, 0.0, 65280.0)
    assert table.shape == (65536, 3)
    for c in range(3):
        assert np.array_equal(table[:, c], measured_table(curves[c], 0.0, 65280.0))
    bgr = np.random.default_rng(0).integers(0, 256, (12, 16, 3), dtype=np.uint8)
    rgb = np.ascontiguousarray(bgr[..., ::-1])
    undone = undo_tone_curve(rgb.astype(np.uint16) << 8, table)
    codes = np.arange(256)
    for c, g in enumerate(GAMMAS):
        assert np.array_equal(undone[..., c], np.rint(65280.0 * (codes / 255) ** g).astype(np.uint16)[rgb[..., c]])
    assert eight_bit_table(table).shape == (1, 256, 3)
    stored, bits = to_stored(bgr, "frame", table)
    assert bits == 8 and np.array_equal(stored, undone)
    # a capture declaring it: meta.json format_version 3, each channel linear; and its sensor record for models
    response = _response(curves)
    _write(tmp_path / "p", response, 128)
    meta = json.loads((tmp_path / "p" / "meta.json").read_text(encoding="utf-8"))
    assert meta["format_version"] == 3 and meta["sensor"]["response_curve"] == [list(c) for c in curves]
    press = load_press(tmp_path / "p")
    assert [int(v) for v in press.led_images[0, 0, 0]] == [round(65280 * (128 / 255) ** g) for g in GAMMAS]
    record = describe_sensor(press.camera, press.leds, press.response)
    check_sensor_record(json.loads(json.dumps(record)), "model.pt")
    assert np.array_equal(response_table_of(record), table)


def test_a_tone_curve_is_redone_on_linear_values_to_the_cameras_own():
    """``redo_tone_curve``: the camera's encoded values back from linear ones (sRGB, a measured curve, one per
    channel), as the `--black-level` hint of a press declaring a curve needs them (it named linear values, s37)."""
    from nlipscalib.core.sensor_response import redo_tone_curve, undo_tone_curve

    codes = (np.arange(256, dtype=np.uint16) << 8).repeat(3).reshape(-1, 3)
    for response in (
        SensorResponse(bit_depth=8, black_level=0.0, white_level=65280.0, camera_response="srgb"),
        _response(),
        _response([_gamma_curve(), _gamma_curve(), tuple(np.linspace(0, 1, 256) ** 2.0)]),
    ):
        table = response.tone_curve()
        linear = undo_tone_curve(codes.copy(), table)
        again = redo_tone_curve(linear, table)
        # the middle of the stored values that undo to the same light: the camera's code to an eighth of a step,
        # above the darkest codes that gamma 2.2 maps to the same 16-bit light (codes 0 and 1: 0)
        assert np.all(undo_tone_curve(np.rint(again).astype(np.uint16), table) == linear)
        assert np.abs(again - codes)[8:].max() <= 32, response.camera_response
    assert redo_tone_curve(codes, None) is codes
