"""``device.additivity``: a camera-response curve judged by LEDs lit apart and together, on synthetic frames of a
gamma 2.2 camera whose light is known. A curve off by a power is raised back to the camera's; a pair that dims as
a whole is refused; the pairs' exposure keeps two LEDs' light below clipping.

Why: a bracket cannot tell a curve from its power (times ``c * t ** a``); light adds, whatever the times."""

from __future__ import annotations

import numpy as np
import pytest

from nlipscalib.core.errors import CaptureError
from nlipscalib.core.tolerances import RESPONSE_ADDITIVITY_ERROR
from nlipscalib.device.additivity import AdditivityFrames, pair_exposure, pin_power

GAMMA = 2.2
ROWS = np.linspace(0.05, 0.4, 48 * 64).reshape(48, 64, 1) * np.ones(3)
LIGHTS = {1: ROWS, 2: ROWS[::-1, ::-1], 7: np.linspace(0.05, 0.4, 64).reshape(1, 64, 1) * np.ones((48, 1, 3))}
"""Each LED's light over the frame, fraction of full scale: pixels lit alike by a pair and lit mostly by one."""
TRUE = np.broadcast_to((np.arange(256) / 255) ** GAMMA, (3, 256))


def _codes(light: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(255 * np.minimum(light, 1) ** (1 / GAMMA)), 0, 255).astype(np.uint8)


def _shots(droop: float = 1.0) -> AdditivityFrames:
    pairs = tuple((a, b, _codes(droop * (LIGHTS[a] + LIGHTS[b]))) for a, b in ((1, 2), (1, 7), (2, 7)))
    return AdditivityFrames(8.0, _codes(0 * ROWS), {k: _codes(v) for k, v in LIGHTS.items()}, pairs)


def test_the_cameras_curve_adds_and_is_kept():
    curves, check = pin_power(TRUE, _shots(), "cam")
    assert curves is TRUE and check.power == 1.0 and check.before < RESPONSE_ADDITIVITY_ERROR / 2


@pytest.mark.parametrize("power", [0.9, 1.1])
def test_a_curve_off_by_a_power_is_raised_back_to_the_cameras(power):
    curves, check = pin_power(TRUE ** (1 / power), _shots(), "cam")
    assert check.before > 3 * RESPONSE_ADDITIVITY_ERROR and check.after < RESPONSE_ADDITIVITY_ERROR / 2
    assert abs(check.power - power) < 0.01
    assert np.abs(curves - TRUE).max() < 0.003


def test_a_pair_that_dims_as_a_whole_is_refused_not_absorbed():
    with pytest.raises(CaptureError, match=r"^cam: with the fitted curve undone, LEDs \d and \d lit together give 0.9"):
        pin_power(TRUE, _shots(droop=0.95), "cam")


def test_the_pairs_exposure_keeps_two_leds_below_clipping():
    times = [0.5 * 2 ** (k / 2) for k in range(15)]
    frames = [_codes(ROWS * t / 8) for t in times]
    # ROWS reaches 0.4 at 8 ms: twice 8 ms (16) peaks at 0.8, twice 11.3 (22.6) clips a sixth of the frame
    assert pair_exposure(frames, times) == 8.0
    assert pair_exposure(frames[-2:], times[-2:]) == times[-2]  # none keeps two below clipping: the shortest


def test_pairs_with_no_pixel_to_judge_leave_the_curve_as_fitted():
    """Every pair clipped (an exposure too long for two LEDs): nothing is judged, nothing raised or refused; the
    command says the curve went unchecked."""
    clipped = AdditivityFrames(8.0, _codes(0 * ROWS), {k: _codes(v) for k, v in LIGHTS.items()}, ())
    clipped = AdditivityFrames(8.0, clipped.dark, clipped.singles, ((1, 2, _codes(ROWS + 1)),))
    curves, check = pin_power(TRUE**1.2, clipped, "cam")
    assert np.array_equal(curves, TRUE**1.2) and check.power == 1.0 and np.isnan(check.before)
