import json
import os

import numpy as np
import pytest

from nlipscalib.core import Camera, Led, Reference, SensorResponse, capture, load_press, surface_files, write_press
from nlipscalib.core.atomic import TMP_PREFIX, atomic_dir, clean_interrupted
from nlipscalib.core.capture import GroundTruth, find_presses
from nlipscalib.core.errors import CaptureError

H, W = 12, 16


def _press(folder, n_leds=3, with_gt=True, dark_level=None):
    """A press of random images; ``dark_level``: its dark frame that value everywhere (a real dark frame, which
    the solver's check asks for), else random like the rest."""
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
    dark = img()
    if dark_level is not None:
        dark = np.full_like(dark, dark_level)
    return write_press(
        folder,
        cam,
        leds,
        SensorResponse(),
        dark,
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
    (tmp_path / "calibration" / "index.json").write_text("{}", encoding="utf-8")
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
        (lambda f: (f / "meta.json").write_text("{nope", encoding="utf-8"), "not valid JSON"),
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
        (lambda f: _spoil_deflated(f / "gt.npz", "normals.npy"), "gt.npz: array 'normals' is not readable (compressed"),
        (lambda f: (f / "tricolor.png").write_bytes(b"garbage"), "tricolor.png: not a readable PNG"),
    ],
)
@pytest.mark.parametrize("decode", [True, False, "background"])
def test_broken_folders_are_reported_precisely(tmp_path, breakage, message, capfd, decode):
    folder = _press(tmp_path / "p")
    breakage(folder)
    with pytest.raises(CaptureError, match=message.replace("(", r"\(").replace(".", r"\.")) as caught:
        _read_every_file(folder, decode)
    assert "allow_pickle" not in str(caught.value)  # numpy's advice for a pickle, not for a broken file
    assert capfd.readouterr().err == ""  # nothing printed by the decoders (libpng) besides the one error


def _read_every_file(folder, decode=True):
    """``load_press`` and a read of each field it may load at its first read (the tri-colour image, the ground
    truth, and the images of an undecoded capture)."""
    press = load_press(folder, decode=decode)
    return press.dark, press.led_images, press.tricolor, press.ground_truth


def _spoil_png(path):
    """A PNG whose signature and end are whole but whose image data is not: found only by decoding it."""
    data = bytearray(path.read_bytes())
    data[40:-40] = bytes(len(data) - 80)
    path.write_bytes(bytes(data))


def test_a_press_loads_without_reading_its_tricolor_image_nor_its_ground_truth(tmp_path):
    """A solve reads neither (~60 ms at 640x480): they are loaded at their first read, and a problem with them
    is reported then, as one line naming the file."""
    folder = _press(tmp_path / "p")
    (folder / "tricolor.png").write_bytes(b"garbage")
    (folder / "gt.npz").write_bytes(b"not npz")
    press = load_press(folder)
    assert press.led_images.shape == (3, H, W, 3) and press.reference is not None
    with pytest.raises(CaptureError, match="tricolor.png: not a readable PNG"):
        _ = press.tricolor
    with pytest.raises(CaptureError, match="gt.npz: not a readable"):
        _ = press.ground_truth
    whole = load_press(_press(tmp_path / "q"))
    assert whole.tricolor.shape == (H, W, 3) and whole.ground_truth.depth.shape == (H, W)
    assert load_press(_press(tmp_path / "r", with_gt=False)).ground_truth is None


def test_an_undecoded_capture_checks_its_images_now_and_decodes_them_at_first_read(tmp_path):
    folder = _press(tmp_path / "p")
    decoded = load_press(folder, led_subset=[0, 2])
    later = load_press(folder, led_subset=[0, 2], decode=False)
    assert isinstance(vars(later)["led_images"], capture.StoredImages)  # nothing decoded yet
    np.testing.assert_array_equal(later.led_images, decoded.led_images)
    np.testing.assert_array_equal(later.dark, decoded.dark)
    assert later.images_digest() != decoded.images_digest()  # the files' bytes, not the arrays
    assert later.images_digest() == load_press(folder, led_subset=[0, 2], decode=False).images_digest()
    assert later.images_digest() != load_press(folder, led_subset=[0, 1], decode=False).images_digest()
    _edit_meta(folder, lambda m: m["camera"].update(width=99))
    with pytest.raises(CaptureError, match=f"dark.png: image is {W}x{H} pixels, but the camera in meta.json is 99x"):
        load_press(folder, decode=False)  # the size is in the PNG's header: refused before any decoding
    _edit_meta(folder, lambda m: m["camera"].update(width=W))
    _spoil_png(folder / "led_02.png")
    spoilt = load_press(folder, decode=False)  # whole at both ends: found by decoding it
    with pytest.raises(CaptureError, match="led_02.png: damaged inside"):
        _ = spoilt.led_images


def test_a_capture_decoded_in_the_background_holds_the_images_decoded_at_once(tmp_path):
    """``decode="background"`` (``nlips solve`` reads reference.npz meanwhile): the first read waits for the
    decoding thread and gives the arrays of a load that decoded them at once; a bad PNG is raised at that read,
    naming its file."""
    folder = _press(tmp_path / "p")
    decoded = load_press(folder, led_subset=[0, 2])
    background = load_press(folder, led_subset=[0, 2], decode="background")
    np.testing.assert_array_equal(background.led_images, decoded.led_images)
    np.testing.assert_array_equal(background.dark, decoded.dark)
    np.testing.assert_array_equal(background.linear_led_images, decoded.linear_led_images)
    assert background.images_digest() == decoded.images_digest()  # the arrays', as for a press decoded at once
    _spoil_png(folder / "led_02.png")
    spoilt = load_press(folder, decode="background")
    with pytest.raises(CaptureError, match="led_02.png: damaged inside"):
        _ = spoilt.led_images
    with pytest.raises(ValueError, match="decode must be True, False or 'background'"):
        load_press(folder, decode="later")


def test_a_press_masks_its_saturated_led_samples_once_read_only(tmp_path):
    """``Press.saturated_led_images`` (read by the contact classification, the indirect fit and the solve): the
    LED images' samples at or above the white level, made once per press and read-only."""
    cam = Camera.from_fov(W, H, 90.0)
    leds = [Led(position=(float(i), 0.0, 0.0)) for i in range(2)]
    images = np.random.default_rng(1).integers(0, 65536, size=(2, H, W, 3), dtype=np.uint16)
    images[1, 2:5, 3:7] = 65535  # clipped
    dark = np.zeros((H, W, 3), np.uint16)
    press = load_press(write_press(tmp_path / "p", cam, leds, SensorResponse(), dark, images, dark))
    mask = press.saturated_led_images
    assert mask[1, 2:5, 3:7].all() and not mask.all()  # the premise: values on both sides of the white level
    np.testing.assert_array_equal(mask, images >= SensorResponse().white_level)
    assert press.saturated_led_images is mask and not mask.flags.writeable


def test_unusable_samples_join_the_saturated_ones_in_a_copy_of_the_press(tmp_path):
    """``with_unusable_samples`` (an LED image's rows read while its LED was off, left out of the solve for that LED:
    s30-darkcols): the copy's ``saturated_led_images`` are the press's and the given samples, on every channel,
    read-only; the press itself and its images are unchanged."""
    cam = Camera.from_fov(W, H, 90.0)
    leds = [Led(position=(float(i), 0.0, 0.0)) for i in range(2)]
    images = np.random.default_rng(2).integers(0, 60000, size=(2, H, W, 3), dtype=np.uint16)
    images[0, 0, 0] = 65535  # clipped
    dark = np.zeros((H, W, 3), np.uint16)
    press = load_press(write_press(tmp_path / "p", cam, leds, SensorResponse(), dark, images, dark))
    unusable = np.zeros((2, H, W), bool)
    unusable[1, 3:6] = True
    masked = capture.with_unusable_samples(press, unusable)
    expected = press.saturated_led_images | unusable[..., None]
    np.testing.assert_array_equal(masked.saturated_led_images, expected)
    assert masked.saturated_led_images[0, 0, 0].all() and not masked.saturated_led_images.flags.writeable
    assert not press.saturated_led_images[1, 3:6].any() and masked.led_images is press.led_images
    # what is computed from the samples is kept apart: the copy carries their digest, a loaded press none
    assert capture.unusable_digest(press) is None and capture.unusable_digest(masked) is not None
    other = np.zeros_like(unusable)
    assert capture.unusable_digest(capture.with_unusable_samples(press, other)) != capture.unusable_digest(masked)


def test_a_file_replaced_after_the_press_was_loaded_is_not_read_into_it(tmp_path):
    """The tri-colour image and the ground truth are read at first use: one replaced since the load (the folder
    rendered again) would mix two presses in one object, so the read is refused, naming the file."""
    import shutil

    folder, other = _press(tmp_path / "p"), _press(tmp_path / "q")
    press = load_press(folder)
    for name in ("tricolor.png", "gt.npz"):
        shutil.copyfile(other / name, folder / name)
    with pytest.raises(CaptureError, match="tricolor.png: changed since the press was loaded"):
        _ = press.tricolor
    with pytest.raises(CaptureError, match="gt.npz: changed since the press was loaded"):
        _ = press.ground_truth
    again = load_press(folder)
    assert again.tricolor.shape == (H, W, 3) and again.ground_truth is not None


def test_a_press_not_yet_decoded_or_read_can_be_sent_to_another_process(tmp_path):
    """Pickled (a worker's argument) before its images are decoded or its tri-colour image read: the other
    process decodes and reads them, the same arrays."""
    import pickle

    folder = _press(tmp_path / "p")
    for press in (load_press(folder, decode=False), load_press(folder)):
        copy = pickle.loads(pickle.dumps(press))
        np.testing.assert_array_equal(copy.led_images, press.led_images)
        np.testing.assert_array_equal(copy.tricolor, press.tricolor)
        assert copy.images_digest() == press.images_digest()


def _spoil_deflated(path, member):
    from tests.core.test_reconstruction import _spoil_deflated_member

    _spoil_deflated_member(path, member)  # a flipped block inside an array: zlib fails, not the zip layer


def test_a_ground_truth_inflates_each_array_at_its_first_read_only(tmp_path, monkeypatch):
    """gt.npz's arrays are inflated at their first read, each once (its shapes and types checked on opening it,
    from their headers): an error map reads 3 of the 5 and a score 4 (at 640x480 the points are 3.3 of its
    7.6 MB deflated); loading a press's truth reads the 3 its surface check needs."""
    from nlipscalib.core import surface_files

    folder = _press(tmp_path / "p")
    read, real = [], surface_files.read_arrays
    monkeypatch.setattr(surface_files, "read_arrays", lambda *a, **k: read.extend(k["only"]) or real(*a, **k))
    gt = GroundTruth.load(folder / "gt.npz", (H, W))
    assert read == []
    with np.load(folder / "gt.npz") as stored:
        assert np.array_equal(gt.normals, stored["normals"]) and gt.normals is gt.normals
        assert read == ["normals"]
        press_truth = load_press(folder).ground_truth
        assert sorted(read) == ["depth", "normals", "normals", "valid"]  # the surface check's
        assert np.array_equal(press_truth.contact, stored["contact"])
    assert "points" not in read and read.count("contact") == 1


def test_a_ground_truth_array_of_another_shape_or_type_is_refused_on_opening(tmp_path):
    folder = _press(tmp_path / "p")
    with np.load(folder / "gt.npz") as stored:
        arrays = dict(stored)
    np.savez(folder / "gt.npz", **{**arrays, "points": arrays["points"][:, :, :2]})
    with pytest.raises(CaptureError, match=r"gt\.npz: ground truth 'points' has shape \(12, 16, 2\), expected"):
        GroundTruth.load(folder / "gt.npz", (H, W))
    np.savez(folder / "gt.npz", **{**arrays, "contact": arrays["contact"].astype("U1")})
    with pytest.raises(CaptureError, match=r"gt\.npz: array 'contact' holds <U1 values, expected numbers"):
        GroundTruth.load(folder / "gt.npz", (H, W))


def test_a_damaged_ground_truth_array_is_named_at_its_first_read(tmp_path):
    """A byte of an array's values damaged (found by the zip CRC when the array is inflated) is one error naming
    the file and the array, at the first read of that array; the other arrays still read."""
    import zipfile

    h, w = 64, 80  # a member longer than the zip reader's first read (4 kB): its header reads without its end
    arrays = {"depth": np.full((h, w), 10.0, np.float32), "points": np.zeros((h, w, 3), np.float32)}
    arrays |= {"normals": np.tile(np.float32([0, 0, -1]), (h, w, 1)), "valid": np.ones((h, w), bool)}
    arrays["contact"] = np.zeros((h, w), bool)
    path = tmp_path / "gt.npz"
    np.savez(path, **arrays)  # stored, not deflated: the flipped byte is past the array's header
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo("contact.npy")
    data = bytearray(path.read_bytes())
    data[info.header_offset + 30 + len(info.filename) + len(info.extra) + info.compress_size - 1] ^= 1
    path.write_bytes(bytes(data))
    truth = GroundTruth.load(path, (h, w))
    assert np.array_equal(truth.normals, arrays["normals"])
    with pytest.raises(CaptureError, match=r"gt\.npz: array 'contact' is not readable \(Bad CRC-32"):
        _ = truth.contact
    arrays["normals"][0, 0] = np.nan
    np.savez(path, **arrays)
    with pytest.raises(CaptureError, match=r"gt\.npz: array 'normals' contains NaN or infinity"):
        _ = GroundTruth.load(path, (h, w)).normals


def test_a_reference_is_read_once_per_file_and_again_when_it_changes(tmp_path, monkeypatch):
    """``nlips solve --reference`` decompressed each reference.npz twice (the settings check's ``read_optics``,
    then ``load_press``; ~30 ms each at 640x480): once per process now, shared read-only, and read again when
    the file is rewritten in place."""
    from nlipscalib.core.capture import read_optics

    folder = _press(tmp_path / "p")
    loads, load = [], Reference.load
    monkeypatch.setattr(Reference, "load", lambda path, shape: loads.append(path) or load(path, shape))
    first = read_optics(folder).reference
    assert load_press(folder).reference is first and load_press(folder, led_subset=[1]).reference is first
    assert len(loads) == 1
    assert not first.depth.flags.writeable and not first.normals.flags.writeable  # shared: nobody writes into it
    with pytest.raises(ValueError, match="read-only"):
        first.depth[0, 0] = 1.0
    with np.load(folder / "reference.npz") as d:
        depth, normals = d["depth"], d["normals"]
    np.savez(folder / "reference.npz", depth=depth + 1, normals=normals)  # in place, stored: another size
    again = load_press(folder).reference
    assert len(loads) == 2 and np.array_equal(again.depth, depth + 1)


def test_a_reference_of_bytes_read_before_is_mapped_from_the_disk_tier_not_inflated(tmp_path, monkeypatch):
    """A sensor's presses carry the same reference.npz bytes: a later process (nothing kept in memory) reading those
    bytes in another press folder gets the arrays from the disk tier, the same arrays bit for bit, without
    inflating the file; other bytes are read and inflated again."""
    import shutil

    from nlipscalib.core import diskcache

    monkeypatch.setenv("NLIPS_CACHE_DIR", str(tmp_path / "cache"))
    a = _press(tmp_path / "a")
    b = tmp_path / "b"
    shutil.copytree(a, b)
    inflated, inflate = [], surface_files._load_npz
    monkeypatch.setattr(surface_files, "_load_npz", lambda path, keys: inflated.append(path) or inflate(path, keys))
    first = load_press(a).reference
    diskcache.wait()  # the entry's background write
    surface_files._checked_reference.cache_clear()  # as a new process: nothing kept in memory
    second = load_press(b).reference
    assert inflated == [a / "reference.npz"]
    for x, y in [(first.depth, second.depth), (first.normals, second.normals)]:
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()
    assert not second.depth.flags.writeable and not second.normals.flags.writeable
    with np.load(b / "reference.npz") as d:
        depth, normals = d["depth"], d["normals"]
    np.savez(b / "reference.npz", depth=depth + 1, normals=normals)
    surface_files._checked_reference.cache_clear()
    assert np.array_equal(load_press(b).reference.depth, depth + 1) and inflated[-1] == b / "reference.npz"
    assert len(inflated) == 2


def test_nan_in_reference_normals_is_rejected(tmp_path):
    folder = _press(tmp_path / "p")
    with np.load(folder / "reference.npz") as d:
        depth, normals = d["depth"], d["normals"].copy()
    normals[0, 0, 0] = np.nan
    np.savez(folder / "reference.npz", depth=depth, normals=normals)
    with pytest.raises(CaptureError, match="NaN"):
        load_press(folder)


def test_bad_led_subset(tmp_path):
    """The argument named as the caller wrote it (``led_subset=``), the LED counted from 1 as a user reads it."""
    folder = _press(tmp_path / "p")
    with pytest.raises(CaptureError) as raised:
        load_press(folder, led_subset=[0, 5])
    assert str(raised.value).startswith(f"{folder}: led_subset=[0, 5] (0-based; LEDs [1, 6] counting from 1)")
    assert str(raised.value).endswith("is invalid for its 3 LEDs: LED 6 out of range 1..3")
    with pytest.raises(CaptureError, match=r"led_subset=\[2, 2\] .*: LED 3 named twice$"):
        load_press(folder, led_subset=[2, 2])


def _edit_meta(folder, change):
    meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
    change(meta)
    (folder / "meta.json").write_text(json.dumps(meta), encoding="utf-8")


@pytest.mark.parametrize(
    "change,message",
    [
        (lambda m: m["images"].update(dark=5), "'images.dark' must be a file name, got 5"),
        (lambda m: m["images"].update(dark=None), "'images.dark' must be a file name, got None"),
        (lambda m: m["images"]["leds"].__setitem__(2, 12), r"'images.leds\[2\]' must be a file name, got 12"),
        (lambda m: m["images"].update(leds=5), "'images.leds' must be a list of file names, got 5"),
        (lambda m: m.update(images="x"), "'images' must be a mapping of image names"),
        (lambda m: m.update(reference=5), "'reference' must be a file name, got 5"),
        (lambda m: m.update(ground_truth=[1]), r"'ground_truth' must be a file name, got \[1\]"),
    ],
)
def test_a_file_name_that_is_no_string_is_named_by_every_reader(tmp_path, change, message):
    """A non-string image name in meta.json was a TypeError traceback: the capture's identity (hashed before the
    press is loaded, by solve, infer, calibrate-leds and calibrate) joined it to the folder unchecked."""
    from nlipscalib.core.capture import read_meta
    from nlipscalib.pipeline import capture_identity

    folder = _press(tmp_path / "p")
    _edit_meta(folder, change)
    for reader in (read_meta, load_press, capture_identity):
        with pytest.raises(CaptureError, match="meta.json: " + message):
            reader(folder)


@pytest.mark.parametrize(
    "change,message",
    [
        (lambda m: m["camera"].update(width="abc"), "camera.width must be a whole number of pixels, got 'abc'"),
        (lambda m: m["camera"].update(height=48.0), "camera.height must be a whole number of pixels, got 48.0"),
        (lambda m: m["camera"].update(fx="88"), "camera.fx must be a finite number of pixels, got '88'"),
        (lambda m: m["camera"].update(cx=None), "camera.cx must be a finite number of pixels, got None"),
        (lambda m: m["camera"].update(dist=5), "camera.dist must be a list of numbers, got 5"),
        (lambda m: m["sensor"].update(bit_depth="twelve"), "sensor.bit_depth must be a whole number of bits"),
        (lambda m: m["sensor"].update(white_level="max"), "sensor.white_level must be a finite number, got 'max'"),
        (lambda m: m["sensor"].update(exposure_ms=0), "sensor.exposure_ms must be > 0 and sensor.gain >= 0"),
        (lambda m: m["sensor"].update(exposure_ms=-5), "sensor.exposure_ms must be > 0"),
        (lambda m: m["sensor"].update(gain=-1), r"sensor.exposure_ms must be > 0 and sensor.gain >= 0, got 10.0, -1"),
        (lambda m: m.update(sensor="x"), "'sensor' must be a mapping of sensor levels, got 'x'"),
        # Camera.from_dict took any value as a mapping: "'int' object is not iterable", and a string's letters
        # as unknown keys ("camera has unknown keys ['e', 'f', 'h', ...]")
        (lambda m: m.update(camera=640), "'camera' must be a mapping of intrinsics .*, got 640"),
        (lambda m: m.update(camera="fisheye"), "'camera' must be a mapping of intrinsics .*, got 'fisheye'"),
        (lambda m: m["leds"][1].update(mu="one"), r"leds\[1\]: led.mu must be a number, got 'one'"),
        (lambda m: m["leds"][0].update(position=["a", 1, 2]), r"leds\[0\]: led.position must be 3 finite numbers"),
    ],
)
def test_a_value_of_the_wrong_type_names_its_key(tmp_path, change, message):
    """These were Python's own errors ("'<' not supported between instances of 'str' and 'int'", "ufunc
    'isfinite' not supported ...", "SensorResponse() argument after ** must be a mapping"), naming no key;
    a zero or negative exposure and a negative gain were accepted."""
    folder = _press(tmp_path / "p")
    _edit_meta(folder, change)
    with pytest.raises(CaptureError, match="meta.json: " + message):
        load_press(folder)


def test_a_reference_array_of_strings_is_named(tmp_path):
    """numpy's "ufunc 'isfinite' not supported for the input types" came out of the solver instead."""
    folder = _press(tmp_path / "p")
    with np.load(folder / "reference.npz") as d:
        depth, normals = d["depth"], d["normals"]
    np.savez(folder / "reference.npz", depth=depth.astype("U8"), normals=normals)
    with pytest.raises(CaptureError, match=r"reference.npz: array 'depth' holds <U8 values, expected numbers"):
        load_press(folder)


def test_a_file_or_a_press_without_meta_json_is_called_what_it_is(tmp_path):
    """A file given as a press said "not a press folder (no such directory)"; a press folder without its meta.json
    (a single press given) said "no press folders found"."""
    from nlipscalib.core.capture import no_presses_error, read_meta

    (tmp_path / "f.txt").write_text("x", encoding="utf-8")
    with pytest.raises(CaptureError, match="f.txt: a file, not a press folder"):
        read_meta(tmp_path / "f.txt")
    with pytest.raises(CaptureError, match="f.txt: a file, not a press folder nor a folder of presses"):
        find_presses(tmp_path / "f.txt")
    folder = _press(tmp_path / "p")
    (folder / "meta.json").unlink()
    assert find_presses(folder) == []
    assert "holds press images but no meta.json" in str(no_presses_error(folder))
    (tmp_path / "empty").mkdir()
    assert str(no_presses_error(tmp_path / "empty")).endswith("empty: no press folders found")


def _edit_surface(folder, name, change):
    with np.load(folder / name) as d:
        arrays = {k: d[k].copy() for k in d.files}
    change(arrays)
    np.savez(folder / name, **arrays)


@pytest.mark.parametrize(
    "change,message",
    [
        (lambda m: m.update(units="m"), "meta.json: 'units' is 'm'; captures are in millimetres"),
        (lambda m: m.update(frame="dome"), "meta.json: 'frame' is 'dome'; captures are in the camera frame"),
    ],
)
def test_units_or_frame_other_than_the_formats_are_refused(tmp_path, change, message):
    """The audit's press with `units: "m"` loaded, and solved to a wrong result without a word."""
    from nlipscalib.core.capture import read_optics

    folder = _press(tmp_path / "p")
    _edit_meta(folder, change)
    for reader in (load_press, read_optics):
        with pytest.raises(CaptureError, match=message):
            reader(folder)


@pytest.mark.parametrize(
    "name,change,message",
    [
        ("reference.npz", lambda a: a.update(normals=-a["normals"]), "'normals' points away from the camera on 100 %"),
        ("reference.npz", lambda a: a.update(normals=2 * a["normals"]), "'normals' is not a unit vector on 192 of"),
        ("reference.npz", lambda a: a.update(depth=a["depth"] / 1000), "'depth' puts the gel 0.0.* mm from the camera"),
        ("gt.npz", lambda a: a.update(normals=-a["normals"]), "'normals' points away from the camera"),
        ("gt.npz", lambda a: a.update(depth=a["depth"] * 1000), "'depth' puts the gel 1.*e\\+04 mm from the camera"),
    ],
)
def test_surfaces_that_break_the_formats_promise_are_named(tmp_path, name, change, message):
    """Depth in metres, flipped or unnormalised normals had the right shapes and loaded: a solve of such a press
    gave 2.68 deg / 9.9 mm instead of 0.40 deg / 0.026 mm, and said nothing."""
    folder = _press(tmp_path / "p")
    _edit_surface(folder, name, change)
    with pytest.raises(CaptureError, match=f"{name}: array {message}"):
        _read_every_file(folder)


def test_a_gel_that_misses_the_sampling_grid_is_checked_on_all_its_pixels():
    """A gel of a few pixels off the every-8th-pixel grid was refused: "puts the gel nan mm from the camera"."""
    from nlipscalib.core.surface_checks import surface_problem

    cam = Camera.from_fov(W, H, 90.0)
    leds = [Led(position=(5.0, 0.0, 0.0))]
    depth = np.full((H, W), 10.0, np.float32)
    normals = np.tile(np.float32([0, 0, -1]), (H, W, 1))
    valid = np.zeros((H, W), bool)
    valid[5:7, 9:11] = True  # 4 pixels, none on rows/columns 0, 8
    assert surface_problem(depth, normals, valid, cam, leds) is None
    assert "points away" in surface_problem(depth, -normals, valid, cam, leds)
    assert surface_problem(np.full((H, W), np.nan, np.float32), normals, valid, cam, leds) is None


def test_one_conversion_of_stored_values_to_light_and_one_white_level_per_bit_depth():
    """Press.linear, NLiPsNet's frames and the capture's exposure check each had their own copy of
    (image - dark) / (white - black), and infer hard-coded an 8-bit frame's white level (0xFF00)."""
    from nlipscalib.core.capture import CLIPPED_VALUE, linearise, white_level_of

    assert white_level_of(8) == CLIPPED_VALUE == 255 << 8 and white_level_of(12) == SensorResponse().white_level
    assert white_level_of(16) == 65535
    rng = np.random.default_rng(0)
    dark = rng.integers(200, 300, (4, 5, 3)).astype(np.uint16)
    images = rng.integers(300, 65535, (2, 4, 5, 3)).astype(np.uint16)
    response = SensorResponse(black_level=256.0, white_level=65520.0)
    lin = linearise(images, dark, response.black_level, response.white_level)
    assert lin.dtype == np.float32
    np.testing.assert_array_equal(lin, (images.astype(np.float32) - dark) / np.float32(65520.0 - 256.0))
    np.testing.assert_array_equal(response.saturated(images), images >= 65520.0)


def test_the_linear_led_images_made_per_led_are_the_whole_stacks_linearisation(tmp_path):
    """``Press.linear_led_images`` converts one LED per thread: the same bits as ``linearise`` of the whole stack,
    read-only."""
    from nlipscalib.core.capture import linearise

    press = load_press(_press(tmp_path / "p"))
    lin = press.linear_led_images
    whole = linearise(press.led_images, press.dark, press.response.black_level, press.response.white_level)
    assert lin.dtype == np.float32 and not lin.flags.writeable and np.ptp(lin) > 0
    assert lin.tobytes() == whole.tobytes()


def test_linearise_rejects_an_image_that_does_not_end_with_the_dark_frames_shape():
    """A (1, W, 3) dark frame (or a (H, W, 1) image) broadcast silently, and a transposed frame raised numpy's
    "operands could not be broadcast"; a scalar level against the gel's dark values stays allowed (infer)."""
    from nlipscalib.core.capture import linearise
    from nlipscalib.core.errors import ShapeError

    dark = np.full((4, 5, 3), 256, np.uint16)
    assert linearise(np.full((2, 4, 5, 3), 512, np.uint16), dark, 256.0, 512.0).shape == (2, 4, 5, 3)
    assert linearise(np.float32(512.0), dark[0], 256.0, 512.0).shape == (5, 3)
    for image, dark_ in ((np.zeros((4, 5, 3)), dark[:1]), (np.zeros((4, 5, 1)), dark), (np.zeros((5, 4, 3)), dark)):
        with pytest.raises(ShapeError, match="must end with the dark frame's shape"):
            linearise(image, dark_, 256.0, 512.0)


# the public names core/capture.py defined before it was split into one file per job (session 24)
FORMAT_NAMES = """CLIPPED_VALUE CaptureOptics FORMAT_NAME FORMAT_VERSION FileLoader GT_FILE GT_KEYS GroundTruth
LEAST_BIT_DEPTH Loader META_FILE Press REFERENCE_FILE REFERENCE_FOLDER Reference SensorResponse StoredImages
decode_in_background decode_together file_stamp find_presses is_incomplete_press is_press_folder led_frame_name
led_image_name linearise listed_files load_press missing_capture_files no_presses_error parse_optics prefetch_press
read_meta read_optics split_reference white_level_of write_press""".split()


def test_every_public_name_of_the_format_is_still_importable_from_core_capture():
    """core.capture is the format's module (docs/api.md, docs/formats.md): each name it held before the split is
    there still, the very object its new home defines, and listed in ``__all__``."""
    import importlib

    missing = [name for name in FORMAT_NAMES if name not in capture.__all__ or not hasattr(capture, name)]
    assert not missing, missing
    for name in FORMAT_NAMES:
        obj = getattr(capture, name)
        home = getattr(obj, "__module__", None)
        if home is not None and home.startswith("nlipscalib.core."):  # a class or function: the same object
            assert getattr(importlib.import_module(home), name) is obj, name


def test_as_press_takes_a_press_or_its_folders_path_and_nothing_else(tmp_path):
    from pathlib import Path

    from nlipscalib.core.capture import as_press
    from nlipscalib.core.errors import ShapeError

    folder = _press(tmp_path / "p")
    press = load_press(folder)
    assert as_press(press) is press
    for given in (str(folder), Path(folder)):
        loaded = as_press(given)
        assert loaded.folder == Path(folder)
        np.testing.assert_array_equal(loaded.led_images, press.led_images)
    with pytest.raises(ShapeError, match="reference must be a Press .* got int"):
        as_press(3, "reference")
    with pytest.raises(CaptureError, match="not a press folder"):
        as_press(tmp_path / "nowhere")


def test_led_gains_rescale_each_led_image_above_the_dark_frame_and_keep_saturated_samples(tmp_path):
    """``capture.with_led_gains`` (a solve's images of LEDs aged on their own, brought to the undeformed capture's
    brightness): LED k's linear image divided by its gain per channel, to the stored values' rounding; a saturated
    sample stays saturated (it was clipped: its light is unknown); a new digest, so no result of the images as
    captured is reused for them; the other fields the press's own."""
    cam = Camera.from_fov(W, H, 90.0)
    leds = [Led(position=(float(i), 0.0, 0.0)) for i in range(3)]
    images = np.random.default_rng(2).integers(4000, 65536, size=(3, H, W, 3), dtype=np.uint16)
    images[0, 0, 0] = 65535  # clipped
    dark = np.full((H, W, 3), 4000, np.uint16)
    press = load_press(write_press(tmp_path / "p", cam, leds, SensorResponse(), dark, images, dark))
    gains = np.array([[0.8, 0.9, 1.0], [1.0, 1.0, 1.0], [1.25, 1.25, 1.25]])
    scaled = capture.with_led_gains(press, gains)
    lin, before = scaled.linear_led_images, press.linear_led_images
    expected = before / gains[:, None, None, :]
    white = SensorResponse().white_level
    keep = (4000 + (images - 4000.0) / gains[:, None, None, :] < white - 1) & ~press.saturated_led_images
    assert np.abs(lin - expected)[keep].max() < 1.0 / white  # half a stored value (rounding) and float32 arithmetic
    assert keep.mean() > 0.5 and (scaled.saturated_led_images | keep).all()  # the rest saturated: left out
    assert scaled.saturated_led_images[0, 0, 0].all()
    assert scaled.leds is press.leds and scaled.reference is press.reference
    assert scaled.images_digest() != press.images_digest()


def test_an_led_subset_of_anything_but_led_indices_is_one_clear_error(tmp_path):
    """`load_press(folder, led_subset="0,2")` failed on "invalid literal for int() with base 10: ','", and
    `led_subset=[1.5]` loaded LED 2 (index 1) without a word."""
    from nlipscalib.core.errors import ShapeError

    folder = _press(tmp_path / "p1")
    for subset, got in (("0,2", "str '0,2'"), ([1.5], "list [1.5]"), ([True, 2], "list [True, 2]"), (3, "int 3")):
        # named as the API's other kind checks name their argument (core.errors.check_kind), before any file is read
        said = f"led_subset must be a sequence of LED indices (0-based integers), got {got}"
        for where in (folder, tmp_path / "no such press"):
            with pytest.raises(ShapeError) as raised:
                load_press(where, led_subset=subset)
            assert str(raised.value) == said
    assert len(load_press(folder, led_subset=np.array([0, 2])).leds) == 2  # NumPy's integers are indices too


def test_load_press_of_another_kind_names_the_argument():
    """load_press(3) failed with Python's own TypeError from inside pathlib."""
    from nlipscalib.core.errors import ShapeError

    with pytest.raises(ShapeError, match=r"folder must be a press folder's path \(str or Path\), got int 3"):
        load_press(3)
