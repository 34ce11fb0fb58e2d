"""Sensor noise model: quantisation, shot + read noise statistics, saturation, determinism."""

import numpy as np

from nlipscalib.core import Led
from nlipscalib.sim.noise import apply_noise, auto_exposure, dark_frame
from nlipscalib.sim.scene import NoiseConfig


def _dn(stored, cfg):
    return stored.astype(np.float64) / (1 << (16 - cfg.bit_depth))


def test_disabled_noise_only_quantises():
    cfg = NoiseConfig(enabled=False, bit_depth=12, black_level=64)
    x = np.linspace(0, 1, 3 * 50).reshape(1, 50, 3)
    out = apply_noise(x, 1.0, cfg, None)
    assert out.dtype == np.uint16
    want = np.rint(x * (4095 - 64) + 64)
    np.testing.assert_array_equal(_dn(out, cfg), want)
    assert np.all(out % 16 == 0)  # DN << 4


def test_shot_and_read_noise_statistics():
    cfg = NoiseConfig(full_well=10000.0, read_noise=2.0, bit_depth=12, black_level=64)
    span = 4095 - 64
    rng = np.random.default_rng(0)
    for x in (0.02, 0.5):  # Poisson branch (200 e-) and normal branch (5000 e-)
        dn = _dn(apply_noise(np.full((200, 200, 3), x), 1.0, cfg, rng), cfg)
        gain = span / cfg.full_well  # DN per electron
        var = x * cfg.full_well * gain**2 + cfg.read_noise**2 + 1 / 12
        assert abs(dn.mean() - (x * span + 64)) < 4 * np.sqrt(var / dn.size) + 0.01
        assert abs(dn.var() / var - 1) < 0.03


def test_dark_frame_is_black_level_plus_read_noise():
    cfg = NoiseConfig(read_noise=2.0, black_level=64)
    dn = _dn(dark_frame((100, 100), cfg, np.random.default_rng(1)), cfg)
    assert dn.shape == (100, 100, 3)
    assert abs(dn.mean() - 64) < 0.05 and abs(dn.std() - np.sqrt(4 + 1 / 12)) < 0.1


def test_saturation_clips_at_white_level():
    cfg = NoiseConfig(bit_depth=12)
    out = apply_noise(np.full((10, 10, 3), 3.0), 1.0, cfg, np.random.default_rng(2))
    assert np.all(out == cfg.response().white_level)


def test_same_seed_same_noise_and_linear_round_trip():
    cfg = NoiseConfig()
    x = np.random.default_rng(3).uniform(0, 0.5, (20, 30, 3))
    a = apply_noise(x, 2.0, cfg, np.random.default_rng(7))
    b = apply_noise(x, 2.0, cfg, np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)
    r = cfg.response()
    lin = (a.astype(np.float64) - r.black_level) / (r.white_level - r.black_level)
    assert abs(np.mean(lin - 2 * x)) < 2e-3  # Press.linear recovers radiance * exposure


def test_auto_exposure_scales_with_config_and_albedo():
    pts = np.stack([*np.meshgrid(np.linspace(-5, 5, 20), np.linspace(-5, 5, 20)), np.full((20, 20), 10.0)], -1)
    pts = pts.reshape(-1, 3)
    n = np.tile([0, 0, -1.0], (len(pts), 1))
    leds = [Led((3, 0, 0)), Led((-3, 0, 0))]
    e1 = auto_exposure(pts, n, leds, (0.8, 0.8, 0.8))
    assert np.isclose(auto_exposure(pts, n, leds, (0.4, 0.4, 0.4)), 2 * e1)
    assert np.isclose(auto_exposure(pts, n, leds, (0.8, 0.8, 0.8), scale=0.5), 0.5 * e1)
