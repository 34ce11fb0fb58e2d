"""Known answers of the images' noise estimate (solver.image_stats.image_noise), on a three-colour camera's frames and
on a Bayer camera's, whose demosaicing the plain Immerkaer mask cancels (s43-bayer)."""

import numpy as np
import pytest

from nlipscalib.sim.bayer import DEMOSAIC_METHODS, bayer_camera
from nlipscalib.solver import image_stats

SIGMA = 0.01
"""Each pixel's noise, linear units (a fraction of the full scale)."""


def _frames(bayer: str | None, method: str = "edge_aware") -> np.ndarray:
    """(4, 96, 128, 3) float: smooth shading (each image its own slope and colour) with independent noise per pixel and
    channel, stored in 16 bits; through a Bayer camera when ``bayer`` names its pattern."""
    rng = np.random.default_rng(4)
    y, x = np.mgrid[:96, :128] / 128.0
    light = np.stack(
        [(0.3 + 0.2 * np.sin(2 * x + k) * np.cos(y - k))[..., None] * rng.uniform(0.8, 1.2, 3) for k in range(4)]
    )
    stored = np.clip(np.rint(60000 * (light + SIGMA * rng.standard_normal(light.shape))), 0, 65535).astype(np.uint16)
    if bayer is not None:
        stored = bayer_camera(stored, bayer, method)
    return stored.astype(np.float32) / 60000


def test_a_three_colour_cameras_noise_is_the_plain_estimate_unchanged(monkeypatch):
    frames, valid = _frames(None), np.ones((96, 128), bool)
    found = image_stats.image_noise(frames, valid)
    assert found == pytest.approx(SIGMA, rel=0.05)
    monkeypatch.setattr(image_stats, "BAYER_NOISE_RATIO", np.inf)  # the plain estimate alone, as until s43
    assert image_stats.image_noise(frames, valid) == found


@pytest.mark.parametrize("method", DEMOSAIC_METHODS)
@pytest.mark.parametrize("pattern", ["RGGB", "GBRG"])
def test_a_bayer_cameras_noise_is_its_pixels_own_not_the_zero_the_plain_mask_leaves(monkeypatch, pattern, method):
    """The demosaiced frames' colours are interpolated linearly between the pixels that record them: the plain mask
    cancels the interpolated pixels and its median measured a fraction of the noise (0 on the twin's frames), which
    left the solve anchoring nothing. The estimate over each 2x2 position is the recorded pixels' own noise."""
    frames, valid = _frames(pattern, method), np.ones((96, 128), bool)
    assert image_stats.image_noise(frames, valid) == pytest.approx(SIGMA, rel=0.1)
    monkeypatch.setattr(image_stats, "BAYER_NOISE_RATIO", np.inf)
    assert image_stats.image_noise(frames, valid) < 0.5 * SIGMA
