"""A solve's images held as one box of the frame (solver/frame_box.py): what the solve reads of them is the whole
frame's, so are its results' bits."""

import numpy as np
import pytest

from nlipscalib.core import load_press
from nlipscalib.core.errors import ShapeError
from nlipscalib.solver import SolverOptions, solve
from nlipscalib.solver.frame_box import FrameBox, frame_crop
from nlipscalib.solver.samples import exclusions

from . import synth

WINDOW = (slice(10, 50), slice(20, 75))


def _frame_box(seed: int = 0, shape=(4, 72, 96, 3)) -> FrameBox:
    """Images whose box differs from the frame under it (so a read of the frame there would show)."""
    rng = np.random.default_rng(seed)
    frame = rng.uniform(0.0, 1.0, shape).astype(np.float32)
    box = frame[:, WINDOW[0], WINDOW[1]] * np.float32(0.5) + np.float32(0.25)
    return FrameBox(frame, box, WINDOW)


def test_a_frame_box_reads_its_box_on_the_window_and_its_frame_elsewhere():
    fb = _frame_box()
    whole = fb.whole()
    assert whole.shape == fb.shape == fb.frame.shape and fb.dtype == np.float32
    np.testing.assert_array_equal(whole[:, WINDOW[0], WINDOW[1]], fb.box)
    outside = np.ones(whole.shape[1:3], bool)
    outside[WINDOW] = False
    np.testing.assert_array_equal(whole[:, outside], fb.frame[:, outside])
    crop = (slice(12, 40), slice(30, 75))
    np.testing.assert_array_equal(frame_crop(fb, crop), whole[:, crop[0], crop[1]])
    assert np.shares_memory(frame_crop(fb, crop), fb.box)  # a view of the box, no copy
    index = np.arange(0, whole.shape[1] * whole.shape[2], 7)
    np.testing.assert_array_equal(fb.pixels(index), whole.reshape(len(whole), -1, 3)[:, index])
    with pytest.raises(ShapeError, match="outside the frame box's window"):
        fb.crop((slice(5, 40), slice(30, 60)))
    with pytest.raises(ShapeError, match="a frame box must be"):
        FrameBox(fb.frame, fb.box[:, 1:], WINDOW)


def test_the_thresholds_of_a_crop_are_those_of_its_whole_frame():
    """The dead-LED and shadow thresholds are statistics of the whole images at the bright ends' sample grid: of a
    frame box, its box's values there, not the frame's under it."""
    fb = _frame_box(1)
    whole = fb.whole()
    crop = (slice(20, 40), slice(30, 60))
    opts = SolverOptions()
    got, report = exclusions(frame_crop(fb, crop), None, opts, whole=fb)
    want, want_report = exclusions(whole[:, crop[0], crop[1]], None, opts, whole=whole)
    np.testing.assert_array_equal(got, want)
    assert report == want_report
    # the frame's values under the window would give other thresholds: the test can tell them apart
    frame_only, _ = exclusions(fb.frame[:, crop[0], crop[1]], None, opts, whole=fb.frame)
    assert not np.array_equal(frame_only, want)


@pytest.fixture(scope="module")
def cube(tmp_path_factory):
    root = tmp_path_factory.mktemp("frame_box")
    synth.make_press(root / "cube", "cube", size=(96, 72))
    return load_press(root / "cube")


@pytest.mark.parametrize("normals", ["depth", "refined"])
def test_a_solve_of_a_frame_box_is_the_solve_of_its_whole_frame_to_the_bit(cube, normals):
    """What the outer interreflection loop hands the solver: the images minus a light on the mask's box, the
    press's images elsewhere. The same result as from the whole frame's array, refined normals included."""
    images = cube.linear_led_images
    mask = np.isfinite(cube.reference.depth)
    mask[:, :20] = False
    mask[:, 80:] = False
    window = (slice(0, 72), slice(20, 80))
    box = np.clip(images[:, window[0], window[1]] - np.float32(0.01), 0, None)
    fb = FrameBox(images, box, window)
    opts = SolverOptions(max_iters=6, normals=normals)
    kw = dict(prior_depth=cube.reference.depth, mask=mask, saturated=cube.saturated_led_images, options=opts)
    got = solve(fb, cube.camera, cube.leds, **kw)
    want = solve(fb.whole(), cube.camera, cube.leds, **kw)
    for name in ("depth", "normals", "albedo", "residual", "confidence", "reconstructed", "usable_leds"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    assert got.reconstructed.any()


def test_a_frame_box_with_a_value_not_finite_is_refused(cube):
    images = cube.linear_led_images
    mask = np.zeros(images.shape[1:3], bool)
    mask[20:50, 30:70] = True
    window = (slice(20, 50), slice(30, 70))
    kw = dict(prior_depth=cube.reference.depth, mask=mask, options=SolverOptions(max_iters=2))
    box = images[:, window[0], window[1]].copy()
    box[2, 5, 5, 1] = np.nan
    with pytest.raises(ShapeError, match="1 NaN/inf values"):
        solve(FrameBox(images, box, window), cube.camera, cube.leds, **kw)
    frame = images.copy()
    frame[1, 2, 3, 0] = np.inf  # outside the window
    with pytest.raises(ShapeError, match="1 NaN/inf values"):
        solve(FrameBox(frame, images[:, window[0], window[1]].copy(), window), cube.camera, cube.leds, **kw)


def test_a_frame_boxs_window_may_leave_its_bounds_open():
    fb = _frame_box()
    open_ended = FrameBox(fb.frame, fb.frame[:, 10:, :75].copy(), (slice(10, None), slice(None, 75)))
    assert open_ended.window == (slice(10, 72), slice(0, 75))
    np.testing.assert_array_equal(open_ended.crop((slice(20, 30), slice(0, 5))), fb.frame[:, 20:30, 0:5])
