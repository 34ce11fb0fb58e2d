"""A lab's day at the command line (render -> calibrate-leds -> solve -> calibrate -> train -> infer -> eval) typed
with the mistakes people make: each one line naming what was given and what to give, exit 2, nothing written."""

import json

import pytest

from nlipscalib.cli import main
from tests.solver import synth

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
    assert f"give its reference/ ({twin}/reference), an undeformed render" in line and line.endswith(way_out), line
    assert captured.out == ""
    assert not any((twin / name / "nlips").exists() for name in ("press_0001", "press_0002"))
    assert not (twin / "calibration").exists() and not (twin / "leds.json").exists()


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
