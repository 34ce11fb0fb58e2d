"""An LED aged on its own under a large contact, on the digital twin (Mitsuba renders, 320x240, one bounce, 16 spp,
sensor noise; at 160x120 the aged LED's 2 % misfit alone spans the gel, and ``--roi auto``'s box with it): a 30 mm
sphere pressed 3 mm at polar 10 deg covers 41 % of the gel, and its dent changes the light the rest of the gel gets
(one bounce; none without bounces), so the per-LED brightness against the undeformed capture reads off by up to 2 %
outside ``--roi auto``'s box as well as over the whole gel, each its own way. benchmarks/RESULTS.md,
s42-autogain2."""

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.sim.indent import PressConfig  # noqa: E402
from nlipscalib.sim.indenters import IndenterConfig  # noqa: E402
from nlipscalib.sim.press import render_press  # noqa: E402
from nlipscalib.sim.scene import load_scene  # noqa: E402
from nlipscalib.solver import solve_press  # noqa: E402
from nlipscalib.solver.led_checks import changed_leds, exposure_ratio, led_gains  # noqa: E402
from nlipscalib.solver.press import _outside_auto_box  # noqa: E402

from .twin_helpers import dimmed_copy  # noqa: E402

LARGE_SPHERE = PressConfig(IndenterConfig(kind="sphere", size=30.0), polar_deg=10, azimuth_deg=30, depth=3.0)
AGED = 7  # 0-based: LED 8, across the dome from the contact
AGED_GAIN = 0.98


@pytest.fixture(scope="module")
def large_sphere(tmp_path_factory):
    """The undeformed dome, the large sphere press, and that press with LED 8 2 % dimmer (aged since the undeformed
    capture)."""
    root = tmp_path_factory.mktemp("aged_large")
    sc = load_scene().replace(
        render={"bounces": 1, "spp": 16}, noise={"enabled": True}, camera={"width": 320, "height": 240}
    )
    reference = load_press(render_press(sc, None, root / "reference", seed=1))
    press = load_press(render_press(sc, LARGE_SPHERE, root / "sphere", seed=5))
    gain = np.where(np.arange(len(press.leds)) == AGED, AGED_GAIN, 1.0)
    return reference, press, dimmed_copy(press, root / "aged", gain)


def _outside_gains(press, reference):
    """:func:`led_gains` measured outside the box ``--roi auto`` finds, alone (s41-autogain's rescale)."""
    outside = _outside_auto_box(press, {"indirect": reference})
    return led_gains(exposure_ratio(press, reference, (), None, outside))


def test_an_aged_led_under_a_large_contact_is_rescaled_alone(large_sphere):
    """LED 8 2 % dimmer: the whole gel says it strays, so ``--roi auto`` measures the gains outside its box too, where
    the dent's light also puts LEDs 1, 2 and 12 1.1-1.6 % low. Rescaled now: only the LED both measures find, LED 8.
    Before, every LED by its outside ratio (LEDs 1, 2 and 12 too; at 640x480 the sphere's contact AAE 1.08 deg, 0.80
    now, 0.79 with LED 8's true gain alone)."""
    reference, _, aged = large_sphere
    assert set(changed_leds(_outside_gains(aged, reference))) > {AGED}  # the outside alone: healthy LEDs too
    gains = np.asarray(solve_press(aged, indirect=reference, roi="auto").report["led_gains"])
    assert changed_leds(gains) == [AGED]
    assert np.abs(gains[AGED] - AGED_GAIN).max() < 0.01, gains[AGED]  # 0.987: outside the box LED 8 reads 0.7 % up
    assert (np.delete(gains, AGED, axis=0) == 1.0).all()  # the others' images as captured


def test_a_large_contact_alone_rescales_no_led(large_sphere):
    """No LED aged: the whole gel finds none astray, and no image is rescaled, though outside the box alone LEDs 1, 2
    and 12 read 1.2-1.8 % low (the dent's light, not an age): why the gains are not taken from there alone (at 640x480
    that rescale cost the sphere's contact 0.79 -> 0.95 deg)."""
    reference, press, _ = large_sphere
    assert _outside_gains(press, reference) is not None
    assert led_gains(exposure_ratio(press, reference)) is None
    assert solve_press(press, indirect=reference, roi="auto").report["led_gains"] is None
