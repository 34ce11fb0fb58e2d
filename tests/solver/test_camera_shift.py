"""A press whose image is shifted against its undeformed capture (the camera moved) is warned about, with the shift."""

import numpy as np
import pytest

from nlipscalib.core import load_press
from nlipscalib.solver.camera_shift import camera_shift, shift_note

from . import synth


def _moved(dx):
    def hook(lin):
        return np.roll(lin, dx, axis=2)  # (L, H, W, 3): the camera moved, the view slid by dx pixels along x

    return hook


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    root = tmp_path_factory.mktemp("shift")
    reference = load_press(synth.make_press(root / "reference", "none"))
    still = load_press(synth.make_press(root / "still", "sphere"))
    moved = load_press(synth.make_press(root / "moved", "sphere", lin_hook=_moved(2)))
    return reference, still, moved


def test_a_press_two_pixels_off_its_undeformed_capture_is_warned_about_with_its_shift(captures):
    """The twin's cube press 2 px off its undeformed capture solved to 0.925 deg (0.424 in place) without a word."""
    reference, _, moved = captures
    dx, dy = camera_shift(reference.linear_led_images, moved.linear_led_images, np.isfinite(moved.reference.depth))
    assert 1.5 < dx < 2.5 and abs(dy) < 0.3
    note = shift_note(moved, reference)
    assert note is not None and str(moved.folder) in note and "(+" in note and "new reference" in note


def test_a_press_in_place_is_not_warned_about(captures):
    reference, still, _ = captures
    dx, dy = camera_shift(reference.linear_led_images, still.linear_led_images, np.isfinite(still.reference.depth))
    assert np.hypot(dx, dy) < 0.5
    assert shift_note(still, reference) is None
