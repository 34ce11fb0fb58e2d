"""A lab's day at the command line (render -> calibrate-leds -> solve -> calibrate -> train -> infer -> eval) typed
with the mistakes people make: each one line naming what was given and what to give, exit 2, nothing written."""

import json

import pytest

from nlipscalib.cli import main
from tests.solver import synth
from tests.solver.twin_helpers import recorded_anew

PRESSED = {"indenter": {"kind": "sphere", "size": 6.0}, "polar_deg": 0.0, "azimuth_deg": 0.0, "depth": 1.5}
"""A twin press's description as `nlips render` records it (meta.json's provenance.press)."""


def _as_twin_render(folder, press):
    """``folder``'s meta.json with the provenance the twin writes: ``press`` None for an undeformed render."""
    meta_file = folder / "meta.json"
    meta = json.loads(meta_file.read_text(encoding="utf-8"))
    meta["provenance"] = {"source": "sim", "press": press, "seed": 1}
    meta_file.write_text(json.dumps(meta), encoding="utf-8")


@pytest.fixture
def twin(tmp_path):
    """A folder of two twin presses and their undeformed render reference/ (64x48)."""
    root = tmp_path / "tw"
    synth.make_press(root / "reference", "none", size=(64, 48))
    _as_twin_render(root / "reference", None)
    for i in (1, 2):
        synth.make_press(root / f"press_{i:04d}", "sphere", size=(64, 48))
        _as_twin_render(root / f"press_{i:04d}", PRESSED)
    return root


@pytest.mark.parametrize(
    "command, way_out",
    [
        (["solve", "{root}/press_0001", "--reference", "{root}/press_0002"], "or solve without --reference"),
        (["calibrate", "{root}", "--reference", "{root}/press_0002", "--workers", "1"], "or leave out --reference"),
        (
            ["calibrate-leds", "{root}/press_0002", "--out", "{root}/leds.json"],
            "or pass --allow-contact to fit on it anyway",
        ),
    ],
    ids=lambda c: c[0] if isinstance(c, list) else "",
)
def test_a_twin_press_given_for_the_undeformed_dome_is_refused_before_any_work(twin, capsys, command, way_out):
    """`nlips solve PRESS --reference OTHER_PRESS` (and calibrate's --reference) solved against the other press's
    dented dome, exit 0, its contact and anchoring wrong without a word; `nlips calibrate-leds PRESS` fitted the
    LEDs first (minutes at 640x480) and refused only after the fit."""
    argv = [part.format(root=twin) for part in command]
    assert main(argv) == 2
    captured = capsys.readouterr()
    (line,) = captured.err.strip().splitlines()
    assert line.startswith(
        f"nlips {command[0]}: error: {twin}/press_0002: a press of the twin (a sphere of 6 mm pressed 1.50 mm deep), "
        "not "
    ), line
    assert f"give reference/ ({twin}/reference), an undeformed render" in line and line.endswith(way_out), line
    assert captured.out == ""
    assert not any((twin / name / "nlips").exists() for name in ("press_0001", "press_0002"))
    assert not (twin / "calibration").exists() and not (twin / "leds.json").exists()


def test_a_press_of_another_dataset_given_as_the_reference_names_the_solved_presss_reference(twin, tmp_path, capsys):
    """`nlips solve out/press --reference out/other/press_0001` said "give its reference/ (out/other/reference)":
    the other dataset's undeformed dome, not the solved press's."""
    import shutil

    other = tmp_path / "other"
    other.mkdir()
    shutil.copytree(twin / "press_0002", other / "press_0002")
    shutil.copytree(twin / "reference", other / "reference")
    assert main(["solve", str(twin / "press_0001"), "--reference", str(other / "press_0002")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"give reference/ ({twin}/reference), an undeformed render" in line, line


def test_the_undeformed_render_is_taken_as_the_reference(twin, capsys):
    assert main(["solve", str(twin / "press_0001"), "--reference", str(twin / "reference"), "-q"]) == 0
    assert capsys.readouterr().out == f"{twin / 'press_0001' / 'nlips'}\n"


def _flip_member(npz, member):
    """8 bytes inverted in the middle of ``member``'s stored bytes in the archive ``npz``: whole length, its ends
    as written, the member's CRC-32 failing."""
    import zipfile

    with zipfile.ZipFile(npz) as archive:
        info = archive.getinfo(member)
        start = info.header_offset + 30 + len(info.filename) + len(info.extra) + info.compress_size // 2
    data = bytearray(npz.read_bytes())
    data[start : start + 8] = bytes(b ^ 0xFF for b in data[start : start + 8])
    npz.write_bytes(bytes(data))


def test_eval_of_a_folder_scores_the_others_when_one_ground_truth_is_damaged(twin, tmp_path, capsys):
    """`nlips eval FOLDER` with one press's gt.npz damaged inside: the whole table failed on it (exit 2, nothing
    scored), where a damaged result fails its press alone. Now it is named under the table, the others scored,
    exit 1 (done in part)."""
    config = tmp_path / "quick.toml"
    config.write_text("max_iters = 2\n", encoding="utf-8")
    assert main(["solve", str(twin), "--config", str(config), "--figures", "none", "--workers", "1", "-q"]) == 0
    capsys.readouterr()
    _flip_member(twin / "press_0002" / "gt.npz", "normals.npy")
    assert main(["eval", str(twin)]) == 1
    out, err = capsys.readouterr()
    assert [line.split()[0] for line in out.strip().splitlines()] == ["press", "press_0001"]
    assert f"damaged, not scored: press_0002: {twin / 'press_0002' / 'gt.npz'}: array 'normals' is not readable" in err
    assert "Traceback" not in err
    assert main(["eval", str(twin / "press_0002")]) == 2  # one press: its error, as before
    assert capsys.readouterr().err.startswith(f"nlips eval: error: {twin / 'press_0002' / 'gt.npz'}: array 'normals'")


SPEC = """
scene = "nlipstac"
seed = 2024
reference = true
[camera]
width = 160
height = 120
[random]
count = 2
polar_deg = [0.0, 30.0]
azimuth_deg = [0.0, 360.0]
depth = [0.4, 1.5]
indenters = [{ kind = "sphere", size = 6.0 }]
"""
"""A dataset spec, as docs/formats.md's try-out."""


@pytest.mark.parametrize(
    "command",
    [
        ["solve", "{root}/press_0001", "--config", "{spec}"],
        ["render", "--scene", "{spec}", "--out", "{root}/p9"],
    ],
    ids=lambda c: c[0],
)
def test_a_dataset_spec_given_to_another_command_is_named_as_one(twin, tmp_path, capsys, command):
    """`nlips solve PRESS --config spec.toml` and `nlips render --scene spec.toml` said only "unknown key(s)
    ['camera', 'random', ...]" and the other file's 10-40 keys: nothing said that the file is a dataset spec."""
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC, encoding="utf-8")
    assert main([part.format(root=twin, spec=spec) for part in command]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert (
        f"{spec}: unknown key(s) [" in line and "]; a dataset spec? give it to `nlips dataset SPEC --out DIR`" in line
    )
    assert not (twin / "p9").exists() and not (twin / "press_0001" / "nlips").exists()


# ---------------------------------------------------------------------- the thirty-fourth session's walk (s34-walk)
def test_a_suggested_command_quotes_a_path_with_a_space(tmp_path, capsys):
    """`nlips eval "mes données/press 1"` (and the "next:" lines of calibrate-leds, calibrate, train, capture) printed
    the path bare: the command copied into a shell split it in two."""
    import shlex

    press = tmp_path / "mes données" / "press 1"
    synth.make_press(press, "sphere", size=(64, 48))
    assert main(["eval", str(press)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    command = line.split("(run `", 1)[1].split("`", 1)[0]
    assert shlex.split(command) == ["nlips", "solve", str(press)], line


def test_a_press_given_as_its_own_reference_is_named_so(tmp_path, capsys):
    """`nlips solve P --reference P` (a sensor's press, which nothing marks as pressed) said "P: no press folders
    found" of the press folder it was given."""
    press = tmp_path / "p1"
    synth.make_press(press, "sphere", size=(64, 48))
    assert main(["solve", str(press), "--reference", str(press)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == (
        f"nlips solve: error: {press}: given as the press and as its --reference; --reference names the undeformed "
        "dome's capture (another folder), or solve without --reference"
    )
    assert not (press / "nlips").exists()


@pytest.mark.parametrize(
    "name, what",
    [("meta.json", "a press's meta.json"), ("checksums.json", "a press's checksums.json")],
)
def test_a_press_file_given_as_the_led_file_is_named(twin, capsys, name, what):
    """`nlips solve P --leds P/meta.json` said "'sensor' is not a sensor description (missing key 'camera')": a
    press's meta.json lists its design's LEDs, so it was read as an LED file until its sensor record."""
    press = twin / "press_0001"
    if not (press / name).exists():
        (press / name).write_text('{"format": "nlipscalib.checksums", "format_version": 1}', encoding="utf-8")
    assert main(["solve", str(press), "--leds", str(press / name)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == (
        f"nlips solve: error: {press / name}: {what}, not an LED file: give the .json from `nlips calibrate-leds`"
    )


@pytest.mark.parametrize("out", ["{root}", "{root}/press_0001", "{root}/../other/press"], ids=["root", "press", "ext"])
def test_calibrate_refuses_a_press_folder_or_the_presses_folder_as_its_out(twin, monkeypatch, capsys, out):
    """`nlips calibrate DS --out DS/press_0001` (or `--out DS`) solved every press and wrote index.json, samples/,
    sensor.npz and the coverage in among the press's images (or the presses), exit 0."""
    from nlipscalib.cli import calibration

    synth.make_press(twin.parent / "other" / "press", "sphere", size=(64, 48))
    monkeypatch.setattr(calibration, "solve_all", lambda *a, **k: pytest.fail("presses solved"))
    target = out.format(root=twin)
    assert main(["--no-progress", "calibrate", str(twin), "--out", target]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    what = "the folder of the presses" if out == "{root}" else "a press folder (meta.json)"
    assert line.startswith(f"nlips calibrate: error: --out {target}: {what}; the calibration dataset needs a folder")
    assert not any((twin / name / "index.json").exists() for name in (".", "press_0001"))


@pytest.mark.parametrize(
    "write, problem",
    [
        (lambda img: img[..., 0], "a grey (single-channel) PNG, where a capture's images are RGB (64x48, 3 channels)"),
        (lambda img: (img >> 8).astype("uint8"), "an 8-bit PNG, where a 16-bit PNG is expected"),
    ],
    ids=["grey", "8-bit"],
)
def test_an_led_image_of_another_kind_says_which(tmp_path, capsys, write, problem):
    """A grey LED image said "image is (48, 64), but the camera in meta.json is (48, 64, 3)", an 8-bit one "expected
    a 16-bit PNG, found uint8": NumPy's words for the file's."""
    import cv2

    press = tmp_path / "p1"
    synth.make_press(press, "sphere", size=(64, 48))
    image = press / "led_02.png"
    cv2.imwrite(str(image), write(cv2.imread(str(image), cv2.IMREAD_UNCHANGED)))
    recorded_anew(press)  # written so by its capture (else the checksums check names the file as changed first)
    assert main(["solve", str(press), "--no-figures"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == f"nlips solve: error: {image}: {problem}"


def test_render_over_a_press_of_the_other_kind_names_both_in_words(twin, capsys):
    """`nlips render --undeformed --out PRESS` printed the press's whole description as a Python dict against None."""
    assert main(["render", "--undeformed", "--out", str(twin / "press_0001")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "(a sphere of 6 mm pressed 1.50 mm deep -> the undeformed dome)" in line and "{" not in line, line


@pytest.mark.parametrize(
    "command",
    [
        ["export", "{tmp}/m.pt", "--out", "{tmp}/a file/m.onnx"],
        ["calibrate-camera-response", "--emulate", "nlipstac", "--out", "{tmp}/a file/curve.json"],
    ],
    ids=lambda c: c[0],
)
def test_an_output_that_cannot_be_written_is_refused_before_the_work(tmp_path, monkeypatch, capsys, command):
    """`nlips export --out RO/m.onnx` loaded and exported the model first; `nlips calibrate-camera-response --out
    RO/curve.json` took the whole bracket (17 s emulated; a real camera's 15 exposures) before failing on the disk."""
    from nlipscalib.cli import camera_response
    from nlipscalib.learn import model

    (tmp_path / "a file").write_text("notes", encoding="utf-8")
    monkeypatch.setattr(model, "load_model", lambda *a, **k: pytest.fail("the model was loaded"))
    monkeypatch.setattr(camera_response, "_emulated_bracket", lambda *a, **k: pytest.fail("the bracket was taken"))
    assert main([part.format(tmp=tmp_path) for part in command]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.endswith(
        f"{tmp_path / 'a file'}: a file where a folder is needed (choose another --out, or move the file)"
    )


@pytest.mark.parametrize("subset, why", [("1,1,2", "LED 1 named twice"), ("2,3,3,4,4", "LED 3, 4 named twice")])
def test_an_led_subset_naming_an_led_twice_says_which(tmp_path, capsys, subset, why):
    """`nlips solve P --leds 1,1,2` said "indices must be unique, in range and at least one", naming no LED; then
    (until s39-lutwords) load_press's words, which name its Python argument `led_subset`, not the --leds typed."""
    press = tmp_path / "p1"
    synth.make_press(press, "sphere", size=(64, 48))
    assert main(["solve", str(press), "--leds", subset, "--no-figures"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.endswith(f"has LEDs 1..12: {why}") and "led_subset=" not in line, line


def test_train_on_a_folder_without_index_says_what_it_is_and_what_to_run(twin, tmp_path, capsys):
    """`nlips train` on a half-built dataset (samples/, no index.json: an interrupted `nlips calibrate`), on a folder
    of presses not calibrated yet and on a press folder said alike "FOLDER/index.json: missing; FOLDER is not a
    calibration dataset (run `nlips calibrate`)"."""
    half = tmp_path / "half"
    (half / "samples").mkdir(parents=True)
    cases = {
        half: f"{half / 'index.json'}: missing, though {half} holds samples/: a build that was interrupted (or is "
        f"still running); run `nlips calibrate PRESSES --out {half}` again on the presses it was made from to finish "
        "it (the samples made are kept)",
        twin: f"{twin}: a folder of presses, not a calibration dataset: `nlips calibrate {twin}` makes one "
        f"({twin / 'calibration'}), the folder to give",
        twin / "press_0001": f"{twin / 'press_0001'}: a press folder, not a calibration dataset: `nlips calibrate "
        f"{twin}` makes one from the folder of presses",
    }
    for folder, line in cases.items():
        assert main(["train", str(folder), "--out", str(tmp_path / "m.pt")]) == 2
        assert capsys.readouterr().err.strip().splitlines() == [f"nlips train: error: {line}"]
    assert not (tmp_path / "m.pt").exists()


@pytest.mark.parametrize(
    "command, role",
    [
        (["calibrate-leds", "{result}", "--out", "{root}/leds.json"], "a capture of the undeformed dome"),
        (["solve", "{root}/press_0002", "--reference", "{result}"], "the undeformed dome's capture (--reference)"),
    ],
    ids=lambda c: c[0] if isinstance(c, list) else "",
)
def test_a_result_folder_given_for_the_undeformed_capture_is_named(twin, capsys, command, role):
    """`nlips calibrate-leds PRESS/nlips` (and `--reference PRESS/nlips`) said "PRESS/nlips/meta.json: missing;
    PRESS/nlips is not a complete press folder"."""
    result = twin / "press_0001" / "nlips"
    result.mkdir()
    (result / "result.npz").write_bytes(b"PK")
    (result / "report.json").write_text("{}", encoding="utf-8")
    assert main([part.format(root=twin, result=result) for part in command]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.endswith(
        f": error: {result}: a reconstruction folder (result.npz: the maps made from {twin / 'press_0001'}), not {role}"
    ), line


def test_a_result_of_the_other_method_at_out_is_not_replaced(tmp_path, capsys):
    """`nlips solve PRESS --out PRESS/nlipsnet` replaced the press's NLiPsNet result with an NLiPs one, exit 0 (and
    `nlips eval PRESS --method nlipsnet` then scored NLiPs as NLiPsNet); `nlips infer` likewise over an NLiPs result."""
    press = tmp_path / "p1"
    synth.make_press(press, "sphere", size=(64, 48))
    other = press / "nlipsnet"
    other.mkdir()
    (other / "result.npz").write_bytes(b"PK")
    (other / "report.json").write_text(json.dumps({"method": "nlipsnet"}), encoding="utf-8")
    assert main(["solve", str(press), "--out", str(other), "--no-figures"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == (
        f"nlips solve: error: {other}: holds an NLiPsNet result (`nlips infer`), which this NLiPs result would "
        "replace; move it away or choose another --out"
    )
    assert json.loads((other / "report.json").read_text(encoding="utf-8")) == {"method": "nlipsnet"}


@pytest.mark.parametrize("command", [["infer", "{model}", "{press}"], ["export", "{model}"]], ids=lambda c: c[0])
def test_an_led_file_given_as_the_model_is_named_a_text_file(tmp_path, capsys, command):
    """`nlips infer leds.json PRESS` said "not an NLiPsNet model file (not a torch.save archive)" (s34-walk)."""
    model = tmp_path / "leds.json"
    model.write_text('{"leds": []}', encoding="utf-8")
    press = tmp_path / "p1"
    synth.make_press(press, "sphere", size=(64, 48))
    assert main([part.format(model=model, press=press) for part in command]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.endswith(
        f"{model}: a text file (JSON: an LED file, a camera calibration, a config?), not the model file: give the .pt "
        "file from `nlips train`"
    ), line
