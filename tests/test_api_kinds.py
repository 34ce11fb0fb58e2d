"""docs/api.md's public functions given an argument of another Python kind, as a new user writes one (a number for a
path, a string for an array, a config or a flag): each is one NlipsError line naming the argument and what it must be,
never Python's TypeError or AttributeError from inside it, nor NumPy's ValueError.

Why: s36-apileft checked the first sections' entry points (load_press, save_reconstruction, save_leds, write_ply,
Predictor, train, render_press); the rest of the page (solve_folder, solve_presses, calibrate_leds, build_dataset,
evaluate and the metrics, load_tricolor, check_sensor, mismatch_warning, to_reconstruction, MismatchWatch,
open_source, CameraSettings, to_stored, lights_out_on_exit, start_board, SaveSink, stream, load_scene,
IndenterConfig, tricolor_colors, capture_led_diameter, read_led_file, Press.linear, VirtualBoard,
AdalightController.open) still failed deep inside
("'int' object is not iterable", "'str' object has no attribute 'read'", "could not convert string to float"), and
solve_presses("out/press") went through the path's characters as press folders (s37 capcheck's walk).
"""

from __future__ import annotations

import numpy as np
import pytest

from nlipscalib.core.errors import NlipsError
from tests.solver import synth

SIZE = (64, 48)


@pytest.fixture(scope="module")
def sensor(tmp_path_factory):
    """A tiny exact-data press, its reference (with ground truth) and an output folder."""
    from nlipscalib.core import load_press

    root = tmp_path_factory.mktemp("api_kinds")
    reference = synth.make_press(root / "reference", "none", size=SIZE)
    press = synth.make_press(root / "press", "sphere", size=SIZE)
    return {"root": root, "reference": reference, "press": press, "loaded": load_press(press)}


def _frame():
    from nlipscalib.learn.infer import Frame

    zeros = np.zeros((2, 2))
    return Frame(zeros[..., None].repeat(3, -1), zeros, zeros[..., None].repeat(3, -1), zeros > 0, {})


def _result(points):
    """A reconstruction's maps (what evaluate reads of one)."""
    from types import SimpleNamespace

    return SimpleNamespace(normals=points, depth=points[..., 2], reconstructed=points[..., 2] == 0)


def _calls(s):
    """(what the message must say, the call) of each wrong kind given."""
    from nlipscalib.core import load_reconstruction
    from nlipscalib.core.ledfile import read_led_file
    from nlipscalib.core.leds import tricolor_colors
    from nlipscalib.core.metrics import aae, depth_rmse, evaluate, mabse
    from nlipscalib.core.sensor import capture_led_diameter
    from nlipscalib.core.sensor_record import check_sensor
    from nlipscalib.learn.dataset import build_dataset
    from nlipscalib.learn.infer import load_tricolor, mismatch_warning, to_reconstruction
    from nlipscalib.learn.ply import write_ply
    from nlipscalib.learn.watch import MismatchWatch
    from nlipscalib.pipeline import solve_folder, solve_presses
    from nlipscalib.solver import calibrate_leds, solve_press

    press, reference, out, loaded = s["press"], s["reference"], s["root"] / "out", s["loaded"]
    points = np.zeros((*SIZE[::-1], 3))
    return {
        "load_reconstruction": ("folder must be", lambda: load_reconstruction(3)),
        "read_led_file": ("path must be", lambda: read_led_file(3)),
        "Press.linear": ("image must be", lambda: loaded.linear("tricolor.png")),
        "solve_press options": ("options must be", lambda: solve_press(loaded, options="fast")),
        "solve_press options dict": ("options must be", lambda: solve_press(loaded, options={"max_iters": 2})),
        "solve_press indirect": ("indirect must be", lambda: solve_press(loaded, indirect=3)),
        "solve_folder": ("folder must be", lambda: solve_folder(3)),
        "solve_folder reference": ("reference must be", lambda: solve_folder(press, reference=3)),
        "solve_presses": ("folders must be", lambda: solve_presses(3)),
        "solve_presses one path": ("give [", lambda: solve_presses(str(press))),
        "solve_presses numbers": ("folders[0] must be", lambda: solve_presses([3])),
        "solve_presses reference": ("reference must be", lambda: solve_presses([press], reference=3)),
        "calibrate_leds": ("presses must be", lambda: calibrate_leds(3)),
        "calibrate_leds led_radius": ("led_radius must be", lambda: calibrate_leds(reference, led_radius="1.8")),
        "build_dataset": ("press_folders must be", lambda: build_dataset(3, reference, out)),
        "build_dataset reference": ("reference_folder must be", lambda: build_dataset([press], 3, out)),
        "build_dataset out": ("out must be", lambda: build_dataset([press], reference, 3)),
        "evaluate": ("result must be", lambda: evaluate("result", loaded.ground_truth)),
        "evaluate ground_truth": ("ground_truth must be", lambda: evaluate(_result(points), "truth")),
        "aae": ("aae: normals must be", lambda: aae("a", "b")),
        "mabse": ("mabse: gt_normals must be", lambda: mabse(points, "b")),
        "depth_rmse": ("depth_rmse: depth must be", lambda: depth_rmse("a", "b")),
        "write_ply points": ("points must be", lambda: write_ply(out / "p.ply", points.tolist())),
        "write_ply mesh": ("mesh must be", lambda: write_ply(out / "p.ply", points, mesh="no")),
        "load_tricolor": ("folder must be", lambda: load_tricolor(3)),
        "check_sensor": ("expected must be", lambda: check_sensor(3, {}, press)),
        "check_sensor actual": ("actual must be", lambda: check_sensor({}, "sensor", press)),
        "mismatch_warning": ("frame must be", lambda: mismatch_warning("frame", press)),
        "to_reconstruction": ("frame must be", lambda: to_reconstruction("frame", None, "x")),
        "to_reconstruction predictor": ("predictor must be", lambda: to_reconstruction(_frame(), "model", "x")),
        "MismatchWatch": ("predictor must be", lambda: MismatchWatch("model.pt", "camera")),
        "capture_led_diameter": ("meta must be", lambda: capture_led_diameter("meta.json")),
        "tricolor_colors": ("n_leds must be", lambda: tricolor_colors("12")),
    }


def _twin_and_device_calls(s):
    from nlipscalib.device.adalight import AdalightController
    from nlipscalib.device.camera import CameraSettings, open_source, to_stored
    from nlipscalib.device.lights_out import lights_out_on_exit
    from nlipscalib.device.live import SaveSink, stream
    from nlipscalib.device.virtual_board import VirtualBoard, start_board
    from nlipscalib.sim.indenters import IndenterConfig
    from nlipscalib.sim.scene import load_scene

    return {
        "load_scene": ("path must be", lambda: load_scene(3)),
        "IndenterConfig size": ("indenter.size: must be a number", lambda: IndenterConfig(kind="sphere", size="6")),
        "CameraSettings": ("exposure_ms must be a number", lambda: CameraSettings(exposure_ms="10")),
        "CameraSettings flag": ("linear_gamma must be True or False", lambda: CameraSettings(linear_gamma="no")),
        "open_source": ("spec must be", lambda: open_source(3.5)),
        "open_source settings": ("settings must be", lambda: open_source(str(s["root"]), "fast")),
        "to_stored": ("frame must be", lambda: to_stored([[1, 2, 3]])),
        "lights_out_on_exit": ("controller must be", lambda: lights_out_on_exit("board").__enter__()),
        "start_board": ("url must be", lambda: start_board(3, 12)),
        "VirtualBoard": ("n_leds must be", lambda: VirtualBoard("twelve")),
        "VirtualBoard baudrate": ("baudrate must be", lambda: VirtualBoard(12, baudrate="fast")),
        "AdalightController.open": ("n_leds must be", lambda: AdalightController.open("loop://", "12")),
        "SaveSink": ("folder must be", lambda: SaveSink(3)),
        "stream": ("source must be", lambda: stream("camera 0", lambda frame: None, [])),
        "stream sinks": ("sinks must be", lambda: stream(_Reader(), lambda frame: None, "frames/")),
    }


class _Reader:
    def read(self):  # pragma: no cover - never reached: the sinks are refused first
        raise AssertionError


CORE = [
    "load_reconstruction",
    "read_led_file",
    "Press.linear",
    "solve_press options",
    "solve_press options dict",
    "solve_press indirect",
    "solve_folder",
    "solve_folder reference",
    "solve_presses",
    "solve_presses one path",
    "solve_presses numbers",
    "solve_presses reference",
    "calibrate_leds",
    "calibrate_leds led_radius",
    "build_dataset",
    "build_dataset reference",
    "build_dataset out",
    "evaluate",
    "evaluate ground_truth",
    "aae",
    "mabse",
    "depth_rmse",
    "write_ply points",
    "write_ply mesh",
    "load_tricolor",
    "check_sensor",
    "check_sensor actual",
    "mismatch_warning",
    "to_reconstruction",
    "to_reconstruction predictor",
    "MismatchWatch",
    "capture_led_diameter",
    "tricolor_colors",
]
TWIN_AND_DEVICE = [
    "load_scene",
    "IndenterConfig size",
    "CameraSettings",
    "CameraSettings flag",
    "open_source",
    "open_source settings",
    "to_stored",
    "lights_out_on_exit",
    "start_board",
    "VirtualBoard",
    "VirtualBoard baudrate",
    "AdalightController.open",
    "SaveSink",
    "stream",
    "stream sinks",
]


def _one_line_naming(call, said: str) -> None:
    with pytest.raises(NlipsError) as raised:
        call()
    message = str(raised.value)
    assert said in message and "\n" not in message, message


@pytest.mark.parametrize("case", CORE)
def test_a_documented_function_given_another_kind_is_one_error_naming_the_argument(sensor, case):
    said, call = _calls(sensor)[case]
    _one_line_naming(call, said)


@pytest.mark.parametrize("case", TWIN_AND_DEVICE)
def test_a_documented_twin_or_device_function_given_another_kind_is_one_error_naming_it(sensor, case):
    pytest.importorskip("cv2")
    said, call = _twin_and_device_calls(sensor)[case]
    _one_line_naming(call, said)


def test_every_case_is_run():
    """The lists name every case of the tables (a case added to a table but not its list would never run)."""
    from pathlib import Path

    names = {"root": Path("x"), "reference": "r", "press": "p", "loaded": None}  # the calls are not made
    assert sorted(CORE) == sorted(_calls(names)) and sorted(TWIN_AND_DEVICE) == sorted(_twin_and_device_calls(names))
