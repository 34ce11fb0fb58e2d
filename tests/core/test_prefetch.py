"""Images decoded ahead of a press's load (``nlips solve`` decodes them beside the solver's import)."""

import argparse
import shutil

import numpy as np
import pytest

from nlipscalib.core import load_press, prefetch, stored_images
from nlipscalib.core.errors import CaptureError

from .test_capture import _press, _spoil_png


def _prefetched(folder):
    """Prefetch the press's images and wait for the thread; returns the files prefetched."""
    names = ["dark.png"] + [f"led_{i:02d}.png" for i in (1, 2, 3)]
    prefetch.prefetch_images([folder / name for name in names]).join()
    return names


def _no_decoding(monkeypatch):
    """Make the load's own decoding fail: what it returns then was taken from the prefetch."""

    def refuse(data, path, out=None):
        raise AssertionError(f"{path} decoded again")

    monkeypatch.setattr(stored_images, "decode_png16", refuse)


@pytest.mark.parametrize("decode", [True, "background"])
def test_a_load_takes_the_images_decoded_ahead_the_same_arrays(tmp_path, monkeypatch, decode):
    folder = _press(tmp_path / "p")
    at_once = load_press(folder)
    _prefetched(folder)
    _no_decoding(monkeypatch)
    press = load_press(folder, decode=decode)
    np.testing.assert_array_equal(press.led_images, at_once.led_images)
    np.testing.assert_array_equal(press.dark, at_once.dark)
    with pytest.raises(AssertionError, match="decoded again"):  # each is taken once: a later load decodes its own
        _ = load_press(folder, decode=decode).led_images


def test_a_file_replaced_after_its_prefetch_is_decoded_from_what_the_load_read(tmp_path, monkeypatch):
    folder, other = _press(tmp_path / "p"), _press(tmp_path / "q", n_leds=4)
    _prefetched(folder)
    shutil.copyfile(other / "led_02.png", folder / "led_02.png")  # same size, other bytes
    press = load_press(folder)
    np.testing.assert_array_equal(press.led_images[1], load_press(other).led_images[1])
    np.testing.assert_array_equal(press.led_images[0], load_press(folder).led_images[0])


def test_a_broken_image_is_reported_by_the_load_not_by_the_prefetch(tmp_path):
    folder = _press(tmp_path / "p")
    _spoil_png(folder / "led_02.png")
    _prefetched(folder)  # nothing raised on its thread
    with pytest.raises(CaptureError, match="led_02.png: damaged inside"):
        load_press(folder)


def test_a_stopped_prefetch_finishes_its_image_and_leaves_the_rest_to_the_load(tmp_path, monkeypatch):
    """A load that begins stops the prefetch (:func:`prefetch.stop`): the image being decoded is finished and
    taken, the others are decoded by the load, and a take never waits for an image that will not come."""
    import threading

    folder = _press(tmp_path / "p")
    decoding, release = threading.Event(), threading.Event()
    decode = prefetch.decode_png16

    def slow(data, path, out=None):
        decoding.set()
        release.wait()
        return decode(data, path, out=out)

    monkeypatch.setattr(prefetch, "decode_png16", slow)
    thread = prefetch.prefetch_images([folder / "dark.png", folder / "led_01.png"])
    decoding.wait()
    prefetch.stop()
    release.set()
    thread.join()
    read = {name: np.fromfile(folder / name, np.uint8) for name in ("dark.png", "led_01.png")}
    np.testing.assert_array_equal(prefetch.take(folder / "dark.png", read["dark.png"]), load_press(folder).dark)
    assert prefetch.take(folder / "led_01.png", read["led_01.png"]) is None


def test_nlips_solve_decodes_ahead_only_a_press_it_will_solve(tmp_path):
    """One press folder, no result at its output or ``--overwrite``: its images are prefetched; a result already
    there is most likely reused, and nothing is decoded for it; a folder that is no press is left to the load."""
    from nlipscalib.cli.solve import _decode_ahead

    folder = _press(tmp_path / "p")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "result.npz").write_bytes(b"")
    key = prefetch._key(folder / "dark.png")
    for out, overwrite, expected in [
        (None, False, True),
        (tmp_path / "out", False, False),
        (tmp_path / "out", True, True),
    ]:
        prefetch._items.pop(key, None)
        _decode_ahead(argparse.Namespace(press=str(folder), out=out, overwrite=overwrite))
        assert (key in prefetch._items) is expected
    prefetch._items.clear()
    _decode_ahead(argparse.Namespace(press=str(tmp_path), out=None, overwrite=True))  # a folder of presses
    assert not prefetch._items


def test_a_prefetched_press_has_its_reference_read_ahead_and_the_load_reads_it_no_more(tmp_path, monkeypatch):
    """``nlips solve`` reads the press's reference.npz beside the solver's import too (on a thread of its own): the
    load then finds it read and checked, the same arrays, and does not read the file again."""
    import threading

    from nlipscalib.core import capture, surface_files

    folder = _press(tmp_path / "p")
    reads = []
    load = surface_files.Reference.load.__func__
    monkeypatch.setattr(
        surface_files.Reference,
        "load",
        classmethod(lambda cls, *a: reads.append(threading.current_thread().name) or load(cls, *a)),
    )
    capture.prefetch_press(folder)
    for thread in threading.enumerate():
        if thread.name in ("prefetch-reference", "prefetch-images"):
            thread.join()
    assert reads == ["prefetch-reference"]
    press = load_press(folder)
    assert reads == ["prefetch-reference"]  # not read again
    np.testing.assert_array_equal(press.reference.depth, np.full(press.camera.shape, 10.0, np.float32))


def test_a_broken_reference_read_ahead_is_reported_by_the_load(tmp_path):
    from nlipscalib.core import capture

    folder = _press(tmp_path / "p")
    (folder / "reference.npz").write_bytes(b"not a zip")
    capture.prefetch_press(folder)  # nothing raised on its thread
    with pytest.raises(CaptureError, match="reference.npz"):
        load_press(folder)


def test_a_prefetched_press_has_its_tricolour_image_decoded_ahead_after_the_led_images(tmp_path, monkeypatch):
    """``nlips solve`` decodes the tri-colour image beside the solver's import too, after the LED images: the load
    takes it from there (no decoding on the thread that reads it), the same array."""
    import os
    import threading

    from nlipscalib.core import capture

    folder = _press(tmp_path / "p")
    expected = load_press(folder).tricolor
    order = []
    decode = stored_images.decode_png16
    monkeypatch.setattr(
        prefetch, "decode_png16", lambda data, key: order.append(os.path.basename(key)) or decode(data, key)
    )
    capture.prefetch_press(folder)
    for thread in threading.enumerate():
        if thread.name in ("prefetch-reference", "prefetch-images"):
            thread.join()
    assert order == ["dark.png", "led_01.png", "led_02.png", "led_03.png", "tricolor.png"]
    _no_decoding(monkeypatch)
    np.testing.assert_array_equal(load_press(folder).tricolor, expected)
