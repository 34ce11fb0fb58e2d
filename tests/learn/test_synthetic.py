"""Model-based samples of steep relief (learn.synthetic): the LED model's light, the mixing fit, the training option."""

import numpy as np
import pytest

from nlipscalib.core.errors import ConfigError
from nlipscalib.core.leds import Led, led_shading
from nlipscalib.core.metrics import angle_deg
from nlipscalib.learn import synthetic as sy
from nlipscalib.learn.checkpoint import jsonable_config
from nlipscalib.learn.train import TrainConfig

LEDS = [
    Led(position=(8.0 * np.cos(a), 8.0 * np.sin(a), 3.0), direction=(-0.3 * np.cos(a), -0.3 * np.sin(a), 0.95))
    for a in np.deg2rad([0, 40, 80, 120, 160, 200, 240, 280, 320])
]
"""Nine LEDs on a ring, three per tri-colour group."""
MIXING = sy.Mixing(
    matrix=np.array([[0.4, 0.02, 0.0], [0.01, 0.38, 0.03], [0.0, 0.02, 0.41]]),
    offset=np.array([0.01, 0.02, 0.005]),
    rms=np.zeros(3),
    pixels=0,
)


def _flat_sensor(height=6, width=8, z=12.0):
    """A flat gel at depth z (normals toward the camera), seen by a pinhole camera, and its rays."""
    v, u = np.mgrid[0:height, 0:width]
    rays = np.stack([(u - (width - 1) / 2) * 0.3, (v - (height - 1) / 2) * 0.3, np.full(u.shape, 4.0)], -1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    normals = np.broadcast_to([0.0, 0.0, -1.0], rays.shape).astype(np.float32)
    reference = {"depth": np.full((height, width), z, np.float32), "normals": normals, "valid": np.ones(u.shape, bool)}
    return reference, rays


@pytest.mark.parametrize("reflectance", [0.0, 0.8])
def test_synthetic_colour_is_the_led_models_light_mixed(reflectance):
    """A sample's colour is M (the LED model's light of each group at its point and normal, plus the indirect light
    of the surface around: reflectance x its light x (1 - cos 40 deg) / 2) + o, where the reference frame is M (the
    light at the undeformed point) + o: unit albedo, point 1 mm behind along the ray, tilt 40 deg."""
    reference, rays = _flat_sensor()
    points0 = reference["depth"][..., None] / rays[..., 2:3] * rays
    light0 = sy.group_light(points0.reshape(-1, 3), reference["normals"].reshape(-1, 3), LEDS)
    tricolor = (light0 @ MIXING.matrix.T + MIXING.offset).reshape(rays.shape)
    out = sy.synthetic_samples(
        reference,
        tricolor,
        rays,
        LEDS,
        MIXING,
        200,
        np.random.default_rng(3),
        tilt_deg=(40, 40),
        behind_mm=(1, 1),
        reflectance=reflectance,
    )
    assert 0 < len(out["rgb"]) <= 200 and out["contact"].all() and (out["source"] == sy.SOURCE_SYNTHETIC).all()
    u, v = out["pixel"][:, 0], out["pixel"][:, 1]
    points = points0[v, u] + rays[v, u]
    # the light written out by hand from led_shading: each group's LEDs summed, channels averaged
    shading = led_shading(points, out["normal"].astype(np.float64), LEDS).mean(-1)
    light = np.stack([shading[3 * g : 3 * g + 3].sum(0) for g in range(3)], -1)
    light += reflectance * light0.reshape(rays.shape)[v, u] * (1 - np.cos(np.deg2rad(40.0))) / 2
    np.testing.assert_allclose(out["rgb"], light @ MIXING.matrix.T + MIXING.offset, rtol=2e-5, atol=1e-6)
    np.testing.assert_allclose(angle_deg(out["normal"], reference["normals"][v, u]), 40.0, atol=1e-3)
    np.testing.assert_array_equal(out["normal"], out["true_normal"])


def test_normals_facing_away_from_the_camera_are_dropped():
    reference, rays = _flat_sensor()
    tricolor = np.ones(rays.shape)
    out = sy.synthetic_samples(
        reference, tricolor, rays, LEDS, MIXING, 500, np.random.default_rng(0), tilt_deg=(89, 89.9)
    )
    u, v = out["pixel"][:, 0], out["pixel"][:, 1]
    assert len(out["rgb"]) < 500
    assert np.all(np.sum(-rays[v, u] * out["normal"], -1) >= sy.MIN_VIEW_COS - 1e-6)


def test_mixing_fit_recovers_a_known_matrix():
    rng = np.random.default_rng(1)
    sums = rng.uniform(0.1, 2.0, (5000, 3))
    tricolor = sums @ MIXING.matrix.T + MIXING.offset + rng.normal(0, 1e-4, (5000, 3))
    tricolor[7] = np.nan  # an unusable pixel is left out, not spread over the fit
    fit = sy.fit_mixing(tricolor, sums)
    np.testing.assert_allclose(fit.matrix, MIXING.matrix, atol=1e-4)
    np.testing.assert_allclose(fit.offset, MIXING.offset, atol=1e-4)
    assert fit.pixels == 4999 and np.all(fit.rms < 2e-4)


def test_group_sums_sum_each_groups_leds():
    images = np.arange(6 * 2 * 3, dtype=float).reshape(6, 2, 3)
    sums = sy.group_sums(images, np.array([0, 0, 1, 1, 2, 2]))
    np.testing.assert_allclose(sums[:, 0], images[0].mean(-1) + images[1].mean(-1))
    np.testing.assert_allclose(sums[:, 2], images[4].mean(-1) + images[5].mean(-1))


def test_synthetic_share_is_checked_and_left_out_of_the_keys_at_zero():
    assert "synthetic_share" not in jsonable_config(TrainConfig())
    assert jsonable_config(TrainConfig(synthetic_share=0.25))["synthetic_share"] == 0.25
    with pytest.raises(ConfigError, match="synthetic_share"):
        TrainConfig(synthetic_share=-0.1)
    with pytest.raises(ConfigError, match="synthetic_reflectance"):
        TrainConfig(synthetic_share=0.25, synthetic_reflectance=1.5)


def test_training_adds_the_synthetic_samples_of_the_datasets_sensor(calib, tmp_path):
    """On the small twin's dataset (its reference capture's LEDs, its presses' images for the mixing): the samples are
    steep and on the gel, and a training with a share of them trains on them and says how many it had."""
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.train import train

    names = calib.names[:3]
    syn = sy.samples_for_dataset(calib, names, 400, seed=0, reflectance=sy.GEL_REFLECTANCE)
    ref = calib.reference()
    u, v = syn["pixel"][:, 0], syn["pixel"][:, 1]
    tilt = angle_deg(syn["normal"], ref["normals"][v, u])
    assert 300 < len(tilt) <= 400 and ref["valid"][v, u].all()
    assert tilt.min() >= sy.TILT_DEG[0] - 1e-3 and tilt.max() <= sy.TILT_DEG[1] + 1e-3
    assert np.all(np.isfinite(syn["rgb"])) and np.all(syn["rgb"] > 0)
    plain, mixed = tmp_path / "plain.pt", tmp_path / "mixed.pt"
    train(calib, TrainConfig(max_epochs=1), plain, val_names=["press_d"], progress=False)
    train(calib, TrainConfig(max_epochs=1, synthetic_share=0.5), mixed, val_names=["press_d"], progress=False)
    info_plain, info_mixed = load_model(plain).info, load_model(mixed).info
    assert info_plain["synthetic_samples"] == 0
    real = info_plain["train_samples"]
    assert 0.4 * real < info_mixed["synthetic_samples"] <= round(0.5 * real)
    assert info_mixed["train_samples"] == real + info_mixed["synthetic_samples"]
