"""``nlips capture``'s exposure check names the consecutive LEDs a lag between which it cannot see (LEDs designed in
close pairs: their light on the gel alike), once per command (s36-lagcost). Exact-data presses (96x72) of the
default ring's LEDs in six pairs 0.5 mm apart, and of the ring."""

from __future__ import annotations

import logging

import pytest

pytest.importorskip("cv2")

from nlipscalib.core import load_press, said_once  # noqa: E402
from nlipscalib.core.repeated_frames import model_light  # noqa: E402
from nlipscalib.device.exposure import check_exposure  # noqa: E402
from tests.solver import synth  # noqa: E402
from tests.solver.test_lag_blind_report import _paired_leds  # noqa: E402


def _checked(press, folder) -> list[str]:
    """The exposure check of ``press``'s frames as ``nlips capture`` runs it (its gel, its design's LED model)."""
    import numpy as np

    frames = {"dark": press.dark, "tricolor": press.tricolor}
    frames |= {f"led_{k + 1:02d}": image for k, image in enumerate(press.led_images)}
    expected = model_light(press.reference.depth, press.reference.normals, press.camera, press.leds)
    return check_exposure(frames, press.response, folder, np.isfinite(press.reference.depth), expected=expected)


def test_leds_in_close_pairs_are_named_once_as_pairs_a_lag_between_which_goes_unseen(tmp_path, caplog):
    paired = load_press(synth.make_press(tmp_path / "paired", "none", leds=_paired_leds()))
    ring = load_press(synth.make_press(tmp_path / "ring", "none"))
    with said_once.scope(), caplog.at_level(logging.INFO, logger="nlipscalib"):
        lines = [
            *_checked(paired, "session/press_0001"),
            *_checked(paired, "session/press_0002"),
            *_checked(ring, "other/press_0001"),
        ]
    # clean captures: no frame called lagged or repeated (the synthetic tricolor frame is saturated: said apart)
    assert not any("switched while the camera read" in line or "repeats" in line for line in lines)
    said = [record for record in caplog.records if "lag-band check cannot see" in record.getMessage()]
    assert len(said) == 1 and said[0].levelno == logging.INFO
    assert said[0].getMessage().startswith("session/press_0001: the lag-band check cannot see a frame read out")
    assert "LEDs 1 to 2 (0.5 mm apart" in said[0].getMessage() and "--flush 1 or more" in said[0].getMessage()
