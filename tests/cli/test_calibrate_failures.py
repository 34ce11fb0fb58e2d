"""`nlips calibrate FOLDER` when a press cannot be solved: its cause said once, the press named at the end."""

import json
import logging

from nlipscalib.cli import main
from tests.solver import synth


def _presses(tmp_path, kinds, damaged):
    """A reference and one synthetic press per kind (64x48), press_0001's image ``damaged`` cut to 300 bytes;
    (the presses' folder, the damaged file)."""
    root = tmp_path / "presses"
    synth.make_press(root / "reference", "none", size=(64, 48))
    for i, kind in enumerate(kinds, 1):
        synth.make_press(root / f"press_{i:04d}", kind, size=(64, 48))
    png = root / "press_0001" / damaged
    png.write_bytes(png.read_bytes()[:300])
    return root, png


def test_a_damaged_press_is_reported_once(tmp_path, capsys, caplog):
    """A truncated PNG printed `ERROR press_0001: ...` and then `ERROR press_0001: failed: ...`."""
    caplog.set_level(logging.INFO)
    root, _ = _presses(tmp_path, ("sphere", "cube"), "led_03.png")
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 1
    out, err = capsys.readouterr()
    logged = caplog.text + err  # pytest's handler receives the log; stderr has it when none is installed
    errors = [line for line in logged.splitlines() if "press_0001" in line and "truncated PNG" in line]
    assert len(errors) == 1 and "failed:" not in errors[0], errors
    assert "1 press failed to solve: press_0001" in err and out == f"{root / 'calibration'}\n"


def test_a_damaged_tricolour_image_fails_its_press_only(tmp_path, capsys, caplog):
    """A truncated tricolor.png stopped the whole build after the solves (exit 2), where a damaged LED image
    fails only its press. It is now found before any solve: its press is left out unsolved."""
    caplog.set_level(logging.INFO)
    root, png = _presses(tmp_path, ("sphere", "cube"), "tricolor.png")
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 1
    out, err = capsys.readouterr()
    logged = caplog.text + err
    errors = [line for line in logged.splitlines() if "tricolor.png" in line]
    assert len(errors) == 1 and f"{png}: cut short (no PNG end chunk); the press is left out, not solved" in errors[0]
    assert "calibration: 1 press, " in err
    assert "1 press left out of the dataset (not sampled): press_0001" in err
    assert not (root / "press_0001" / "nlips").exists() and (root / "press_0002" / "nlips" / "result.npz").is_file()
    index = json.loads((root / "calibration" / "index.json").read_text(encoding="utf-8"))
    assert [entry["name"] for entry in index["presses"]] == ["press_0002"]


def _flip_inside(path, at=0.5):
    """``path`` with 8 bytes inverted at the fraction ``at`` of its length: a file of whole length, damaged
    inside (a bad disk block, a bad copy); its ends are as written."""
    data = bytearray(path.read_bytes())
    i = int(len(data) * at)
    data[i : i + 8] = bytes(b ^ 0xFF for b in data[i : i + 8])
    path.write_bytes(bytes(data))


def test_a_tricolour_image_damaged_inside_is_found_before_any_solve(tmp_path, capsys, caplog):
    """A tricolor.png of full length with bytes flipped inside passed every check at its ends: its press was solved
    (minutes at 640x480), then left out by the build with "not a readable PNG image" after libpng's own line. Now
    the chunk whose CRC fails is named before any solve and the press is not solved."""
    caplog.set_level(logging.INFO)
    root, _ = _presses(tmp_path, ("sphere", "cube", "sphere"), "led_01.png")  # press_0001's LED image: cut short
    png = root / "press_0002" / "tricolor.png"
    _flip_inside(png)
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 1
    out, err = capsys.readouterr()
    logged = caplog.text + err
    (line,) = [line for line in logged.splitlines() if "tricolor.png" in line]
    assert f"{png}: damaged inside (chunk IDAT at byte " in line and "fails its CRC-32 check)" in line
    assert "libpng" not in err and not (root / "press_0002" / "nlips").exists()
    assert "1 press left out of the dataset (not sampled): press_0002" in err
    assert "1 press failed to solve: press_0001" in err and out == f"{root / 'calibration'}\n"


def test_ground_truth_damaged_inside_is_found_before_any_solve(tmp_path, capsys, caplog):
    """A twin press's gt.npz damaged inside its true normals: found by the build, after the solves; now before."""
    import zipfile

    caplog.set_level(logging.INFO)
    root = tmp_path / "presses"
    synth.make_press(root / "reference", "none", size=(64, 48))
    for i in (1, 2):
        synth.make_press(root / f"press_{i:04d}", "sphere", size=(64, 48))
    gt = root / "press_0001" / "gt.npz"
    with zipfile.ZipFile(gt) as archive:
        member = archive.getinfo("normals.npy")
        start = member.header_offset + 30 + len(member.filename) + len(member.extra)
    _flip_inside(gt, (start + member.compress_size / 2) / gt.stat().st_size)
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 1
    err = capsys.readouterr().err
    (line,) = [line for line in (caplog.text + err).splitlines() if "gt.npz" in line]
    assert f"{gt}: damaged inside (member normals.npy: " in line and "left out, not solved" in line
    assert not (root / "press_0001" / "nlips").exists()
    assert "1 press left out of the dataset (not sampled): press_0001" in err


def test_every_press_unsampled_fails_the_run(tmp_path, capsys, caplog):
    root, png = _presses(tmp_path, ("sphere",), "tricolor.png")
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"{png}: cut short (no PNG end chunk); the press is left out, not solved" in caplog.text + err
    assert f"nlips calibrate: error: {root}: every press holds a damaged file (each named above)" in err
    assert "Traceback" not in err and not (root / "press_0001" / "nlips").exists()
