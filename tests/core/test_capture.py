import json
import os

import numpy as np
import pytest

from nlipscalib.core import Camera, Led, Reference, SensorResponse, load_press, write_press
from nlipscalib.core.atomic import TMP_PREFIX, atomic_dir, clean_interrupted
from nlipscalib.core.capture import GroundTruth, find_presses
from nlipscalib.errors import CaptureError

H, W = 12, 16


def _press(folder, n_leds=3, with_gt=True):
    cam = Camera.from_fov(W, H, 90.0)
    leds = [Led(position=(float(i), 0.0, 0.0)) for i in range(n_leds)]
    rng = np.random.default_rng(0)
    img = lambda: rng.integers(0, 60000, size=(H, W, 3), dtype=np.uint16)  # noqa: E731
    gt = None
    if with_gt:
        depth = np.full((H, W), 10.0, np.float32)
        pts = (cam.rays * 10.0).astype(np.float32)
        n = np.zeros((H, W, 3), np.float32)
        n[..., 2] = -1
        gt = GroundTruth(depth, pts, n, np.ones((H, W), bool), np.zeros((H, W), bool))
    ref = Reference(np.full((H, W), 10.0, np.float32), np.tile(np.float32([0, 0, -1]), (H, W, 1)))
    return write_press(
        folder,
        cam,
        leds,
        SensorResponse(),
        img(),
        np.stack([img() for _ in leds]),
        img(),
        provenance={"source": "test"},
        reference=ref,
        ground_truth=gt,
    )


def test_round_trip_keeps_everything(tmp_path):
    folder = _press(tmp_path / "p1")
    p = load_press(folder)
    assert p.led_images.shape == (3, H, W, 3) and p.led_images.dtype == np.uint16
    assert p.camera.shape == (H, W)
    assert p.leds[2].position == (2.0, 0.0, 0.0)
    assert p.meta["provenance"]["source"] == "test"
    assert p.ground_truth.depth.shape == (H, W) and p.reference.normals.shape == (H, W, 3)
    lin = p.linear(p.led_images)
    assert lin.dtype == np.float32 and lin.shape == p.led_images.shape
    sub = load_press(folder, led_subset=[0, 2])
    np.testing.assert_array_equal(sub.led_images[1], p.led_images[2])
    assert find_presses(tmp_path) == [folder]


def test_find_presses_warns_about_incomplete_press_folders(tmp_path, caplog):
    import logging
    import shutil

    caplog.set_level(logging.WARNING)
    good = _press(tmp_path / "p1")
    broken = tmp_path / "p2"
    shutil.copytree(good, broken)
    (broken / "meta.json").unlink()  # an interrupted copy
    (tmp_path / "calibration").mkdir()  # other output beside the presses: not a press, no warning
    (tmp_path / "calibration" / "index.json").write_text("{}")
    shutil.copytree(good, tmp_path / (TMP_PREFIX + "p3~host~1~x"))  # a write in progress: ignored
    assert find_presses(tmp_path) == [good]
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and str(broken) in warnings[0] and "meta.json" in warnings[0], warnings


def test_a_folders_own_reference_is_never_a_press_whichever_reference_is_named(tmp_path):
    """``split_reference(DS, OTHER)`` returned DS/reference among the presses: ``nlips calibrate DS --reference
    OTHER`` solved the undeformed dome as if it were a press."""
    from nlipscalib.core.capture import split_reference

    ds = tmp_path / "ds"
    own, press, other = _press(ds / "reference"), _press(ds / "press_a"), _press(tmp_path / "other")
    assert split_reference(ds) == ([press], own)
    assert split_reference(ds, other) == ([press], other)
    assert split_reference(ds, own) == ([press], own)
    assert split_reference(ds, press) == ([], press)  # a press named as the reference: the user's choice
    assert split_reference(own, other) == ([own], other)  # a press folder given as such is still a press


def test_written_files_get_ordinary_permissions(tmp_path):
    import os
    import stat

    from nlipscalib.core.atomic import DIR_MODE, FILE_MODE

    folder = _press(tmp_path / "p1")
    assert stat.S_IMODE(os.stat(folder).st_mode) == DIR_MODE
    assert stat.S_IMODE(os.stat(folder / "meta.json").st_mode) == FILE_MODE
    assert FILE_MODE & stat.S_IRUSR and DIR_MODE & stat.S_IXUSR


def test_write_refuses_to_clobber_and_leaves_no_temp(tmp_path):
    _press(tmp_path / "p1")
    with pytest.raises(FileExistsError):
        _press(tmp_path / "p1")
    assert not list(tmp_path.glob(TMP_PREFIX + "*"))


def test_interrupted_folder_write_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError):
        with atomic_dir(tmp_path / "p") as tmp:
            (tmp / "half.png").write_bytes(b"x")
            raise RuntimeError("power cut")
    assert list(tmp_path.iterdir()) == []
    (tmp_path / (TMP_PREFIX + "stale")).mkdir()
    os.utime(tmp_path / (TMP_PREFIX + "stale"), (0, 0))  # owner unknown: cleaned once old (core/test_atomic.py)
    assert len(clean_interrupted(tmp_path)) == 1


@pytest.mark.parametrize(
    "breakage,message",
    [
        (lambda f: (f / "led_02.png").unlink(), "led_02.png: listed in meta.json but missing"),
        (lambda f: (f / "meta.json").write_text("{nope"), "not valid JSON"),
        (lambda f: (f / "meta.json").unlink(), "meta.json: missing"),
        (lambda f: (f / "dark.png").write_bytes(b"garbage"), "dark.png: not a readable PNG"),
        (lambda f: _edit_meta(f, lambda m: m["camera"].update(width=99)), "dark.png: image is"),
        (lambda f: _edit_meta(f, lambda m: m["leds"].pop()), "3 LED images listed"),
        (lambda f: _edit_meta(f, lambda m: m.update(format_version=7)), "format_version 7"),
        (lambda f: _edit_meta(f, lambda m: m["leds"][0].update(mu=-1)), "mu"),
        (lambda f: _edit_meta(f, lambda m: m["sensor"].update(black_level=70000)), "black_level"),
        (lambda f: (f / "gt.npz").write_bytes(b"not npz"), "gt.npz: not a readable"),
        (lambda f: (f / "led_03.png").write_bytes((f / "led_03.png").read_bytes()[:-200]), "led_03.png: truncated PNG"),
        (lambda f: (f / "reference.npz").write_bytes(b"garbage"), "reference.npz: not a readable"),
        (lambda f: _spoil_deflated(f / "gt.npz", "normals.npy"), "gt.npz: not a readable .npz file (compressed"),
    ],
)
def test_broken_folders_are_reported_precisely(tmp_path, breakage, message, capfd):
    folder = _press(tmp_path / "p")
    breakage(folder)
    with pytest.raises(CaptureError, match=message.replace("(", r"\(").replace(".", r"\.")) as caught:
        load_press(folder)
    assert "allow_pickle" not in str(caught.value)  # numpy's advice for a pickle, not for a broken file
    assert capfd.readouterr().err == ""  # nothing printed by the decoders (libpng) besides the one error


def _spoil_deflated(path, member):
    from tests.core.test_reconstruction import _spoil_deflated_member

    _spoil_deflated_member(path, member)  # a flipped block inside an array: zlib fails, not the zip layer


def test_nan_in_reference_normals_is_rejected(tmp_path):
    folder = _press(tmp_path / "p")
    with np.load(folder / "reference.npz") as d:
        depth, normals = d["depth"], d["normals"].copy()
    normals[0, 0, 0] = np.nan
    np.savez(folder / "reference.npz", depth=depth, normals=normals)
    with pytest.raises(CaptureError, match="NaN"):
        load_press(folder)


def test_bad_led_subset(tmp_path):
    folder = _press(tmp_path / "p")
    with pytest.raises(CaptureError, match="subset"):
        load_press(folder, led_subset=[0, 5])


def _edit_meta(folder, change):
    meta = json.loads((folder / "meta.json").read_text())
    change(meta)
    (folder / "meta.json").write_text(json.dumps(meta))
