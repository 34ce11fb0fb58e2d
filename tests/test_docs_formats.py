"""docs/formats.md names every top-level key the writers put into the JSON files it describes."""

from __future__ import annotations

import ast
import dataclasses
import json
import re
from pathlib import Path

import numpy as np

from nlipscalib.core import Camera, Led, SensorResponse, write_press
from nlipscalib.learn.dataset import SamplingConfig, write_index

FORMATS = Path(__file__).resolve().parents[1] / "docs" / "formats.md"


def _section(start: str, end: str) -> str:
    text = FORMATS.read_text(encoding="utf-8")
    return text[text.index(start) : text.index(end)]


def _undocumented(keys, section: str) -> list[str]:
    named = set(re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", section))
    return sorted(set(keys) - named)


def test_every_index_json_key_is_documented(tmp_path):
    # smoothing_colour is written whenever it is not 0 (its default, 0.08, included), so it is checked too
    write_index(tmp_path, {"camera": {}}, SamplingConfig(), [], str(tmp_path))
    index = json.loads((tmp_path / "index.json").read_text(encoding="utf-8"))
    section = _section("# Calibration dataset", "# NLiPsNet model file")
    assert _undocumented(index, section) == []
    assert _undocumented(index["sampling"], section) == []
    assert {"reference", "software_version"} <= set(index)  # the two keys the document once left out
    assert [f.name for f in dataclasses.fields(SamplingConfig)] == list(index["sampling"])


def test_every_meta_json_key_is_documented(tmp_path):
    camera = Camera(4, 3, 2.0, 2.0, 1.5, 1.0, "brown", (0.0,) * 5)
    leds = [Led((float(i), 0.0, -1.0)) for i in range(3)]
    img = np.zeros((3, 4, 3), np.uint16)
    folder = write_press(tmp_path / "p", camera, leds, SensorResponse(), img, np.stack([img] * 3), img)
    meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
    section = _section("## meta.json", "## reference.npz")
    assert _undocumented(meta, section) == []
    assert _undocumented(meta["sensor"], section) == []
    assert _undocumented(meta["camera"], section) == []
    assert _undocumented(meta["leds"][0], section) == []


def test_the_dataset_spec_section_documents_every_key_and_its_example_loads(tmp_path):
    """A lab's own spec (`nlips dataset SPEC`) had no description outside the source: the README's "or a spec file
    of yours" left a new user reading dataset_spec.py to make even a small try-out."""
    from nlipscalib.sim.dataset import DatasetSpec, GridSpec, RandomSpec, expand_jobs, load_dataset_spec

    section = _section("# Dataset spec", "# Reconstruction format")
    for cls in (DatasetSpec, GridSpec, RandomSpec):
        assert _undocumented([f.name for f in dataclasses.fields(cls)], section) == [], cls.__name__
    (example,) = re.findall(r"```toml\n(.*?)```", section, re.S)
    (tmp_path / "tiny.toml").write_text(example, encoding="utf-8")
    spec, scene = load_dataset_spec(tmp_path / "tiny.toml")
    jobs = expand_jobs(spec)
    assert [j.name for j in jobs] == ["reference"] + [f"press_{i:04d}" for i in range(1, 7)]  # as the text says
    assert (scene.camera.width, scene.camera.height, scene.render.bounces) == (160, 120, 1)


def _literal_keys(module: str, function: str, variable: str | None = None) -> list[str]:
    """The string keys of the dict literal(s) assigned to ``variable`` (None: returned; also a call's keyword
    argument of that name) in ``function`` of ``module`` (a dotted name under nlipscalib/), nested dicts included:
    what a writer puts into its file, read from its source, for writers that need a whole run (a training, an
    experiment, a stream, a camera) to produce the file."""
    import ast

    source = Path(__file__).resolve().parents[1] / "nlipscalib" / (module.replace(".", "/") + ".py")
    tree = ast.parse(source.read_text(encoding="utf-8"))
    (func,) = [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef) and n.name == function]
    values = [
        n.value
        for n in ast.walk(func)
        if (isinstance(n, ast.Return) and variable is None)
        or (isinstance(n, ast.Assign) and any(isinstance(t, ast.Name) and t.id == variable for t in n.targets))
        or (isinstance(n, ast.keyword) and variable is not None and n.arg == variable)
    ]
    assert values, f"{module}.{function} makes no {variable or 'return value'}"
    return [
        k.value
        for value in values
        for d in ast.walk(value)
        if isinstance(d, ast.Dict)
        for k in d.keys
        if isinstance(k, ast.Constant) and isinstance(k.value, str)
    ]


def test_a_twin_press_provenance_and_dataset_json_keys_are_documented(tmp_path):
    """meta.json's `provenance.press` and dataset.json were "indenter and place" and "the spec, the scene and every
    press": a lab's tool reading them had to guess the key names."""
    from nlipscalib.core.config import to_mapping
    from nlipscalib.sim.dataset import expand_jobs, load_dataset_spec
    from nlipscalib.sim.dataset_manifest import manifest_text

    (example,) = re.findall(r"```toml\n(.*?)```", _section("# Dataset spec", "# Reconstruction format"), re.S)
    (tmp_path / "tiny.toml").write_text(example, encoding="utf-8")
    spec, scene = load_dataset_spec(tmp_path / "tiny.toml")
    jobs = expand_jobs(spec)
    press = to_mapping(jobs[1].press)  # as sim.press writes it into provenance.press
    meta_section = _section("## meta.json", "## reference.npz")
    assert _undocumented(press, meta_section) == []
    assert _undocumented(press["indenter"], meta_section) == []
    manifest = json.loads(manifest_text(spec, scene, jobs))
    dataset_json = _section("`dataset.json` beside", "## Images")
    assert _undocumented(manifest, dataset_json) == []
    assert _undocumented(manifest["presses"][1], dataset_json) == []


def test_led_file_sensor_description_and_camera_calibration_keys_are_documented():
    from nlipscalib.core import Camera, Led
    from nlipscalib.core.sensor_record import describe_sensor
    from nlipscalib.device.camera_calibration import Calibration
    from nlipscalib.solver.calibrate import LedCalibration

    led = Led((1.0, 0.0, 0.0))
    cal = LedCalibration(
        leds=(led,), albedo=(1.0, 1.0, 1.0), std=[{}], rms=[0.0], emitters=(led,), led_radius=1.8,
        reflectance_profile={}, quality={},
    )  # fmt: skip
    led_file = _section("## LED file", "## Camera response file")
    assert _undocumented(cal.to_json(), led_file) == []
    assert _undocumented(["leds", "sensor"], led_file) == []  # core.ledfile.save_leds's and cli.calibrate's
    assert _undocumented(_literal_keys("solver.calibration_quality", "fit_quality"), led_file) == []
    camera = Camera(4, 3, 2.0, 2.0, 1.5, 1.0)
    sensor = describe_sensor(camera, [led] * 3, SensorResponse())
    assert _undocumented(sensor, _section("## Sensor description", "# Dataset spec")) == []
    calibration = Calibration(camera, 0.1, (0.1,), ("a.png",), ())
    assert _undocumented(calibration.to_dict(), _section("## Camera calibration", "## Sensor description")) == []


def test_camera_response_file_and_device_press_provenance_keys_are_documented():
    """The response file's keys and its provenance's (nested ``monotonic`` too), and what a device or emulated
    press records in meta.json ``provenance`` beside the session's own keys (the camera, the measured response)."""
    response_file = _section("## Camera response file", "## Camera calibration")
    assert _undocumented(_literal_keys("core.response_curve", "write_response_file", "doc"), response_file) == []
    assert _undocumented(_literal_keys("cli.camera_response", "_fit_and_write", "provenance"), response_file) == []
    device = _section("Device presses record in `provenance`", "`reference.npz` of device presses")
    keys = [
        *_literal_keys("cli.capture", "_run_device", "provenance"),
        *_literal_keys("cli.capture", "response_provenance"),
        *_literal_keys("emulator", "open_emulated_sensor", "provenance"),
        *_literal_keys("device.recording_resume", "read_record"),  # a recorded camera's frames read (s41)
    ]
    assert {"camera_gamma", "camera_response", "tone_curve", "from_frame"} <= set(keys)  # the check reads the writers
    from nlipscalib.device.recording_resume import RECORD_KEY

    assert _undocumented([*keys, RECORD_KEY], device) == []


def test_report_json_interreflection_model_onnx_stream_and_experiment_keys_are_documented():
    report_json = _section("## report.json", "`provenance` (written by")
    assert _undocumented(_literal_keys("solver.indirect", "to_json"), report_json) == []
    model = _section("# NLiPsNet model file", "`MODEL.onnx` beside it")
    assert _undocumented(_literal_keys("learn.model", "save_model", "payload"), model) == []
    onnx = _section("`MODEL.onnx` beside it", "The ONNX graph")
    assert _undocumented(_literal_keys("learn.onnx_export", "export_proto", "meta"), onnx) == []
    stream = _section("`nlips infer MODEL VIDEO", "## PLY")
    assert _undocumented(_literal_keys("cli.infer", "_write_stream_report", "report"), stream) == []
    results = _section("# Experiment report", "# Disk cache")
    assert _undocumented(_literal_keys("experiments.framework", "run_experiment", "doc"), results) == []


def test_the_ply_section_describes_what_write_ply_writes(tmp_path):
    from nlipscalib.learn.ply import write_ply

    points = np.zeros((2, 2, 3), np.float32)
    points[0, 0] = np.nan
    path = write_ply(tmp_path / "p.ply", points, points, mesh=True)
    header = path.read_bytes().split(b"end_header\n")[0].decode().splitlines()
    section = _section("## PLY", "# Experiment report")
    assert "binary little-endian PLY 1.0" in section and header[1] == "format binary_little_endian 1.0"
    (comment,) = [line.removeprefix("comment ") for line in header if line.startswith("comment ")]
    assert f"`{comment}`" in section
    properties = [line.split()[-1] for line in header if line.startswith("property")]
    assert properties == ["x", "y", "z", "nx", "ny", "nz", "vertex_indices"]
    assert "`float x, y, z`" in section and "`float nx, ny, nz`" in section
    assert "`list uchar int vertex_indices`" in section


def test_every_coverage_json_key_is_documented():
    section = _section("coverage.json (", "# NLiPsNet model file")
    for function in ("coverage", "steep_gap", "_next_press"):
        assert _undocumented(_literal_keys("learn.coverage", function), section) == [], function


def test_conventions_md_tricolor_rule_and_normal_map_colours():
    """docs/conventions.md: the tri-colour grouping is given as a formula a lab's own capture tool can follow (it
    only named the Python function), and the normal-map colours as a formula; both are checked against the code."""
    from nlipscalib.core import tricolor_groups
    from nlipscalib.report import normals_to_rgb

    text = (FORMATS.parent / "conventions.md").read_text(encoding="utf-8")
    assert "group floor(3 i / L)" in text and "13 LEDs: 1-5 red, 6-9 green, 10-13 blue" in text
    for n in range(3, 40):
        assert tricolor_groups(n).tolist() == [3 * i // n for i in range(n)]
    assert [list(tricolor_groups(13)).count(g) for g in range(3)] == [5, 4, 4]
    assert "RGB = ((n_x, -n_y, -n_z) + 1) / 2" in text
    n = np.array([[[0.6, 0.0, -0.8], [0.0, -0.6, -0.8]]])
    np.testing.assert_allclose(normals_to_rgb(n), (n * [1, -1, -1] + 1) / 2, atol=1e-6)


def test_a_press_written_from_formats_md_alone_loads(tmp_path):
    """A lab's own capture tool writes press folders from docs/formats.md, not with write_press: the smallest folder
    the page allows (the required keys, every default left out, a `brown` lens without `dist`, a key of the lab's
    own, images written by OpenCV from BGR arrays, reference.npz by plain np.savez) must load as the page says."""
    import cv2

    from nlipscalib.core import load_press

    h, w, n = 12, 16, 3
    folder = tmp_path / "press_0001"
    folder.mkdir()
    rng = np.random.default_rng(0)
    rgb = {name: rng.integers(256, 60000, (h, w, 3), dtype=np.uint16) for name in ["dark", "tricolor", "led_01"]}
    rgb |= {f"led_{i:02d}": rgb["led_01"] + 1000 * i for i in (2, 3)}
    for name, image in rgb.items():
        assert cv2.imwrite(str(folder / f"{name}.png"), image[..., ::-1])  # OpenCV's arrays are BGR
    z = np.full((h, w), 10.0, np.float32)
    np.savez(folder / "reference.npz", depth=z, normals=np.broadcast_to([0, 0, -1], (h, w, 3)).astype(np.float32))
    meta = {
        "format": "nlipscalib.press",
        "format_version": 1,
        "camera": {"width": w, "height": h, "fx": 12.0, "fy": 12.0, "cx": 7.5, "cy": 5.5, "model": "brown"},
        "leds": [{"position": [5.0 * np.cos(a), 5.0 * np.sin(a), 0.0]} for a in (0.0, 2.1, 4.2)],
        "sensor": {},
        "images": {"dark": "dark.png", "leds": [f"led_{i:02d}.png" for i in (1, 2, 3)], "tricolor": "tricolor.png"},
        "reference": "reference.npz",
        "lab_station": "bench 2",  # formats.md: other top-level keys are ignored
    }
    (folder / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    press = load_press(folder)
    np.testing.assert_array_equal(press.dark, rgb["dark"])  # RGB in memory as in the file
    np.testing.assert_array_equal(press.led_images, np.stack([rgb[f"led_{i:02d}"] for i in (1, 2, 3)]))
    assert press.camera.dist == (0.0,) * 5 and len(press.leds) == n
    # the page's defaults (no response_curve: only a measured response has one)
    assert dataclasses.astuple(press.response) == (12, 256, 65520, 10, 1, "linear", None)
    assert [led.direction for led in press.leds] == [(0.0, 0.0, 1.0)] * n and press.leds[0].mu == 1.0
    np.testing.assert_array_equal(press.reference.depth, z)
    section = _section("## meta.json", "## reference.npz")
    assert 'missing keys take the defaults 12, 256, 65520, 10, 1, `"linear"`' in section
    assert "Other top-level keys are ignored" in section


def test_session_times_are_written_as_formats_md_shows_them():
    """docs/formats.md, "Capture sessions": `started` and `captured_at` are ISO 8601 with the offset written without
    a colon (``time.strftime("%z")``); a lab parsing them needs the form, not only "ISO 8601"."""
    import datetime

    example = re.search(r"no colon: `([^`]+)`", _section("## Capture sessions", "## LED file")).group(1)
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d[+-]\d{4}", example)
    assert datetime.datetime.fromisoformat(example).utcoffset() == datetime.timedelta(hours=1)
    assert _literal_strftime("device.session") == {"%Y-%m-%dT%H:%M:%S%z"}


def _literal_strftime(module: str) -> set[str]:
    """The format strings ``module`` gives time.strftime."""
    import ast

    source = Path(__file__).resolve().parents[1] / "nlipscalib" / (module.replace(".", "/") + ".py")
    calls = [n for n in ast.walk(ast.parse(source.read_text(encoding="utf-8"))) if isinstance(n, ast.Call)]
    return {c.args[0].value for c in calls if getattr(c.func, "attr", "") == "strftime"}


def test_the_disk_cache_section_describes_an_entry_byte_for_byte_and_names_every_kept_kind(tmp_path):
    """An entry written by ``diskcache.store`` is read back by the layout the page gives alone (magic line, sizes,
    pickle, 64-byte aligned buffers), and every kind the package keeps on disk is one of the page's folders."""
    import pickle
    import struct

    from nlipscalib.core import diskcache

    section = FORMATS.read_text(encoding="utf-8")[FORMATS.read_text(encoding="utf-8").index("# Disk cache") :]
    magic = re.search(r"the line `(nlipscalib\.diskcache/\d+)`", section).group(1)
    tag = re.search(r'pickle \(protocol 5\) of \(`"([^"]+)"`', section).group(1)
    align = int(re.search(r"multiple of (\d+) bytes", section).group(1))
    value = {"a": np.arange(7, dtype=np.float32), "b": np.ones((3, 5)), "note": "x"}
    path = tmp_path / "surface" / "entry.pkl"
    path.parent.mkdir()
    diskcache.store(path, value)
    data = path.read_bytes()
    head = (magic + "\n").encode()
    assert data.startswith(head)
    n_pickle, n_buffers = struct.unpack_from("<QQ", data, len(head))
    offset = len(head) + 16
    sizes = struct.unpack_from(f"<{n_buffers}Q", data, offset)
    offset += 8 * n_buffers
    pickled = data[offset : offset + n_pickle]
    offset += n_pickle
    buffers = []
    for size in sizes:
        start = -(-offset // align) * align
        assert data[offset:start].strip(b"\0") == b""  # only zeros pad a buffer to its aligned start
        buffers.append(data[start : start + size])
        offset = start + size
    assert offset == len(data)
    read_tag, read = pickle.loads(pickled, buffers=buffers)
    assert read_tag == tag
    assert read["note"] == "x" and np.array_equal(read["a"], value["a"]) and np.array_equal(read["b"], value["b"])

    folders = set(re.search(r"\n  (surface/<digest>\.pkl.*)\n", section).group(1).replace("<digest>.pkl", "").split())
    persisted = set()  # kinds of reuse.reused(KIND, ..., persist=<not False>) and diskcache.entry(KIND, ...)
    for file in (FORMATS.parents[1] / "nlipscalib").rglob("*.py"):
        for node in ast.walk(ast.parse(file.read_text(encoding="utf-8"))):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.args):
                continue
            kind = node.args[0].value if isinstance(node.args[0], ast.Constant) else None
            persist = [k.value for k in node.keywords if k.arg == "persist"]
            kept = persist and not (isinstance(persist[0], ast.Constant) and persist[0].value is False)
            if isinstance(kind, str) and (node.func.attr == "entry" or (node.func.attr == "reused" and kept)):
                persisted.add(kind)
    assert len(persisted) >= 7  # the source was read (a renamed call would otherwise pass silently)
    assert {k.replace(" ", "_") + "/" for k in persisted} == folders


def test_the_model_file_section_names_the_reference_arrays_and_the_onnx_versions_the_code_uses():
    from nlipscalib.learn import onnx_export
    from nlipscalib.learn.model import REFERENCE_ARRAYS

    model = _section("# NLiPsNet model file", "`nlips infer` writes `PRESS/nlipsnet/`")
    reference = re.search(
        r"`reference` \(the sensor\.npz arrays inference reads.*?; change detection", model, re.S
    ).group(0)
    assert set(re.findall(r"`(\w+)`", reference)) - {"reference"} == set(REFERENCE_ARRAYS)
    assert f"opset {onnx_export.OPSET}, IR version {onnx_export.IR_VERSION}" in model


def _subscript_report_keys(path: Path) -> list[str]:
    """The string keys ``path`` assigns one by one into a report dict (``rep["key"] = ...``,
    ``result.report["key"] = ...``): the keys a solve adds after its report's dict literal."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return [
        target.slice.value
        for node in ast.walk(tree)
        if isinstance(node, ast.Assign)
        for target in node.targets
        if isinstance(target, ast.Subscript)
        and isinstance(target.slice, ast.Constant)
        and isinstance(target.slice.value, str)
        and (ast.unparse(target.value) == "rep" or ast.unparse(target.value).endswith("report"))
    ]


def test_every_key_a_solve_adds_to_report_json_and_every_solver_keyword_setting_is_documented():
    """s28 added report.json's `reference_gain` (the undeformed capture's light scaled to the press's) and
    `sensor_check` (what --allow-sensor-misfit overrode) without a row in the table, and the settings'
    `check_sensor` / `reorder_leds` (--allow-sensor-misfit, --keep-led-order) went unnamed."""
    from nlipscalib.cli.solve import SOLVER_KEYWORDS

    solver = Path(__file__).resolve().parents[1] / "nlipscalib" / "solver"
    keys = [k for path in sorted(solver.glob("*.py")) for k in _subscript_report_keys(path)]
    assert {"reference_gain", "sensor_check", "leds_reordered"} <= set(keys)  # the source was read
    assert _undocumented(keys, _section("## report.json", "`provenance` (written by")) == []
    settings = _section("| `settings.solver_keywords`", "| `inputs.press`")
    assert _undocumented(SOLVER_KEYWORDS, settings) == []


def test_files_from_older_versions_names_the_format_versions_each_reader_reads():
    """The section said captures were "format 1, the only one so far" after s28 wrote sRGB captures as 2."""
    from nlipscalib.core import press_meta
    from nlipscalib.learn import dataset, model

    section = _section("# Files from older versions", "- **Reconstructions**") + _section(
        "- **Calibration datasets**", "- **LED files**"
    )
    read = {"Captures": press_meta.READ_VERSIONS, "Calibration datasets": (dataset.FORMAT_VERSION,)}
    read["Models"] = model.MODEL_READ_VERSIONS
    for kind, versions in read.items():
        (said,) = re.findall(rf"- \*\*{kind}\*\* \(([^)]*)\)", section)
        assert {int(n) for n in re.findall(r"\d+", said)} == set(versions), kind


def test_the_model_file_section_names_every_info_key_the_training_writes():
    """s28-tinynet added the model's `info.contacts` (what `nlips infer`'s small-contact warning reads) without a word
    in the model file's section."""
    from nlipscalib.learn.resolution import INFO_KEY

    model = _section("# NLiPsNet model file", "`MODEL.onnx` beside it")
    info = _literal_keys("learn.train", "_save_trained", "info")
    assert "samples_digest" in info  # the source was read
    contacts = _literal_keys("learn.resolution", "calibrated_contacts")
    assert _undocumented([*info, INFO_KEY, *contacts], model) == []


def test_the_press_script_example_loads_as_documented(tmp_path):
    """The `--script` format was documented nowhere but in the emulator's docstring (s35-walk): its example loads,
    with the moved pose and the default frames before the move the section states."""
    from nlipscalib.emulator import load_script

    (example,) = re.findall(r"```toml\n(.*?)```", _section("## Press script", "# Dataset spec"), re.S)
    (tmp_path / "script.toml").write_text(example, encoding="utf-8")
    coin, cube = load_script(tmp_path / "script.toml")
    assert (coin.press.indenter.kind, coin.moved) == ("coin", None)
    assert cube.press.indenter.kind == "cube" and cube.press.indenter.size == 5.0
    assert cube.moved.azimuth_deg == 30.0 and cube.moved.polar_deg == cube.press.polar_deg == 20.0
    assert cube.move_after_frames == 5 and "default 5" in _section("## Press script", "# Dataset spec")
