"""Presses whose files are not the ones their checksums.json recorded (another whole image copied over one): refused
by `nlips solve`, `calibrate`, `calibrate-leds` and `train` in one line naming the file (exit 2), used with
--allow-edited; and `nlips verify [--record]` for folders written before the record existed."""

import json

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core.imageio import write_png16
from nlipscalib.core.press_checksums import CHECKSUMS_FILE
from tests.solver import synth

SIZE = (64, 48)


def _presses(root, kinds=("sphere", "cube")):
    synth.make_press(root / "reference", "none", size=SIZE)
    for i, kind in enumerate(kinds, 1):
        synth.make_press(root / f"press_{i:04d}", kind, size=SIZE)
    return root


def _copy_over(source, target):
    """Another whole image of the same sensor copied over ``target``: every format check passes it."""
    target.write_bytes(source.read_bytes())
    return target


@pytest.mark.parametrize("command", ["solve", "calibrate", "calibrate-leds"])
def test_a_press_with_another_image_copied_over_one_is_refused_naming_it(tmp_path, capsys, command):
    root = _presses(tmp_path / "presses")
    if command == "calibrate-leds":
        changed = _copy_over(root / "press_0001" / "led_04.png", root / "reference" / "led_04.png")
        argv = [command, str(root / "reference"), "--out", str(tmp_path / "leds.json")]
    else:
        changed = _copy_over(root / "press_0002" / "led_04.png", root / "press_0001" / "led_04.png")
        argv = [command, str(root / "press_0001") if command == "solve" else str(root), "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"error: {changed}: changed since it was written (" in err and "--allow-edited" in err
    assert not (root / "press_0001" / "nlips").exists() and not (tmp_path / "leds.json").exists()


def test_allow_edited_solves_the_press_as_it_is(tmp_path, capsys):
    root = _presses(tmp_path / "presses", ("sphere",))
    _copy_over(root / "reference" / "led_04.png", root / "press_0001" / "led_04.png")
    assert main(["solve", str(root / "press_0001"), "--roi", "auto", "--allow-edited", "--no-progress"]) == 0
    assert (root / "press_0001" / "nlips" / "result.npz").is_file()


def test_train_refuses_a_dataset_whose_press_changed_since_it_was_sampled(tmp_path, capsys):
    """index.json records each press's files as sampled; a press captured again or copied over after `nlips calibrate`
    trained without a word (the shards alone are read). --allow-edited trains on the samples as they are."""
    root = _presses(tmp_path / "presses")
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 0
    index = json.loads((root / "calibration" / "index.json").read_text(encoding="utf-8"))
    recorded = json.loads((root / "press_0002" / CHECKSUMS_FILE).read_bytes())["files"]
    assert index["presses"][1]["files"] == recorded and set(index["reference_files"]) == set(recorded)
    capsys.readouterr()
    changed = _copy_over(root / "press_0001" / "tricolor.png", root / "press_0002" / "tricolor.png")
    model = tmp_path / "m.pt"
    argv = ["train", str(root / "calibration"), "--out", str(model), "--epochs", "1", "--no-onnx", "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"error: {changed.resolve()}: changed since it was sampled (" in err
    assert "run `nlips calibrate` on its presses again" in err and "--allow-edited" in err and not model.exists()
    assert main([*argv, "--allow-edited"]) == 0 and model.is_file()


def test_train_compares_an_older_datasets_presses_with_their_own_records(tmp_path, capsys):
    """A dataset built before index.json recorded its presses' files: each press is compared with its checksums.json."""
    root = _presses(tmp_path / "presses", ("sphere",))
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 0
    path = root / "calibration" / "index.json"
    index = json.loads(path.read_text(encoding="utf-8"))
    del index["reference_files"]
    for entry in index["presses"]:
        del entry["files"]
    path.write_text(json.dumps(index), encoding="utf-8")
    capsys.readouterr()
    argv = ["train", str(root / "calibration"), "--out", str(tmp_path / "m.pt"), "--epochs", "1", "--no-onnx"]
    write_png16(root / "press_0001" / "led_02.png", np.zeros((SIZE[1], SIZE[0], 3), np.uint16))
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"{(root / 'press_0001' / 'led_02.png').resolve()}: changed since it was written (" in err
    assert "was built before datasets recorded their presses' files" in err


def test_verify_records_older_folders_once_whole_and_names_damaged_ones(tmp_path, capsys, caplog):
    root = _presses(tmp_path / "presses")
    written = {p.name: (p / CHECKSUMS_FILE).read_bytes() for p in root.iterdir()}
    for press in root.iterdir():
        (press / CHECKSUMS_FILE).unlink()
    data = bytearray((root / "press_0002" / "led_05.png").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (root / "press_0002" / "led_05.png").write_bytes(bytes(data))
    assert main(["verify", str(root), "--no-progress"]) == 1
    err = capsys.readouterr().err + caplog.text  # the damaged press's line is logged (pytest's handler takes it)
    assert f"{root / 'press_0002'}: led_05.png damaged inside (chunk " in err
    assert "2 without checksums.json" in err and not (root / "press_0001" / CHECKSUMS_FILE).exists()
    assert main(["verify", str(root), "--record", "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "3 press folders verified: 2 whole, 1 damaged" in err and "checksums.json recorded in 2" in err
    for name in ("reference", "press_0001"):
        assert json.loads((root / name / CHECKSUMS_FILE).read_bytes()) == json.loads(written[name])
    assert not (root / "press_0002" / CHECKSUMS_FILE).exists()
    # recorded: a whole image copied over one later is now refused by the readers
    _copy_over(root / "reference" / "led_01.png", root / "press_0001" / "led_01.png")
    caplog.clear()
    assert main(["verify", str(root / "press_0001")]) == 1
    assert "led_01.png changed since it was written" in capsys.readouterr().err + caplog.text
    assert main(["solve", str(root / "press_0001"), "--no-progress"]) == 2


def test_eval_refuses_a_ground_truth_copied_over_naming_it_unless_allowed(tmp_path, capsys):
    """`nlips eval` read a press's gt.npz without its checksums.json: another press's ground truth copied over it (a
    whole file of the same shape) scored the result against the wrong surface without a word (s34-leftovers). Now one
    line naming the file, exit 2; --allow-edited scores it as it is."""
    root = _presses(tmp_path / "presses")
    press = root / "press_0001"
    assert main(["solve", str(press), "--roi", "auto", "--no-progress", "--no-figures"]) == 0
    other = root / "press_0002" / "gt.npz"
    assert other.stat().st_size != (press / "gt.npz").stat().st_size  # a sphere's and a cube's surfaces
    changed = _copy_over(other, press / "gt.npz")
    capsys.readouterr()
    assert main(["eval", str(press)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        len(err) == 1 and f"error: {changed}: changed since it was written (" in err[0] and "--allow-edited" in err[0]
    )
    assert main(["eval", str(press), "--allow-edited"]) == 0
