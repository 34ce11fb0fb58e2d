"""The public API's entry points given each kind of mistake a lab's script makes (a float or a string for a whole
count, a negative count, a string for a flag, a dict or another class's instance for a config, a list for an array,
None where a path is needed, a misspelt keyword): one NlipsError line naming the argument, raised before any work.

Why: s37 checked one wrong kind per function of docs/api.md (tests/test_api_kinds.py); s38-apikinds walked every
keyword of ``run_experiment``, ``run_dataset`` and the solve entries (``solve_press``, ``solver.solve``,
``solve_folder``, ``solve_presses``, ``calibrate_leds``) and the rest of the page, and found them failing deep inside
("'str' object has no attribute 'tasks'", "'<' not supported between instances of 'str' and 'int'", a SystemError
from inside Mitsuba for ``render_press(seed=1.5)``), or running on: ``solve_press(press, max_outer=-1)``,
``check_sensor="no"`` (truthy: the check stayed on), ``roi=(0.5, 0, 20, 20)`` (taken for 0), ``run_experiment(...,
workers=0)``, ``run_dataset(..., stale_s=-1)``, ``SolverOptions(max_iters=2.5)``, ``render_press(..., seed="1")``.
"""

from __future__ import annotations

import numpy as np
import pytest

from nlipscalib.core.errors import NlipsError
from tests.solver import synth

SIZE = (64, 48)


@pytest.fixture(scope="module")
def sensor(tmp_path_factory):
    """A tiny exact-data press and its reference (with ground truth), loaded, and an output folder."""
    from nlipscalib.core import load_press

    root = tmp_path_factory.mktemp("api_kinds_entries")
    reference = synth.make_press(root / "reference", "none", size=SIZE)
    press = synth.make_press(root / "press", "sphere", size=SIZE)
    return {"root": root, "reference": reference, "press": press, "loaded": load_press(press)}


def _experiment_calls(s):
    from nlipscalib.experiments import get
    from nlipscalib.experiments.framework import run_experiment
    from nlipscalib.learn.train import TrainConfig
    from nlipscalib.solver import SolverOptions

    q1 = get("q1")
    cfg, out = q1.config("quick"), s["root"] / "experiment"

    def run(*args, **kwargs):
        given = dict(zip(("exp", "cfg", "out", "report"), args))
        call = {"exp": q1, "cfg": cfg, "out": out, "report": out / "report", "size": "quick"} | given | kwargs
        return lambda: run_experiment(call.pop("exp"), call.pop("cfg"), call.pop("out"), call.pop("report"), **call)

    return {
        "exp a name": ("exp must be an Experiment", run("q1")),
        "cfg a dict": ("cfg must be a Q1Config", run(q1, {"presses": 1})),
        "cfg of another class": ("cfg must be a Q1Config", run(q1, TrainConfig())),
        "cfg None": ("cfg must be a Q1Config", run(q1, None)),
        "out a number": ("out must be", run(q1, cfg, 3)),
        "report None": ("report must be", run(q1, cfg, out, None)),
        "size a number": ("size must be", run(size=3)),
        "workers a float": ("workers must be a whole number >= 1, got float 2.0", run(workers=2.0)),
        "workers a string": ("workers must be a whole number", run(workers="2")),
        "workers 0": ("workers must be a whole number >= 1, got 0", run(workers=0)),
        "scheduler a number": ("scheduler must be", run(scheduler=3)),
        "solver_options a string": ("solver_options must be a dict", run(solver_options="fast")),
        "solver_options a SolverOptions": ("solver_options must be a dict", run(solver_options=SolverOptions())),
        "solver_options a misspelt field": (
            "solver_options: unknown key(s) ['max_iter']",
            run(solver_options={"max_iter": 2}),
        ),
        "solver_options a field's kind": (
            "solver_options.max_iters: expected an integer",
            run(solver_options={"max_iters": "2"}),
        ),
        "keep_presses a string": ("keep_presses must be True or False", run(keep_presses="no")),
    }


def _dataset_calls(s):
    from nlipscalib.core.config import from_mapping
    from nlipscalib.sim.dataset import DatasetSpec, expand_jobs, run_dataset
    from nlipscalib.sim.scene import load_scene

    grid = {"indenters": [{"kind": "sphere", "size": 6.0}], "polar_deg": [10], "azimuth_deg": [0], "depth": [1.0]}
    spec = from_mapping(DatasetSpec, {"grid": grid}, "spec")
    scene, jobs, out = load_scene("nlipstac"), expand_jobs(spec), s["root"] / "dataset"

    def run(**kwargs):
        call = {"scene": scene, "jobs": jobs, "out": out, "workers": 1, "progress": False} | kwargs
        return lambda: run_dataset(**call)

    return {
        "scene a name": ("scene must be a SceneConfig", run(scene="nlipstac")),
        "scene a dict": ("scene must be a SceneConfig", run(scene={"camera": {}})),
        "scene the spec": ("scene must be a SceneConfig", run(scene=spec)),
        "jobs a number": ("jobs must be a list of PressJob", run(jobs=3)),
        "jobs the spec": ("jobs must be a list of PressJob", run(jobs=spec)),
        "jobs names": ("jobs[0] must be a PressJob, got str", run(jobs=["press_0001"])),
        "out None": ("out must be", run(out=None)),
        "workers a float": ("workers must be a whole number >= 0, got float 1.5", run(workers=1.5)),
        "workers a string": ("workers must be a whole number", run(workers="2")),
        "workers negative": ("workers must be a whole number >= 0, got -1", run(workers=-1)),
        "stale_s a string": ("stale_s must be a number", run(stale_s="60")),
        "stale_s negative": ("stale_s must be > 0 seconds", run(stale_s=-1)),
        "verify a string": ("verify must be True or False", run(verify="no")),
    }


def _solve_press_calls(s):
    from nlipscalib.solver import solve_press

    press = s["loaded"]

    def run(**kwargs):
        return lambda: solve_press(press, **kwargs)

    return {
        "press None": ("press must be a Press", lambda: solve_press(None)),
        "indirect of another shape": (
            "indirect must be the undeformed capture or (12, 48, 64, 3)",
            run(indirect=np.zeros((2, 2))),
        ),
        "roi not whole pixels": ("roi must be (x0, y0, w, h) pixels", run(roi=(0.5, 0, 20, 20))),
        "roi two numbers": ("roi must be (x0, y0, w, h) pixels", run(roi=[1, 2])),
        "progress a string": ("progress must be True or False", run(progress="yes")),
        "max_outer a float": ("max_outer must be a whole number >= 0, got float 2.5", run(max_outer=2.5)),
        "max_outer negative": ("max_outer must be a whole number >= 0, got -1", run(max_outer=-1)),
        "max_outer a string": ("max_outer must be a whole number", run(max_outer="2")),
        "bounces a float": ("bounces must be 1 or 2, got 1.0", run(bounces=1.0)),
        "outer_relaxation a flag": ("outer_relaxation must be 'auto' or a number", run(outer_relaxation=True)),
        "coating_albedo a string": ("coating reflectance", run(coating_albedo="0.5")),
        "check_sensor a string": ("check_sensor must be True or False or None", run(check_sensor="no")),
        "reorder_leds a string": ("reorder_leds must be True or False", run(reorder_leds="no")),
        "dent_interreflection a string": ("dent_interreflection must be True or False", run(dent_interreflection="no")),
        "light_gain a string": ("light_gain must be 3 numbers", run(light_gain="1")),
        "light_gain two numbers": ("light_gain must be 3 numbers", run(light_gain=[1.0, 2.0])),
        "led_radius a string": ("led_radius must be a number", run(led_radius="1.8")),
        "led_radius negative": ("led_radius must be a finite radius >= 0 mm", run(led_radius=-1.0)),
        "emitters a number": ("emitters must be a sequence of Led", run(emitters=3, led_radius=1.8)),
        "a misspelt keyword": ("solve_press has no keyword 'roii' (did you mean 'roi'?)", run(roii="auto")),
    }


def _solve_calls(s):
    from nlipscalib.solver import solve

    press = s["loaded"]
    images = press.linear(press.led_images)

    def run(*args, **kwargs):
        given = dict(zip(("images", "camera", "leds"), args))
        call = {"images": images, "camera": press.camera, "leds": press.leds} | given | kwargs
        return lambda: solve(call.pop("images"), call.pop("camera"), call.pop("leds"), **call)

    return {
        "images a list": ("images must be an (L, H, W, 3) float array", run(images.tolist())),
        "camera a dict": ("camera must be a Camera", run(images, {"fx": 100.0})),
        "leds numbers": ("leds must be a sequence of Led", run(images, press.camera, [1, 2, 3])),
        "options a dict": ("options must be a SolverOptions", run(options={"max_iters": 2})),
        "unrefined a float": ("unrefined must be a whole number >= 0, got float 1.5", run(unrefined=1.5)),
        "led_radius a string": ("led_radius must be a number", run(led_radius="1")),
    }


def _pipeline_calls(s):
    from nlipscalib.pipeline import solve_folder, solve_presses
    from nlipscalib.solver import calibrate_leds

    press, reference = s["press"], s["reference"]
    return {
        "solve_folder leds a number": ("leds must be an LED file's path", lambda: solve_folder(press, leds=3)),
        "solve_folder overwrite a string": (
            "overwrite must be True or False",
            lambda: solve_folder(press, overwrite="no"),
        ),
        "solve_folder out a number": ("out must be the result folder's path", lambda: solve_folder(press, out=3)),
        "solve_folder roi not whole pixels": (
            "roi must be (x0, y0, w, h) pixels",
            lambda: solve_folder(press, roi=(0.5, 0, 20, 20)),
        ),
        "solve_folder solver_keywords a string": (
            "solver_keywords must be a dict",
            lambda: solve_folder(press, solver_keywords="fast"),
        ),
        "solve_folder solver_keywords' kind": (
            "max_outer must be a whole number",
            lambda: solve_folder(press, solver_keywords={"max_outer": "2"}),
        ),
        "solve_presses workers a float": (
            "workers must be a whole number >= 1, got float 2.0",
            lambda: solve_presses([press], workers=2.0),
        ),
        "solve_presses workers a flag": (
            "workers must be a whole number >= 1, got bool",
            lambda: solve_presses([press], workers=True),
        ),
        "solve_presses folders a dict": (
            "folders must be a list of press folders",
            lambda: solve_presses({"a": press}),
        ),
        "solve_presses wait a string": ("wait must be True or False", lambda: solve_presses([press], wait="no")),
        "calibrate_leds led_radius negative": (
            "led_radius must be a finite radius >= 0 mm",
            lambda: calibrate_leds(reference, led_radius=-1.0),
        ),
        "calibrate_leds stride a float": (
            "stride must be a whole number >= 1",
            lambda: calibrate_leds(reference, stride=2.5),
        ),
        "calibrate_leds initial numbers": (
            "initial must be a sequence of Led",
            lambda: calibrate_leds(reference, initial=[1, 2]),
        ),
        "calibrate_leds allow_contact a string": (
            "allow_contact must be True or False",
            lambda: calibrate_leds(reference, allow_contact="no"),
        ),
    }


def _rest_calls(s):
    from nlipscalib.core import load_press, load_reconstruction
    from nlipscalib.learn.dataset import build_dataset
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.train import TrainConfig, train
    from nlipscalib.solver import SolverOptions

    press, reference, out = s["press"], s["reference"], s["root"] / "out"
    return {
        "SolverOptions max_iters a float": (
            "solver.max_iters: expected an integer, got 2.5",
            lambda: SolverOptions(max_iters=2.5),
        ),
        "SolverOptions max_iters a string": (
            "solver.max_iters: expected an integer, got '2'",
            lambda: SolverOptions(max_iters="2"),
        ),
        "SolverOptions smoothness a string": (
            "solver.smoothness: expected a number",
            lambda: SolverOptions(smoothness="0.1"),
        ),
        "load_press decode a number": (
            "decode must be True, False or 'background'",
            lambda: load_press(press, decode=3),
        ),
        "load_press led_subset a string": (
            "led_subset must be a sequence of LED indices (0-based integers), got str '0,2'",
            lambda: load_press(press, led_subset="0,2"),
        ),
        "load_press led_subset of fractions": (
            "led_subset must be a sequence of LED indices (0-based integers), got list [1.5]",
            lambda: load_press(press, led_subset=[1.5]),
        ),
        "load_reconstruction shape a string": (
            "shape must be (H, W) pixels",
            lambda: load_reconstruction(out, "64x48"),
        ),
        "build_dataset result_dir a number": (
            "result_dir must be",
            lambda: build_dataset([press], reference, out, result_dir=3),
        ),
        "build_dataset progress a string": (
            "progress must be True or False",
            lambda: build_dataset([press], reference, out, progress="no"),
        ),
        "train dataset a number": (
            "dataset must be a CalibrationDataset",
            lambda: train(3, TrainConfig(), out / "m.pt"),
        ),
        "train progress a string": (
            "progress must be True or False",
            lambda: train(out, TrainConfig(), out / "m.pt", progress="no"),
        ),
        "Predictor backend a number": ("backend must be", lambda: Predictor(out / "m.pt", backend=3)),
        "Predictor depth a string": ("depth must be True or False", lambda: Predictor(out / "m.pt", depth="no")),
    }


def _twin_and_device_calls(s):
    from nlipscalib.device.controller import LedController
    from nlipscalib.device.live import stream
    from nlipscalib.sim.indent import PressConfig
    from nlipscalib.sim.indenters import IndenterConfig
    from nlipscalib.sim.press import render_press
    from nlipscalib.sim.scene import load_scene

    scene, out = load_scene("nlipstac"), s["root"] / "twin"
    sphere = PressConfig(IndenterConfig(kind="sphere", size=6.0), polar_deg=12, azimuth_deg=30, depth=1.2)
    return {
        "render_press seed a float": (
            "seed must be a whole number >= 0, got float 1.5",
            lambda: render_press(scene, sphere, out, seed=1.5),
        ),
        "render_press seed a string": (
            "seed must be a whole number",
            lambda: render_press(scene, sphere, out, seed="1"),
        ),
        "render_press overwrite a string": (
            "overwrite must be True or False",
            lambda: render_press(scene, sphere, out, overwrite="no"),
        ),
        "render_press return_result a string": (
            "return_result must be True or False",
            lambda: render_press(scene, sphere, out, return_result="no"),
        ),
        "IndenterConfig scale_to_size a string": (
            "indenter.scale_to_size: must be true or false",
            lambda: IndenterConfig(kind="sphere", scale_to_size="no"),
        ),
        "SceneConfig.replace a table for a name": (
            "scene.name: expected a string",
            lambda: scene.replace(name={"a": 1}),
        ),
        "stream max_frames negative": (
            "max_frames must be a whole number >= 0, got -1",
            lambda: stream(_Reader(), _predict, [], max_frames=-1),
        ),
        "stream max_frames a float": (
            "max_frames must be a whole number",
            lambda: stream(_Reader(), _predict, [], max_frames=2.5),
        ),
        "LedController.open timeout a string": (
            "timeout must be a number of seconds",
            lambda: LedController.open("loop://", timeout="1"),
        ),
        "LedController.open retries a float": (
            "retries must be a whole number >= 0",
            lambda: LedController.open("loop://", retries=1.5),
        ),
        "LedController.open reconnect_s 0": (
            "reconnect_s must be > 0 seconds",
            lambda: LedController.open("loop://", reconnect_s=0),
        ),
    }


class _Reader:
    def read(self):  # pragma: no cover - never reached: the arguments are refused first
        raise AssertionError


def _predict(frame):  # pragma: no cover - never reached
    raise AssertionError


TABLES = {
    "run_experiment": _experiment_calls,
    "run_dataset": _dataset_calls,
    "solve_press": _solve_press_calls,
    "solve": _solve_calls,
    "pipeline": _pipeline_calls,
    "rest": _rest_calls,
    "twin_and_device": _twin_and_device_calls,
}
CASES = {
    "run_experiment": [
        "exp a name",
        "cfg a dict",
        "cfg of another class",
        "cfg None",
        "out a number",
        "report None",
        "size a number",
        "workers a float",
        "workers a string",
        "workers 0",
        "scheduler a number",
        "solver_options a string",
        "solver_options a SolverOptions",
        "solver_options a misspelt field",
        "solver_options a field's kind",
        "keep_presses a string",
    ],
    "run_dataset": [
        "scene a name",
        "scene a dict",
        "scene the spec",
        "jobs a number",
        "jobs the spec",
        "jobs names",
        "out None",
        "workers a float",
        "workers a string",
        "workers negative",
        "stale_s a string",
        "stale_s negative",
        "verify a string",
    ],
    "solve_press": [
        "press None",
        "indirect of another shape",
        "roi not whole pixels",
        "roi two numbers",
        "progress a string",
        "max_outer a float",
        "max_outer negative",
        "max_outer a string",
        "bounces a float",
        "outer_relaxation a flag",
        "coating_albedo a string",
        "check_sensor a string",
        "reorder_leds a string",
        "dent_interreflection a string",
        "light_gain a string",
        "light_gain two numbers",
        "led_radius a string",
        "led_radius negative",
        "emitters a number",
        "a misspelt keyword",
    ],
    "solve": [
        "images a list",
        "camera a dict",
        "leds numbers",
        "options a dict",
        "unrefined a float",
        "led_radius a string",
    ],
    "pipeline": [
        "solve_folder leds a number",
        "solve_folder overwrite a string",
        "solve_folder out a number",
        "solve_folder roi not whole pixels",
        "solve_folder solver_keywords a string",
        "solve_folder solver_keywords' kind",
        "solve_presses workers a float",
        "solve_presses workers a flag",
        "solve_presses folders a dict",
        "solve_presses wait a string",
        "calibrate_leds led_radius negative",
        "calibrate_leds stride a float",
        "calibrate_leds initial numbers",
        "calibrate_leds allow_contact a string",
    ],
    "rest": [
        "SolverOptions max_iters a float",
        "SolverOptions max_iters a string",
        "SolverOptions smoothness a string",
        "load_press decode a number",
        "load_press led_subset a string",
        "load_press led_subset of fractions",
        "load_reconstruction shape a string",
        "build_dataset result_dir a number",
        "build_dataset progress a string",
        "train dataset a number",
        "train progress a string",
        "Predictor backend a number",
        "Predictor depth a string",
    ],
    "twin_and_device": [
        "render_press seed a float",
        "render_press seed a string",
        "render_press overwrite a string",
        "render_press return_result a string",
        "IndenterConfig scale_to_size a string",
        "SceneConfig.replace a table for a name",
        "stream max_frames negative",
        "stream max_frames a float",
        "LedController.open timeout a string",
        "LedController.open retries a float",
        "LedController.open reconnect_s 0",
    ],
}
PARAMS = [pytest.param(table, case, id=f"{table}: {case}") for table, cases in CASES.items() for case in cases]


@pytest.mark.parametrize(("table", "case"), PARAMS)
def test_an_entry_given_a_mistaken_argument_is_one_error_naming_it_before_any_work(sensor, table, case):
    if table == "twin_and_device":
        pytest.importorskip("serial")
    said, call = TABLES[table](sensor)[case]
    with pytest.raises(NlipsError) as raised:
        call()
    message = str(raised.value)
    assert said in message and "\n" not in message, message


def test_every_case_is_run():
    """The lists name every case of the tables (a case added to a table but not its list would never run)."""
    from pathlib import Path

    from nlipscalib.core import load_press

    root = Path(__file__).parent / "nothing"
    names = {"root": root, "reference": root, "press": root, "loaded": None}
    for table, cases in CASES.items():
        if table in ("solve_press", "solve"):
            continue  # their tables read the loaded press's arrays: checked by the next test
        assert sorted(cases) == sorted(TABLES[table](names)), table
    assert load_press  # imported: the module's dependencies load


def test_the_loaded_press_tables_name_every_case(sensor):
    for table in ("solve_press", "solve"):
        assert sorted(CASES[table]) == sorted(TABLES[table](sensor)), table


@pytest.mark.parametrize(
    "line",
    ["render = 16", 'noise = "high"', "camera = [160, 120]"],
)
def test_a_dataset_spec_section_given_another_kind_is_one_error_naming_the_file_and_key(tmp_path, line):
    """``render = 16`` (for ``render = {spp = 16}``) was taken as the section and failed, or was dropped, later."""
    from nlipscalib.core.errors import ConfigError
    from nlipscalib.sim.dataset import load_dataset_spec

    spec = tmp_path / "spec.toml"
    grid = '[grid]\nindenters = [{kind = "sphere", size = 6.0}]\npolar_deg = [10]\nazimuth_deg = [0]\ndepth = [1.0]\n'
    spec.write_text(f"{line}\n{grid}", encoding="utf-8")
    key = line.split(" = ")[0]
    with pytest.raises(ConfigError, match=rf"^{tmp_path / 'spec.toml'}\.{key}: expected a table"):
        load_dataset_spec(spec)


def _wrong_kind_of(hint):
    """A TOML value of another kind than the annotated field ``hint`` takes (a string for a number, a number for a
    string or a flag)."""
    return {int: "2", float: "0.1", bool: "no", str: 3}.get(hint, {"a": 1})


def test_every_solver_option_given_another_kind_in_a_config_file_is_one_error_naming_it(tmp_path, capsys):
    """``nlips solve --config`` reads SolverOptions through core.config.from_mapping; the same file's fields given
    from Python are checked alike (SolverOptions.__post_init__: check_field_kinds)."""
    import dataclasses
    import typing

    from nlipscalib.core.config import from_mapping
    from nlipscalib.core.errors import ConfigError
    from nlipscalib.solver import SolverOptions

    hints = typing.get_type_hints(SolverOptions)
    for field in dataclasses.fields(SolverOptions):
        wrong = _wrong_kind_of(hints[field.name])
        for make in (
            lambda name, value: from_mapping(SolverOptions, {name: value}, "c.toml"),
            lambda name, value: SolverOptions(**{name: value}),
        ):
            with pytest.raises(ConfigError) as raised:
                make(field.name, wrong)
            message = str(raised.value)
            assert field.name in message and "\n" not in message, message
