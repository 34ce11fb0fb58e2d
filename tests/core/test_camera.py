import math

import numpy as np
import pytest

from nlipscalib.core.camera import Camera, pixel_derivatives
from nlipscalib.core.errors import ConfigError, ShapeError

cv2 = pytest.importorskip("cv2")


def _K(cam):
    return np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1.0]])


def _points(n=200, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p[:, 2] = np.abs(p[:, 2]) + 0.6  # in front of the camera, up to ~60 deg off axis
    return p * rng.uniform(5, 30, size=(n, 1))


def test_fisheye_projection_matches_opencv():
    cam = Camera.from_fov(640, 480, 100.0, "fisheye", (0.05, -0.01, 0.002, 0.0))
    p = _points()
    ours = cam.project(p)
    ref, _ = cv2.fisheye.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), _K(cam), np.array(cam.dist))
    np.testing.assert_allclose(ours, ref.reshape(-1, 2), atol=1e-6)


def test_brown_projection_matches_opencv():
    cam = Camera(640, 480, 300.0, 302.0, 321.0, 238.0, "brown", (-0.2, 0.05, 0.001, -0.002, -0.005))
    p = _points()
    ours = cam.project(p)
    ref, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), _K(cam), np.array(cam.dist))
    np.testing.assert_allclose(ours, ref.reshape(-1, 2), atol=1e-6)


@pytest.mark.parametrize("model,dist", [("fisheye", (0.05, -0.01, 0.0, 0.0)), ("brown", (-0.1, 0.01, 0.0, 0.0, 0.0))])
def test_unproject_inverts_project(model, dist):
    cam = Camera.from_fov(160, 120, 90.0, model, dist)
    rays = cam.rays
    assert rays.shape == (120, 160, 3)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-12)
    u, v = cam.pixel_grid()
    np.testing.assert_allclose(cam.project(rays * 7.0), np.stack([u, v], -1), atol=1e-6)


LENSES = [("fisheye", (0.05, -0.01, 0.0, 0.0)), ("brown", (-0.3, 0.1, 0.001, -0.001, -0.01))]


@pytest.mark.parametrize("model,dist", LENSES)
def test_lens_inversion_stops_when_converged_at_the_fixed_iterations_answer(model, dist, monkeypatch):
    """The Newton loops stop once their steps are ulp-sized: the rays are those of all 30 iterations."""
    from nlipscalib.core import camera as camera_module

    cam = Camera.from_fov(320, 240, 100.0, model, dist)
    u, v = cam.pixel_grid()
    uv = np.stack([u, v], -1)
    early = cam.unproject(uv)
    monkeypatch.setattr(camera_module, "_NEWTON_STEP_TOL", -1.0)  # never converged: every iteration runs
    np.testing.assert_allclose(early, cam.unproject(uv), rtol=0, atol=1e-15)


def test_from_fov_gives_requested_field_of_view():
    cam = Camera.from_fov(640, 480, 100.0, "fisheye", (0.05, -0.01, 0.0, 0.0))
    left, right = cam.unproject(np.array([[-0.5, cam.cy], [639.5, cam.cy]]))
    angle = math.degrees(math.acos(np.clip(left @ right, -1, 1)))
    assert angle == pytest.approx(100.0, abs=0.01)


def test_scaled_camera_keeps_rays_of_the_same_scene_points():
    cam = Camera.from_fov(160, 120, 100.0)
    half = cam.scaled(0.5)
    assert half.shape == (60, 80)
    # the centre of a 2x2 block in the full image is the centre of one pixel in the half image
    full_uv = np.array([[0.5, 0.5], [10.5, 20.5]])
    half_uv = (full_uv + 0.5) * 0.5 - 0.5
    np.testing.assert_allclose(cam.unproject(full_uv), half.unproject(half_uv), atol=1e-9)


def test_bad_camera_configs_name_the_problem():
    with pytest.raises(ConfigError, match="model"):
        Camera(64, 48, 50, 50, 32, 24, "pinhole")
    with pytest.raises(ConfigError, match="coefficients"):
        Camera(64, 48, 50, 50, 32, 24, "fisheye", (0.1,))
    with pytest.raises(ConfigError, match="unknown keys"):
        Camera.from_dict({"width": 64, "height": 48, "fx": 1, "fy": 1, "cx": 0, "cy": 0, "fov": 3})
    with pytest.raises(ShapeError, match=r"\(\.\.\., 3\)"):
        Camera.from_fov(64, 48).project(np.zeros((4, 2)))


def test_depth_to_points_rejects_a_depth_that_does_not_match_the_rays():
    """A (H, 1) or (1, W) depth broadcast silently against (H, W, 3) rays into a wrong point cloud."""
    from nlipscalib.core.camera import depth_to_points

    rays = Camera.from_fov(8, 6).rays
    np.testing.assert_allclose(depth_to_points(np.full((6, 8), 10.0), rays)[..., 2], 10.0)
    for depth in (np.full((6, 1), 10.0), np.full((8, 6), 10.0), np.float64(10.0)):
        with pytest.raises(ShapeError, match="depth must be"):
            depth_to_points(depth, rays)
    with pytest.raises(ShapeError, match="rays"):
        depth_to_points(np.full((6, 8), 10.0), rays[..., :2])


def test_pixel_derivatives_exact_on_a_quadratic_table_border_included():
    # second-order stencils, one-sided at the border: exact for a quadratic in u and v everywhere
    v, u = np.mgrid[0:7, 0:9].astype(float)
    table = np.stack([u**2 + 3 * u * v, v**2 - u, 2 * v], axis=-1)
    d_u, d_v = pixel_derivatives(table)
    np.testing.assert_allclose(d_u, np.stack([2 * u + 3 * v, -np.ones_like(u), 0 * u], -1), atol=1e-12)
    np.testing.assert_allclose(d_v, np.stack([3 * u, 2 * v, 2 + 0 * u], -1), atol=1e-12)


def test_pixel_derivatives_refuses_a_table_too_small_for_the_stencil():
    with pytest.raises(ShapeError, match="3 x 3"):
        pixel_derivatives(np.zeros((2, 5, 3)))


def test_a_camera_without_dist_has_an_undistorted_lens_of_either_model():
    """docs/formats.md: meta.json's `dist` defaults to zeros; a `brown` camera without it was refused ("needs 5
    coefficients, got 4": the fisheye's four zeros were the default for both models)."""
    keys = {"width": 64, "height": 48, "fx": 50.0, "fy": 50.0, "cx": 31.5, "cy": 23.5}
    assert Camera.from_dict(keys | {"model": "brown"}).dist == (0.0,) * 5
    assert Camera.from_dict(keys).dist == (0.0,) * 4
    brown, fisheye = Camera(**keys, model="brown"), Camera(**keys)
    np.testing.assert_allclose(brown.project(brown.rays), fisheye.project(fisheye.rays), atol=1e-9)
    with pytest.raises(ConfigError, match="coefficients"):
        Camera(**keys, model="brown", dist=(0.0,) * 4)  # an explicit list is still checked against the model
