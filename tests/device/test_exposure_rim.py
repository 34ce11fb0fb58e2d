"""The capture's exposure check on a camera that sees the whole dome down to its base (the gel does not fill the
frame: a circular image with black corners). One small render (160x120, direct light: the default) of the default
nlipstac design with its camera 8 mm below the base and a 130 deg field of view: its base, at the LEDs' own height,
is lit at a tenth of the gel's median, and before s32-rimview ``nlips capture --emulate`` warned at every press
"columns 4-10 (left) of every LED image are dark" (read while no LED was lit)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mitsuba")
pytest.importorskip("cv2")

from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.core.imageio import read_image  # noqa: E402
from nlipscalib.core.repeated_frames import model_light  # noqa: E402
from nlipscalib.device.exposure import check_exposure  # noqa: E402
from nlipscalib.sim.press import render_press  # noqa: E402
from nlipscalib.sim.scene import load_scene  # noqa: E402

RIM_VIEW = {"width": 160, "height": 120, "hfov_deg": 130.0, "position": (0.0, 0.0, -8.0)}


def test_the_dim_base_of_a_wide_view_is_no_band_read_unlit(tmp_path):
    folder = render_press(load_scene().replace(camera=RIM_VIEW), None, tmp_path / "reference", seed=3)
    press = load_press(folder)
    frames = {path.stem: read_image(path) for path in sorted(folder.glob("*.png"))}
    gel = np.isfinite(press.reference.depth)
    expected = model_light(press.reference.depth, press.reference.normals, press.camera, press.leds)
    alone = check_exposure(frames, press.response, folder, gel, reference=True)
    assert any("of every LED image are dark" in line for line in alone)  # the images alone: the base looks unlit
    assert check_exposure(frames, press.response, folder, gel, reference=True, expected=expected) == []
    # columns 60-79 read while no LED was lit in every LED frame: still named
    for name in [name for name in frames if name.startswith("led_")]:
        frames[name][:, 60:80] = frames["dark"][:, 60:80]
    lines = check_exposure(frames, press.response, folder, gel, reference=True, expected=expected)
    assert any("columns" in line and "of every LED image are dark" in line for line in lines), lines
