"""The lag-band check on a design with its LEDs in close pairs (s35-exchange's scene copy: 12 LEDs in six pairs
0.8 mm apart on the 9 mm ring, point emitters, 160x120, one bounce, 16 spp).

Far from a pair its two LEDs light the gel within 1 % of each other, which the images alone take for the previous
LED's light repeated: every clean capture of such designs (24 of 24) was warned "led_02.png's columns 0-34 (left)
show led_01.png's light" and those columns were left out of LED 2's fit and of the solve. Each LED's modelled light
now tells where the two lights are alike by design.
"""

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.core.repeated_frames import frame_checks, model_light  # noqa: E402
from nlipscalib.sim.press import render_press  # noqa: E402
from tests.cli.test_calibrate_leds import _close_pairs_scene  # noqa: E402


@pytest.fixture(scope="module")
def paired(tmp_path_factory):
    return load_press(render_press(_close_pairs_scene(), None, tmp_path_factory.mktemp("pairs") / "clean", seed=1))


def test_leds_in_close_pairs_are_no_lag_band_and_a_true_lag_is_still_found(paired):
    images = np.array(paired.linear_led_images)
    gel = np.isfinite(paired.reference.depth)
    expected = model_light(paired.reference.depth, paired.reference.normals, paired.camera, paired.leds)
    # the images alone: the second LED of a pair "shows" the first's light far from the pair
    assert {band.index for band in frame_checks(images, gel)[1]} & {1, 7}
    assert frame_checks(images, gel, expected)[:2] == ([], [])
    # LED 3's frame (the first of the second pair) read across the switch: its top 3/8 rows, or its left 3/8
    # columns, still hold LED 2's light (the other pair's): found against the model as without it
    for lines, axis in ((np.s_[:45], "rows"), (np.s_[:, :60], "columns")):
        lagged = images.copy()
        lagged[2][lines] = images[1][lines]
        bands = frame_checks(lagged, gel, expected)[1]
        assert [(band.index, band.axis, band.top) for band in bands] == [(2, axis, True)]
