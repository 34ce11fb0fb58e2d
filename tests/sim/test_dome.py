"""Dome meshes lie on their analytic surfaces and face the camera."""

import numpy as np
import pytest

from nlipscalib.core.errors import ConfigError
from nlipscalib.sim.dome import dome_inward_normals, dome_surface_point, make_dome
from nlipscalib.sim.scene import DomeConfig, load_scene

SHAPES = ["nlipstac", "fingertip", "oblate", "capsule", "flat"]


@pytest.fixture(scope="module", params=SHAPES)
def dome(request):
    cfg = load_scene(request.param).dome
    return cfg, make_dome(cfg)


def _implicit(cfg, p):
    """Signed residual of the analytic surface equation (0 on the surface)."""
    a = cfg.radius
    if cfg.shape == "hemisphere":
        return np.linalg.norm(p, axis=1) - a
    if cfg.shape in ("fingertip", "oblate"):
        return np.sqrt((p[:, 0] ** 2 + p[:, 1] ** 2) / a**2 + p[:, 2] ** 2 / cfg.height**2) - 1
    if cfg.shape == "capsule":
        zc = cfg.height - a
        wall = np.hypot(p[:, 0], p[:, 1]) - a
        cap = np.linalg.norm(p - [0, 0, zc], axis=1) - a
        return np.where(p[:, 2] <= zc, wall, cap)
    return p[:, 2] - cfg.height


def test_vertices_on_analytic_surface_and_extents(dome):
    cfg, mesh = dome
    assert np.abs(_implicit(cfg, mesh.vertices)).max() < 1e-6
    top = cfg.radius if cfg.shape == "hemisphere" else cfg.height
    assert mesh.bounds[1, 2] == pytest.approx(top, abs=1e-6)
    assert mesh.bounds[1, 0] == pytest.approx(cfg.radius, rel=1e-3)
    if cfg.shape != "flat":
        assert mesh.bounds[0, 2] == pytest.approx(0.0, abs=1e-9)  # open at the base


def test_faces_wound_inward_and_sized(dome):
    cfg, mesh = dome
    inward = dome_inward_normals(cfg, mesh.triangles_center)
    assert np.all(np.einsum("ij,ij->i", mesh.face_normals, inward) > 0.9)
    assert mesh.is_winding_consistent and mesh.euler_number == 1  # one open disc
    assert np.median(mesh.edges_unique_length) == pytest.approx(cfg.edge_length, rel=0.2)


def test_hemisphere_faces_point_at_the_centre():
    mesh = make_dome(DomeConfig())
    to_axis = -mesh.triangles_center  # toward the base centre, where the camera looks from
    assert np.all(np.einsum("ij,ij->i", mesh.face_normals, to_axis) > 0)


@pytest.mark.parametrize("name", SHAPES)
def test_surface_point_is_on_the_mesh(name):
    cfg = load_scene(name).dome
    mesh = make_dome(cfg)
    for polar, az in [(0, 0), (25, 40), (50, 200)]:
        p, n = dome_surface_point(cfg, polar, az)
        closest, dist, _ = mesh.nearest.on_surface(p[None])
        assert dist[0] < 0.01
        assert np.linalg.norm(n) == pytest.approx(1.0)
        assert n @ (np.array([0, 0, -3.0]) - p) > 0  # faces the camera


def test_surface_point_hemisphere_exact():
    p, n = dome_surface_point(DomeConfig(radius=15), 90 - 30, 90)
    np.testing.assert_allclose(p, [0, 15 * np.cos(np.radians(30)), 7.5], atol=1e-12)
    np.testing.assert_allclose(n, -p / 15, atol=1e-12)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(shape="fingertip", radius=12, height=10), "height > radius"),
        (dict(shape="oblate", radius=10, height=12), "height < radius"),
        (dict(shape="capsule", radius=10, height=8), "height > radius"),
        (dict(radius=-1), "radius"),
        (dict(thickness=0), "thickness"),
        (dict(contact_edge_length=1.0), "contact_edge_length"),
    ],
)
def test_bad_domes_raise(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        make_dome(DomeConfig(**kwargs))


def test_press_points_off_the_dome_raise():
    with pytest.raises(ConfigError, match="off the dome"):
        dome_surface_point(DomeConfig(), 95, 0)
    with pytest.raises(ConfigError, match="misses the flat pad"):
        dome_surface_point(load_scene("flat").dome, 60, 0)
