"""Known-answer tests of the twin's non-ideal effects (extended LEDs, glossy coat, camera, gel optics)."""

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from nlipscalib.core import led_shading, load_press  # noqa: E402
from nlipscalib.core.errors import ConfigError  # noqa: E402
from nlipscalib.core.leds import Led  # noqa: E402
from nlipscalib.sim.camera_effects import defocus, disk_psf, vignetting_map  # noqa: E402
from nlipscalib.sim.noise import apply_noise, dark_frame  # noqa: E402
from nlipscalib.sim.press import render_press, undeformed_mesh  # noqa: E402
from nlipscalib.sim.render import render_surface  # noqa: E402
from nlipscalib.sim.render.shapes import plate  # noqa: E402
from nlipscalib.sim.scene import CameraEffectsConfig, NoiseConfig, SceneConfig, load_scene  # noqa: E402

W, H = 48, 36
PLATE_Z = 10.0
"""Plate height in the dome frame, mm (13 mm in front of the camera)."""
LEDS = {"positions": [[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [0.0, -4.0, 1.0]], "directions": [[0, 0, 1]] * 3, "mu": 1.5}


@pytest.fixture(scope="module")
def flat_scene():
    """Three LEDs facing a plate, ideal camera, no noise (each test switches on the effect it checks)."""
    return (
        SceneConfig()
        .ideal()
        .replace(
            camera={"width": W, "height": H, "hfov_deg": 90.0},
            leds=LEDS,
            noise={"enabled": False},
            render={"spp": 64, "bounces": 0, "threads": 2},
        )
    )


def _area_quadrature(led: Led, shape: str, size: float, n: int = 40) -> list[Led]:
    """Point LEDs at a fine grid of the emitting area, each with Psi / (number of points)."""
    g = (np.arange(n) + 0.5) / n - 0.5
    a, b = (c.ravel() * size for c in np.meshgrid(g, g))
    if shape == "disk":
        keep = a**2 + b**2 <= (size / 2) ** 2
        a, b = a[keep], b[keep]
    d = np.asarray(led.direction)
    s = np.cross(d, [0.0, 1.0, 0.0] if abs(d[1]) < 0.9 else [1.0, 0.0, 0.0])
    s /= np.linalg.norm(s)
    t = np.cross(d, s)
    psi = tuple(np.asarray(led.intensity) / len(a))
    return [Led(tuple(led.position + ai * s + bi * t), led.direction, led.mu, psi) for ai, bi in zip(a, b)]


def test_quadrature_reproduces_the_on_axis_disk_formula():
    """Lambertian disk (mu = 1) of radius R facing a parallel plane at h: E = Psi / (h^2 + R^2) on the axis."""
    h, radius = 10.0, 4.0
    quad = _area_quadrature(Led((0.0, 0.0, 0.0), mu=1.0), "disk", 2 * radius, n=200)
    e = led_shading(np.array([[0.0, 0.0, h]]), np.array([[0.0, 0.0, -1.0]]), quad).sum(axis=0)[0, 0]
    assert e == pytest.approx(1.0 / (h**2 + radius**2), rel=1e-3)


@pytest.mark.parametrize("shape", ["disk", "square"])
def test_extended_led_equals_area_integral_of_the_mu_law(flat_scene, shape):
    size = 6.0
    scene = flat_scene.replace(led_package={"enabled": True, "shape": shape, "size": size})
    res = render_surface(scene, plate(z=PLATE_Z, half=60.0))
    gt, albedo = res.gt, np.asarray(scene.coating.albedo) / np.pi
    v = gt.valid
    for k, led in enumerate(scene.led_models()):
        want = led_shading(gt.points[v], gt.normals[v], _area_quadrature(led, shape, size)).sum(axis=0) * albedo
        point = led_shading(gt.points[v], gt.normals[v], [led])[0] * albedo
        ratio = res.images[k][v] / want
        assert abs(np.median(ratio) - 1) < 0.01, (shape, k, np.median(ratio))
        assert np.percentile(np.abs(ratio - 1), 90) < 0.05
        # and the extended LED really differs from the point LED here
        assert np.max(np.abs(want / point - 1)) > 0.03


def test_small_led_tends_to_the_point_led(flat_scene):
    surface = plate(z=PLATE_Z, half=60.0)
    point = render_surface(flat_scene, surface).images
    tiny = render_surface(flat_scene.replace(led_package={"enabled": True, "size": 0.01}), surface).images
    lit = point > 1e-3 * point.max()
    assert np.max(np.abs(tiny[lit] / point[lit] - 1)) < 1e-3


def test_glossy_coat_highlight_sits_at_the_mirror_point(flat_scene):
    scene = flat_scene.replace(coating={"specular": 1.0, "roughness": 0.05})
    res = render_surface(scene, plate(z=PLATE_Z, half=60.0))
    camera = scene.camera_model()
    h = PLATE_Z - scene.camera.position[2]  # plate depth in the camera frame
    for k, led in enumerate(scene.led_models()):
        p = np.asarray(led.position)
        mirror_eye = np.array([0.0, 0.0, 2 * h])  # the camera mirrored in the plate
        point = mirror_eye + (p - mirror_eye) * (h / (2 * h - p[2]))
        want = camera.project(point[None])[0]
        row, col = np.unravel_index(np.argmax(res.images[k, ..., 1]), (H, W))
        assert np.hypot(col - want[0], row - want[1]) <= 1.5, (k, (col, row), want)


def test_specular_weight_blends_out_the_diffuse_part(flat_scene):
    surface = plate(z=PLATE_Z, half=60.0)
    lambert = render_surface(flat_scene, surface).images
    same = render_surface(flat_scene.replace(coating={"specular": 0.0, "roughness": 0.5}), surface).images
    np.testing.assert_array_equal(same, lambert)
    half = render_surface(flat_scene.replace(coating={"specular": 0.5, "roughness": 0.05}), surface).images
    lit = lambert > 1e-3 * lambert.max()
    # away from the narrow highlight the coat reflects half the Lambertian light
    assert np.median(half[lit] / lambert[lit]) == pytest.approx(0.5, abs=0.01)


def test_polynomial_vignetting_is_recovered_from_a_flat_render(tmp_path):
    base = (
        SceneConfig()
        .ideal()
        .replace(
            camera={"width": W, "height": H}, noise={"enabled": False, "bit_depth": 16}, render={"spp": 1, "threads": 2}
        )
    )
    coeffs = [-0.3, 0.05, 0.0]
    vignetted = base.replace(camera_effects={"vignetting": "polynomial", "vignetting_coeffs": coeffs})
    plain = load_press(render_press(base, None, tmp_path / "plain", seed=1))
    dark = load_press(render_press(vignetted, None, tmp_path / "vig", seed=1))
    a, b = plain.linear(plain.led_images).sum(axis=0), dark.linear(dark.led_images).sum(axis=0)
    ok = a[..., 1] > 0.05 * a[..., 1].max()
    measured = b[..., 1][ok] / a[..., 1][ok]
    cam = base.camera_model()
    u, v = cam.pixel_grid()
    r2 = ((u - cam.cx) ** 2 + (v - cam.cy) ** 2) / ((W / 2) ** 2 + (H / 2) ** 2)
    want = 1 - 0.3 * r2 + 0.05 * r2**2
    np.testing.assert_allclose(measured, want[ok], rtol=2e-3)
    assert want.min() < 0.8  # the corners really are darker


def test_cos4_vignetting_is_one_on_axis_and_falls_off():
    cam = SceneConfig().replace(camera={"width": 41, "height": 31, "hfov_deg": 90.0}).camera_model()
    vmap = vignetting_map(cam, CameraEffectsConfig(vignetting="cos4"))
    assert vmap[15, 20] == pytest.approx(1.0, abs=1e-6)
    theta = np.arctan2(np.hypot(*cam.rays[15, -1, :2]), cam.rays[15, -1, 2])
    assert vmap[15, -1] == pytest.approx(np.cos(theta) ** 4, rel=1e-5)
    assert np.all(np.diff(vmap[15, 20:]) < 0)


def test_defocus_spreads_a_point_over_a_disk_and_keeps_the_light():
    image = np.zeros((41, 41, 3), np.float32)
    image[20, 20] = 1.0
    radius = 5.0
    out = defocus(image, radius)
    assert out.sum() == pytest.approx(3.0, rel=1e-5)
    yy, xx = np.mgrid[:41, :41]
    r = np.hypot(yy - 20, xx - 20)
    assert np.all(out[r > radius + 1] == 0)
    np.testing.assert_allclose(out[r < radius - 1, 0], 1 / (np.pi * radius**2), rtol=0.05)
    assert disk_psf(0.0).shape == (1, 1) and np.array_equal(defocus(image, 0.0), image)


def test_response_curve_and_black_level_error():
    noise = NoiseConfig(enabled=False, bit_depth=16)
    effects = CameraEffectsConfig(response_gamma=2.0, black_level_error=100.0)
    x = np.full((4, 4, 3), 0.25)
    stored = apply_noise(x, 1.0, noise, None, effects).astype(np.float64)
    dark = dark_frame((4, 4), noise, None, effects).astype(np.float64)
    span = noise.response().white_level - noise.response().black_level
    # the dark frame carries the true black level; subtracting it leaves the response curve alone
    assert dark.mean() == pytest.approx(noise.black_level + 100.0)
    np.testing.assert_allclose((stored - dark) / span, 0.25**2, atol=2e-5)
    # subtracting the stated black level instead is off by the error
    np.testing.assert_allclose((stored - noise.response().black_level) / span, 0.0625 + 100 / span, atol=2e-5)


def test_effect_settings_are_validated():
    with pytest.raises(ConfigError, match="led_package"):
        SceneConfig().replace(led_package={"enabled": False}, gel_optics={"enabled": True})
    with pytest.raises(ConfigError, match="specular"):
        SceneConfig().replace(coating={"specular": 1.5})
    with pytest.raises(ConfigError, match="vignetting"):
        SceneConfig().replace(camera_effects={"vignetting": "polynomial", "vignetting_coeffs": [-1.2, 0, 0]})
    with pytest.raises(ConfigError, match="shape"):
        SceneConfig().replace(led_package={"shape": "hexagon"})


@pytest.fixture(scope="module")
def dome_scene():
    return (
        SceneConfig()
        .ideal()
        .replace(
            camera={"width": 24, "height": 18},
            noise={"enabled": False},
            render={"threads": 2},
            led_package={"enabled": True},
        )
    )


def test_index_matched_gel_renders_as_without_the_interface(dome_scene):
    mesh = undeformed_mesh(dome_scene.dome)
    straight = render_surface(dome_scene, mesh, spp=16)
    matched = dome_scene.replace(gel_optics={"enabled": True, "gel_ior": 1.3, "housing_ior": 1.3})
    through = render_surface(matched, mesh, spp=128)
    np.testing.assert_allclose(through.gt.points, straight.gt.points, atol=2e-3)
    v = straight.gt.valid
    ratio = through.images[:, v].mean(axis=(1, 2)) / straight.images[:, v].mean(axis=(1, 2))
    np.testing.assert_allclose(ratio, 1.0, atol=0.03)


def test_refracting_gel_bends_the_view_and_dims_the_coat(dome_scene):
    mesh = undeformed_mesh(dome_scene.dome)
    straight = render_surface(dome_scene, mesh, spp=16)
    optics = dome_scene.replace(gel_optics={"enabled": True, "gel_ior": 1.41})
    through = render_surface(optics, mesh, spp=128)
    cam = dome_scene.camera_model()
    # the central pixel's ray meets the concentric interface head-on: it still sees the apex
    centre = np.unravel_index(np.argmin(np.hypot(*(np.stack(cam.pixel_grid()) - [[[cam.cx]], [[cam.cy]]]))), cam.shape)
    np.testing.assert_allclose(through.gt.points[centre], straight.gt.points[centre], atol=0.05)
    # off axis the pixel sees another point of the same dome
    shift = np.linalg.norm(through.gt.points - straight.gt.points, axis=-1)[straight.gt.valid & through.gt.valid]
    assert shift.max() > 0.1
    radius = np.linalg.norm(through.gt.points[through.gt.valid] - np.asarray([0, 0, 3.0]), axis=-1)
    np.testing.assert_allclose(radius, dome_scene.dome.radius, atol=0.02)
    # a diffuse coat under n = 1.41 seen from air: ~ T^2 / n^2 ~ 0.45 of the light (the rest is trapped)
    v = straight.gt.valid & through.gt.valid
    ratio = through.images[:, v].mean() / straight.images[:, v].mean()
    assert 0.35 < ratio < 0.55


def test_default_scene_is_the_papers_sensor_and_ideal_is_the_nlips_model():
    default, ideal = load_scene(), load_scene("nlipstac_ideal")
    # SceneConfig()'s defaults but the design's declared LED size: the disks its [led_package] renders
    assert default == SceneConfig().replace(leds={"emitter_diameter": SceneConfig().led_package.size})
    assert default.led_package.enabled and default.camera_effects.defocus_px > 0
    assert default.camera_effects.black_level_error != 0 and default.coating.specular == 0
    assert ideal.replace(name=default.name) == default.ideal()
    assert not ideal.led_package.enabled and not ideal.camera_effects.enabled
    # ideal() turns off every departure, whatever the scene had on
    stripped = load_scene("nlipstac_realistic").ideal()
    assert not stripped.led_package.enabled and not stripped.camera_effects.enabled
    assert stripped.coating.specular == 0 and not stripped.gel_optics.enabled
    # and its design declares the point LEDs it renders: calibrate-leds fits them as points by default
    assert default.leds.emitter_diameter > 0 and stripped.leds.emitter_diameter == ideal.leds.emitter_diameter == 0


def test_extended_leds_have_little_monte_carlo_noise_at_4_spp():
    """The antithetic pair of area points keeps a 3.6 mm disk's per-pixel noise at 4 spp near 0.5 % rms
    (one point per sample: about 2.7 %, more than the sensor's shot noise)."""
    scene = (
        SceneConfig()
        .ideal()
        .replace(
            camera={"width": 64, "height": 48},
            noise={"enabled": False},
            render={"threads": 2},
            led_package={"enabled": True, "size": 3.6},
        )
    )
    mesh = undeformed_mesh(scene.dome)
    exact = render_surface(scene, mesh, spp=256, seed=1).images[..., 1]
    quick = render_surface(scene, mesh, spp=4, seed=2).images[..., 1]
    lit = exact > 0.05 * exact.max(axis=(1, 2), keepdims=True)
    rel = quick[lit] / exact[lit] - 1
    assert np.sqrt(np.mean(rel**2)) < 0.012
