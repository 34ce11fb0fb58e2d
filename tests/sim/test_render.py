"""Physics, ground truth and camera of the Mitsuba renderer (small images, CPU)."""

import dataclasses

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from nlipscalib.core import led_shading  # noqa: E402
from nlipscalib.sim.press import tricolor_linear, undeformed_mesh  # noqa: E402
from nlipscalib.sim.render import load_mitsuba, render_surface  # noqa: E402
from nlipscalib.sim.render.scene import build_scene, sensor_entry  # noqa: E402
from nlipscalib.sim.render.shapes import plate  # noqa: E402
from nlipscalib.sim.scene import SceneConfig  # noqa: E402

W, H = 80, 60


@pytest.fixture(scope="module")
def scene():
    """The exact NLiPs image model: point LEDs, Lambertian coat, ideal camera (the default scene is not)."""
    return (
        SceneConfig()
        .ideal()
        .replace(
            camera={"width": W, "height": H}, noise={"enabled": False}, render={"spp": 4, "bounces": 0, "threads": 2}
        )
    )


@pytest.fixture(scope="module")
def dome_result(scene):
    return render_surface(scene, undeformed_mesh(scene.dome))


def _model(scene, gt):
    albedo = np.asarray(scene.coating.albedo) / np.pi
    return led_shading(gt.points, gt.normals, scene.led_models()) * albedo


def _check_matches_model(scene, res):
    model = _model(scene, res.gt)
    v = res.gt.valid
    assert v.mean() > 0.5
    for k in range(len(model)):
        lit = v & (model[k, ..., 0] > 1e-3 * model[k, ..., 0][v].max())
        err = np.abs(res.images[k][lit] / model[k][lit] - 1)
        assert np.median(err) < 0.01, (k, np.median(err))


def test_plate_direct_light_matches_image_model(scene):
    res = render_surface(scene, plate(z=10.0, half=60.0))
    assert res.images.shape == (12, H, W, 3) and res.images.dtype == np.float32
    _check_matches_model(scene, res)


def test_dome_direct_light_matches_image_model(scene, dome_result):
    _check_matches_model(scene, dome_result)


def test_gt_normals_agree_with_finite_differences(dome_result):
    gt = dome_result.gt
    p = gt.points.astype(np.float64)
    du = p[1:-1, 2:] - p[1:-1, :-2]
    dv = p[2:, 1:-1] - p[:-2, 1:-1]
    n_fd = np.cross(du, dv)
    n_fd /= np.linalg.norm(n_fd, axis=-1, keepdims=True)
    n = gt.normals[1:-1, 1:-1].astype(np.float64)
    n_fd *= np.sign(np.sum(n_fd * n, axis=-1, keepdims=True))
    ok = np.ones_like(gt.valid)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            ok &= np.roll(gt.valid, (dy, dx), axis=(0, 1))
    ok = ok[1:-1, 1:-1]
    angle = np.degrees(np.arccos(np.clip(np.sum(n_fd * n, axis=-1), -1, 1)))[ok]
    assert np.median(angle) < 1.0
    # toward the camera: n . (-ray) > 0
    assert np.all(np.sum(gt.normals[gt.valid] * gt.points[gt.valid], axis=-1) < 0)


def test_undeformed_dome_has_no_contact_and_finite_gt(dome_result):
    gt = dome_result.gt
    assert not gt.contact.any()
    assert np.all(np.isfinite(gt.depth[gt.valid])) and np.all(np.isnan(gt.depth[~gt.valid]))
    np.testing.assert_allclose(np.linalg.norm(gt.normals[gt.valid], axis=-1), 1, atol=1e-5)
    np.testing.assert_array_equal(gt.depth[gt.valid], gt.points[..., 2][gt.valid])


@pytest.mark.parametrize(
    "model,dist", [("fisheye", (0.05, -0.01, 0.002, 0.0)), ("brown", (-0.2, 0.05, 1e-3, -1e-3, 0))]
)
def test_gt_points_reproject_to_pixel_centres(scene, model, dist):
    s = scene.replace(camera={"model": model, "dist": list(dist), "hfov_deg": 90.0})
    gt = render_surface(s, undeformed_mesh(s.dome), spp=1).gt
    uv = s.camera_model().project(gt.points.astype(np.float64))
    u, v = s.camera_model().pixel_grid()
    err = np.hypot(uv[..., 0] - u, uv[..., 1] - v)[gt.valid]
    assert err.max() < 1e-3


@pytest.mark.parametrize(
    "model,dist", [("fisheye", (0.05, -0.01, 0.002, 0.0)), ("brown", (-0.2, 0.05, 1e-3, -1e-3, 0))]
)
def test_sensor_rays_equal_core_camera_rays(scene, model, dist):
    mi, _ = load_mitsuba("auto", 2)
    cam = scene.replace(camera={"model": model, "dist": list(dist), "hfov_deg": 90.0}).camera_model()
    sensor = mi.load_dict(sensor_entry(cam, 1))
    u, v = cam.pixel_grid()
    pos = mi.Point2f(((u + 0.5) / W).ravel().astype(np.float32), ((v + 0.5) / H).ravel().astype(np.float32))
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
    d = np.array(ray.d).T.reshape(H, W, 3)
    # |difference| of unit vectors ~ angle in radians; times the focal length ~ pixels
    err_px = np.linalg.norm(d - cam.rays, axis=-1) * cam.fx
    assert err_px.max() < 1e-3


def test_tricolor_equals_coloured_render(scene, dome_result):
    """A render with each LED coloured as its group equals the colour-weighted sum of single-LED images."""
    mi, _ = load_mitsuba("auto", 2)
    from nlipscalib.core.leds import TRICOLOR_COLORS, tricolor_groups

    leds = scene.led_models()
    colours = TRICOLOR_COLORS[tricolor_groups(len(leds))]
    coloured = [dataclasses.replace(led, intensity=tuple(c)) for led, c in zip(leds, colours)]
    mesh = undeformed_mesh(scene.dome)
    verts = np.asarray(mesh.vertices) - np.asarray(scene.camera.position)
    sc = build_scene(
        mi,
        scene.camera_model(),
        coloured,
        verts,
        mesh.faces,
        mesh.vertex_normals,
        np.zeros(len(verts)),
        albedo=scene.coating.albedo,
        spp=4,
    )
    direct = np.array(mi.render(sc, spp=4, seed=scene.render.seed))[..., :3]
    tri = tricolor_linear(dome_result.images)
    v = dome_result.gt.valid
    np.testing.assert_allclose(direct[v], tri[v], rtol=1e-4, atol=1e-7)


def test_multi_led_integrator_matches_mitsuba_path_with_one_bounce(scene):
    mesh = undeformed_mesh(scene.dome)
    raw = scene.replace(render={"denoise_indirect": False})  # the integrator itself, as the path tracer
    ours = render_surface(raw, mesh, spp=64, bounces=1).images[3]
    path = render_surface(scene, mesh, spp=64, bounces=1, integrator="path", only_led=3).images[0]
    direct = render_surface(scene, mesh, spp=4, bounces=0).images[3]
    assert abs(ours.mean() / path.mean() - 1) < 0.01
    # 10x10-pixel blocks average the interreflection noise away
    blocks = lambda im: im[..., 1].reshape(H // 10, 10, W // 10, 10).mean(axis=(1, 3))  # noqa: E731
    assert np.median(np.abs(blocks(ours) / blocks(path) - 1)) < 0.03
    assert 1.05 < ours.mean() / direct.mean() < 1.4  # interreflection brightens the dome


def test_albedo_variation_modulates_images(scene, dome_result):
    varied = render_surface(scene.replace(coating={"variation": 0.2}), undeformed_mesh(scene.dome)).images
    v = dome_result.gt.valid
    ratio = varied[:, v] / np.maximum(dome_result.images[:, v], 1e-12)
    assert 0.03 < ratio.std() < 0.3 and abs(np.median(ratio) - 1) < 0.1


def test_a_ray_that_slips_between_triangles_is_traced_again():
    """One pixel inside a 160x120 sphere dent missed the mesh (a ray through a shared vertex): a hole in the
    ground truth. A miss whose four neighbours hit is traced again, slightly turned; a miss at the view's
    edge (off the gel) stays one."""
    from nlipscalib.sim.render.groundtruth import _retrace_pinholes

    h, w = 4, 5
    rays = np.tile(np.array([0, 0, 1], np.float32), (h * w, 1))
    valid = np.ones(h * w, bool)
    valid[[7, 0]] = False  # (1, 2) inside, (0, 0) at the edge
    points = np.zeros((h * w, 3), np.float32)
    normals, contact = points.copy(), np.zeros(h * w, bool)
    calls = []

    def trace(r):
        calls.append(len(r))
        n = len(r)
        return np.ones(n, bool), np.full((n, 3), 7, np.float32), np.full((n, 3), 0.5, np.float32), np.ones(n, bool)

    _retrace_pinholes(trace, rays, valid.reshape(h, w), (valid, points, normals, contact))
    assert calls == [1] and valid[7] and not valid[0]
    assert (points[7] == 7).all() and contact[7] and not contact[0]


def test_the_coverage_is_whole_on_a_gel_filling_view_and_partial_only_on_a_wide_views_outline(scene, dome_result):
    """The film's alpha is each pixel's coverage by the gel (the bounce light is filtered per unit of it): 1 on
    every pixel of a gel-filling view, so its images keep their bits; through a refracting gel too, where some
    paths are lost at the interface (the share reaching the coat: 0.94-1 here, 0.71 on average on
    nlipstac_realistic at 160x120). Past the gel: partial only on the outline, 0 beyond."""
    from scipy import ndimage

    assert np.all(dome_result.coverage == 1)
    refracting = scene.replace(
        gel_optics={"enabled": True}, led_package={"enabled": True}, camera={"width": 32, "height": 24}
    )
    res = render_surface(refracting, undeformed_mesh(scene.dome), spp=16, bounces=0)
    assert res.gt.valid.all() and np.all(res.coverage == 1)
    wide = scene.replace(camera={"hfov_deg": 130.0, "position": [0.0, 0.0, -8.0]})
    res = render_surface(wide, undeformed_mesh(scene.dome), spp=16, bounces=0)
    v, cov = res.gt.valid, res.coverage
    partial = (cov > 0) & (cov < 1)
    near_outline = ndimage.binary_dilation(v) & ~ndimage.binary_erosion(v)
    assert partial.sum() > 50 and np.all(near_outline[partial])
    assert np.all(cov[~ndimage.binary_dilation(v)] == 0) and np.all(cov[ndimage.binary_erosion(v)] == 1)
    # where a pixel is covered its direct light is its covered share: the covered samples' light
    lit = res.images[:, partial, 1].sum(0)
    assert np.all(lit > 0)
