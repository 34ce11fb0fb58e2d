"""The bounce light's Monte Carlo noise filter (sim/render/denoise.py): known answers, and in the renderer."""

import numpy as np
import pytest

from nlipscalib.sim.render.denoise import DenoiseConfig, denoise_indirect

H, W = 40, 50


def _guides(normal_edge_deg: float = 0.0, depth_step: float = 0.0):
    """Flat surface at 15 mm; the right half tilted by ``normal_edge_deg`` and/or moved by ``depth_step`` mm."""
    normals = np.zeros((H, W, 3), np.float32)
    normals[..., 2] = -1.0
    t = np.radians(normal_edge_deg)
    normals[:, W // 2 :] = (np.sin(t), 0.0, -np.cos(t))
    depth = np.full((H, W), 15.0, np.float32)
    depth[:, W // 2 :] += depth_step
    valid = np.ones((H, W), bool)
    valid[:3] = False  # a rim that sees no surface
    return normals, depth, valid


def test_a_constant_field_is_returned_unchanged_and_nothing_outside_the_surface():
    normals, depth, valid = _guides()
    field = np.full((2, H, W, 3), 0.25, np.float32)
    out = denoise_indirect(field, normals, depth, valid)
    np.testing.assert_allclose(out[:, valid], 0.25, rtol=1e-5)
    assert np.all(out[:, ~valid] == 0)


def test_noise_on_a_smooth_field_drops_many_fold_and_its_mean_stays():
    normals, depth, valid = _guides()
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:H, 0:W]
    smooth = (0.2 + 0.05 * np.sin(x / 15.0) * np.cos(y / 12.0)).astype(np.float32)
    clean = np.broadcast_to(smooth[None, ..., None], (3, H, W, 3))
    noisy = clean * (1 + 0.3 * rng.standard_normal(clean.shape)).astype(np.float32)
    out = denoise_indirect(noisy, normals, depth, valid)
    inner = valid.copy()
    inner[:, :8] = inner[:, -8:] = False
    inner[:11] = inner[-8:] = False
    before = np.sqrt(np.mean((noisy - clean)[:, inner] ** 2))
    after = np.sqrt(np.mean((out - clean)[:, inner] ** 2))
    assert after < before / 5
    assert abs(out[:, valid].mean() / noisy[:, valid].mean() - 1) < 0.01


def _dome(pitch_mm: float, radius_mm: float = 12.0):
    """A sphere cap of ``radius_mm`` 15 mm from the camera at its apex, seen square-on with pixels ``pitch_mm``
    apart: its normals turn by ``pitch_mm / radius_mm`` radians a pixel (0.4 mm: 1.9 deg, a 64x48 view)."""
    y, x = (np.mgrid[0:H, 0:W] - np.array([H / 2, W / 2])[:, None, None]) * pitch_mm
    valid = x**2 + y**2 < (0.95 * radius_mm) ** 2  # the corners of the coarse view miss the cap
    h = np.sqrt(np.maximum(radius_mm**2 - x**2 - y**2, 0.0))
    normals = (np.stack([x, y, -h], -1) / radius_mm).astype(np.float32)
    return normals, np.where(valid, 15.0 + radius_mm - h, np.nan).astype(np.float32), valid


@pytest.mark.parametrize("pitch_mm", [0.1, 0.4])
def test_noise_drops_as_much_on_a_curved_dome_seen_coarsely_as_finely(pitch_mm):
    """The filter stopped at normals merely apart: on a dome whose normals turn 1.9 deg a pixel (the default twin
    at 64x48) it cut the noise 4.5-fold, not 12-fold, and the rest, correlated over pixels, read as a press
    (benchmarks/RESULTS.md, s27-noiselow). It now follows the surface's curvature at any pixel pitch."""
    normals, depth, valid = _dome(pitch_mm)
    rng = np.random.default_rng(1)
    y, x = np.mgrid[0:H, 0:W]
    smooth = (0.2 + 0.05 * np.sin(x / 15.0) * np.cos(y / 12.0)).astype(np.float32)
    clean = np.broadcast_to(smooth[None, ..., None], (3, H, W, 3))
    noisy = clean * (1 + 0.3 * rng.standard_normal(clean.shape)).astype(np.float32)
    out = denoise_indirect(noisy, normals, depth, valid)
    inner = np.zeros((H, W), bool)
    inner[8:-8, 8:-8] = True
    inner &= valid
    before = np.sqrt(np.mean((noisy - clean)[:, inner] ** 2))
    after = np.sqrt(np.mean((out - clean)[:, inner] ** 2))
    assert after < before / 10
    assert abs(out[:, valid].mean() / noisy[:, valid].mean() - 1) < 0.01


@pytest.mark.parametrize("edge", [{"normal_edge_deg": 30.0}, {"depth_step": 1.0}])
def test_light_is_not_blurred_across_an_edge_of_the_geometry(edge):
    normals, depth, valid = _guides(**edge)
    field = np.zeros((1, H, W, 3), np.float32)
    field[:, :, : W // 2] = 0.1
    field[:, :, W // 2 :] = 0.3  # a tilted or moved facet receives other light
    out = denoise_indirect(field, normals, depth, valid)
    np.testing.assert_allclose(out[0, 3:, : W // 2], 0.1, rtol=0.02)
    np.testing.assert_allclose(out[0, 3:, W // 2 :], 0.3, rtol=0.02)
    # without the edge in the guides the same step would be smeared over many pixels
    flat = denoise_indirect(field, *_guides())
    assert abs(flat[0, 20, W // 2 - 1, 0] - 0.1) > 0.03


def test_bad_settings_and_guides_are_refused():
    from nlipscalib.core.errors import ConfigError

    with pytest.raises(ConfigError):
        DenoiseConfig(iterations=9)
    with pytest.raises(ConfigError):
        DenoiseConfig(normal_deg=0)
    normals, depth, valid = _guides()
    with pytest.raises(ValueError):
        denoise_indirect(np.zeros((1, H, W + 1, 3)), normals, depth, valid)


def test_the_renderer_splits_the_bounce_light_exactly_and_filters_only_it():
    pytest.importorskip("mitsuba")
    from nlipscalib.sim.press import undeformed_mesh
    from nlipscalib.sim.render import render_surface
    from nlipscalib.sim.scene import SceneConfig

    scene = (
        SceneConfig()
        .ideal()
        .replace(camera={"width": 48, "height": 36}, noise={"enabled": False}, render={"threads": 2, "bounces": 1})
    )
    mesh = undeformed_mesh(scene.dome)
    plain = render_surface(scene.replace(render={"denoise_indirect": False}), mesh, spp=16, seed=3)
    off = scene.replace(render={"denoise": {"iterations": 0}, "denoise_indirect": True})  # split, nothing filtered
    split = render_surface(off, mesh, spp=16, seed=3)
    np.testing.assert_allclose(split.images, plain.images, rtol=1e-5, atol=1e-8)  # the same paths, split
    on = scene.replace(render={"denoise_indirect": True})
    filtered = [render_surface(on, mesh, spp=16, seed=seed) for seed in (3, 4)]
    v = plain.gt.valid
    # the same samples: only the bounce light differs, and its level over the dome is kept (it is a fifth
    # to a third of the image, so 0.5 % of the image is a few % of it) ...
    assert abs(filtered[0].images[:, v].mean() / split.images[:, v].mean() - 1) < 0.005
    # ... and its noise (what two renders with other samples disagree on) is filtered; what is left is
    # mostly the direct light's antialiasing noise at this coarse pixel size, which is never filtered
    raw_noise = np.std((render_surface(off, mesh, spp=16, seed=4).images - split.images)[:, v])
    assert np.std((filtered[1].images - filtered[0].images)[:, v]) < 0.7 * raw_noise


def _outline(radius_px: float = 14.0):
    """A flat disk of surface in the middle of the frame and its coverage of each pixel (the share of a pixel's
    8x8 sub-samples inside the disk): 1 inside, between 0 and 1 on the outline, 0 beyond."""
    normals, depth, _ = _guides()
    sub = (np.arange(8) + 0.5) / 8 - 0.5
    y = np.arange(H)[:, None, None, None] + sub[None, None, :, None] - H / 2
    x = np.arange(W)[None, :, None, None] + sub[None, None, None, :] - W / 2
    coverage = (x**2 + y**2 < radius_px**2).mean(axis=(2, 3)).astype(np.float32)
    centre = np.hypot(np.arange(H)[:, None] - H / 2, np.arange(W)[None, :] - W / 2)
    return normals, depth, centre < radius_px, coverage


def test_at_the_outline_the_light_per_unit_coverage_stays_flat():
    """A partly covered pixel's light is its covered share of the surface's: filtered as a whole pixel it was
    averaged with its neighbours' full light (the wide twin's outer pixel +17 %, those within 1-8 px 0.2-0.9 %
    low; benchmarks/RESULTS.md, s35-wideedge). Per unit coverage the light of a uniform surface is flat."""
    normals, depth, valid, coverage = _outline()
    partial = valid & (coverage < 1)
    assert partial.sum() > 20  # the outline's pixels whose centre sees the surface
    light = np.array([0.2, 0.3], np.float32)[:, None, None, None] * coverage[None, ..., None]
    light = np.broadcast_to(light, (2, H, W, 3))
    out = denoise_indirect(light, normals, depth, valid, coverage=coverage)
    np.testing.assert_allclose(
        out[:, valid] / coverage[valid][None, :, None], light[:, valid] / coverage[valid][None, :, None], rtol=1e-5
    )
    assert np.all(out[:, ~valid] == 0)
    # taken whole, the outer pixels come out far off their share, and the next ones in low
    whole = denoise_indirect(light, normals, depth, valid)
    assert np.max(whole[:, partial] / light[:, partial]) > 1.5
    assert np.min((whole / np.maximum(light, 1e-30))[:, valid & (coverage == 1)]) < 0.99


def test_noise_per_unit_coverage_is_filtered_to_its_mean_at_the_outline():
    """The render's estimate on a partly covered pixel is the mean of its samples on the surface: divided by
    the coverage its noise is the surface's, and the filter's mean there is the light's, not its neighbours'."""
    normals, depth, valid, coverage = _outline()
    rng = np.random.default_rng(2)
    clean = np.full((8, H, W, 3), 0.25, np.float32) * coverage[None, ..., None]
    noisy = clean * (1 + 0.3 * rng.standard_normal(clean.shape)).astype(np.float32)
    out = denoise_indirect(noisy, normals, depth, valid, coverage=coverage)
    ring = valid & (coverage < 1)
    assert abs(out[:, ring].sum() / clean[:, ring].sum() - 1) < 0.02
    assert abs(denoise_indirect(noisy, normals, depth, valid)[:, ring].sum() / clean[:, ring].sum() - 1) > 0.1


def test_whole_coverage_keeps_the_filters_bits_and_inside_the_gel_a_missed_sample_is_no_coverage():
    """A gel-filling view's coverage is 1: its images keep their bits. Inside the gel a pixel's sample can slip
    between the mesh's triangles (single-precision ray tests: 1 to 3 pixels of a 160x120 wide view, 9-50 px from
    its outline, came out 15/16 or 255/256 covered): the render's defect, taken whole as before, not coverage."""
    normals, depth, valid = _guides()
    rng = np.random.default_rng(3)
    light = (0.2 + 0.05 * rng.standard_normal((2, H, W, 3))).astype(np.float32)
    plain = denoise_indirect(light, normals, depth, valid)
    assert np.array_equal(denoise_indirect(light, normals, depth, valid, coverage=np.ones((H, W), np.float32)), plain)
    pinhole = np.where(valid, 1.0, 0.0).astype(np.float32)
    pinhole[20, 25] = 15 / 16
    assert np.array_equal(denoise_indirect(light, normals, depth, valid, coverage=pinhole), plain)
    with pytest.raises(ValueError):
        denoise_indirect(light, normals, depth, valid, coverage=pinhole[:, 1:])


def test_an_outline_pixel_none_of_whose_samples_reached_the_surface_is_left_out():
    """At a low sample count a pixel whose centre sees the surface may have no sample on it (coverage 0): it holds
    no estimate, and must not pull its neighbours toward its 0."""
    normals, depth, valid, coverage = _outline()
    on_outline = np.argwhere(valid & (coverage < 1))[0]
    coverage[tuple(on_outline)] = 0.0
    light = np.full((1, H, W, 3), 0.2, np.float32) * coverage[None, ..., None]
    out = denoise_indirect(light, normals, depth, valid, coverage=coverage)
    assert np.all(out[0, on_outline[0], on_outline[1]] == 0)
    covered = valid & (coverage > 0)
    np.testing.assert_allclose(out[0, covered] / coverage[covered][:, None], 0.2, rtol=1e-5)


def _wide_ideal(width: int, height: int):
    """The exact image model seen past its gel (s33-rimedge's 130 deg view from 8 mm back): the outline in view."""
    from nlipscalib.sim.scene import SceneConfig

    return (
        SceneConfig()
        .ideal()
        .replace(
            camera={"width": width, "height": height, "hfov_deg": 130.0, "position": [0.0, 0.0, -8.0]},
            noise={"enabled": False},
            render={"threads": 2, "bounces": 1},
        )
    )


def test_the_renderer_filters_a_wide_views_bounce_light_per_unit_coverage():
    """In a view past the gel the film's alpha is each pixel's coverage; the filtered bounce light of the
    outer pixels keeps their raw level (it was +17 % of their light at 160x120, s35-wideedge)."""
    pytest.importorskip("mitsuba")
    from scipy import ndimage

    from nlipscalib.sim.press import undeformed_mesh
    from nlipscalib.sim.render import render_surface

    scene = _wide_ideal(64, 48)
    mesh = undeformed_mesh(scene.dome)
    raw = render_surface(
        scene.replace(render={"denoise": {"iterations": 0}}), mesh, spp=64, seed=3
    )  # split, unfiltered
    filtered = render_surface(scene, mesh, spp=64, seed=3)
    v = raw.gt.valid
    outer = v & (ndimage.distance_transform_edt(v) <= 1)
    bounce_gain = (filtered.images - raw.images)[:, outer].sum() / raw.images[:, outer].sum()  # same samples
    assert abs(bounce_gain) < 0.03, bounce_gain
