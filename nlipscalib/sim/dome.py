"""Gel dome meshes and the analytic surface they sample, in the dome frame (mm).

Every dome except ``flat`` is a surface of revolution about +z, meshed as rings of nearly
equilateral triangles at equal arc-length steps along the meridian, so vertices lie exactly on the
analytic surface and the open base rim lies exactly at z = 0. Faces are wound so that their normals
point **inward** (toward the axis and the camera): Mitsuba's ``diffuse`` BSDF is one-sided and the
camera sees the coated surface from inside.

Shape rules (checked by :func:`check_dome`):

* ``hemisphere``: sphere of ``radius``; ``height`` is ignored.
* ``fingertip``: prolate half-ellipsoid, needs ``height > radius``.
* ``oblate``: flattened half-ellipsoid, needs ``height < radius`` (``height == radius`` is a hemisphere).
* ``capsule``: cylinder of ``radius`` capped by a hemisphere, total height ``height > radius``.
* ``flat``: square pad of half side ``radius`` at ``z = height > 0``, seen from below.
"""

from __future__ import annotations

import functools

import numpy as np
import trimesh

from ..core.tolerances import NORMAL_EPS
from ..errors import ConfigError
from .scene import DomeConfig

_MERIDIAN_SAMPLES = 4096  # dense polyline for arc-length parametrisation; chord error ~1e-7 mm


def check_dome(cfg: DomeConfig) -> None:
    """Raise :class:`ConfigError` when ``cfg`` describes no buildable dome."""
    for name in ("radius", "thickness", "edge_length", "contact_edge_length"):
        if not getattr(cfg, name) > 0:
            raise ConfigError(f"dome.{name} must be > 0, got {getattr(cfg, name)}")
    if cfg.shape != "hemisphere" and not cfg.height > 0:
        raise ConfigError(f"dome.height must be > 0, got {cfg.height}")
    if cfg.shape == "fingertip" and not cfg.height > cfg.radius:
        raise ConfigError(f"fingertip dome needs height > radius (got {cfg.height} <= {cfg.radius}); use oblate")
    if cfg.shape == "oblate" and not cfg.height < cfg.radius:
        raise ConfigError(f"oblate dome needs height < radius (got {cfg.height} >= {cfg.radius}); use fingertip")
    if cfg.shape == "capsule" and not cfg.height > cfg.radius:
        raise ConfigError(f"capsule dome needs height > radius (got {cfg.height} <= {cfg.radius})")
    if cfg.edge_length > cfg.radius / 3:
        raise ConfigError(f"dome.edge_length {cfg.edge_length} is too coarse for radius {cfg.radius}")
    if cfg.contact_edge_length > cfg.edge_length:
        raise ConfigError("dome.contact_edge_length must be <= dome.edge_length")
    if cfg.shape != "flat" and cfg.thickness >= min(cfg.radius, _apex_height(cfg)):
        raise ConfigError(f"dome.thickness {cfg.thickness} must be smaller than the dome's radius and height")


def _apex_height(cfg: DomeConfig) -> float:
    return cfg.radius if cfg.shape == "hemisphere" else cfg.height


def make_dome(cfg: DomeConfig) -> trimesh.Trimesh:
    """Triangle mesh of the gel's coated surface, open at the base.

    Parameters
    ----------
    cfg : DomeConfig

    Returns
    -------
    trimesh.Trimesh
        Dome frame, mm; face normals point inward (toward the camera). A fresh copy each call.
    """
    return _make_dome_cached(cfg).copy()


@functools.lru_cache(maxsize=16)
def _make_dome_cached(cfg: DomeConfig) -> trimesh.Trimesh:
    check_dome(cfg)
    if cfg.shape == "flat":
        vertices, faces = _flat_pad(cfg)
    else:
        vertices, faces = _revolution_mesh(_meridian(cfg), cfg.edge_length)
        vertices = project_to_dome(cfg, vertices)
    return _orient_inward(cfg, vertices, faces)


def _meridian(cfg: DomeConfig) -> np.ndarray:
    """(K, 2) float, mm: dense (r, z) polyline from the apex down to the base rim."""
    t = np.linspace(0.0, np.pi / 2, _MERIDIAN_SAMPLES)
    a = cfg.radius
    if cfg.shape == "hemisphere":
        return np.stack([a * np.sin(t), a * np.cos(t)], 1)
    if cfg.shape in ("fingertip", "oblate"):
        return np.stack([a * np.sin(t), cfg.height * np.cos(t)], 1)
    # capsule: quarter circle of the cap, then the straight cylinder wall down to z = 0
    zc = cfg.height - a
    cap = np.stack([a * np.sin(t), zc + a * np.cos(t)], 1)
    wall = np.stack([np.full(_MERIDIAN_SAMPLES, a), np.linspace(zc, 0.0, _MERIDIAN_SAMPLES)], 1)
    return np.concatenate([cap, wall[1:]])


def _revolution_mesh(meridian: np.ndarray, edge: float) -> tuple[np.ndarray, np.ndarray]:
    """Rings at equal arc length along ``meridian``, zipped into triangle strips."""
    seg = np.linalg.norm(np.diff(meridian, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n_rings = max(2, int(np.ceil(s[-1] / (edge * np.sqrt(3) / 2))))
    s_ring = np.linspace(0.0, s[-1], n_rings + 1)
    r = np.interp(s_ring, s, meridian[:, 0])
    z = np.interp(s_ring, s, meridian[:, 1])
    counts = np.maximum(6, np.round(2 * np.pi * r / edge).astype(int))
    counts[0] = 1  # the apex
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    verts, fracs = [], []
    for k, (rk, zk, n) in enumerate(zip(r, z, counts)):
        # stagger successive rings by an irrational fraction of a step: strips stay close to
        # equilateral and no two edge midpoints of neighbouring rings tie in _zip_rings
        f = (np.arange(n) + (k * 0.6180339887) % 1.0) / n
        fracs.append(f)
        ang = 2 * np.pi * f
        verts.append(np.stack([rk * np.cos(ang), rk * np.sin(ang), np.full(n, zk)], 1))
    faces = [_zip_rings(fracs[k], fracs[k + 1], starts[k], starts[k + 1]) for k in range(n_rings)]
    return np.concatenate(verts), np.concatenate(faces)


def _zip_rings(fa: np.ndarray, fb: np.ndarray, oa: int, ob: int) -> np.ndarray:
    """Triangles between two closed rings given their vertices' angular fractions in [0, 1).

    Each edge of one ring is joined to the vertex of the other ring nearest (in angle) to the
    edge's midpoint; this tiles the band exactly once.
    """
    na, nb = len(fa), len(fb)

    def nearest(frac, ring):
        d = np.abs((frac[:, None] - ring[None, :] + 0.5) % 1.0 - 0.5)
        return np.argmin(d, axis=1)

    ia = np.arange(na)
    ib = np.arange(nb)
    mid_a = fa + 0.5 / na
    mid_b = fb + 0.5 / nb
    tri_a = np.stack([oa + ia, oa + (ia + 1) % na, ob + nearest(mid_a, fb)], 1)
    tri_b = np.stack([ob + ib, ob + (ib + 1) % nb, oa + nearest(mid_b, fa)], 1)
    tris = np.concatenate([tri_a, tri_b])
    keep = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
    return tris[keep]


def _flat_pad(cfg: DomeConfig) -> tuple[np.ndarray, np.ndarray]:
    n = max(2, int(np.ceil(2 * cfg.radius / cfg.edge_length)))
    g = np.linspace(-cfg.radius, cfg.radius, n + 1)
    x, y = np.meshgrid(g, g, indexing="ij")
    # The camera sits on the axis, so grid and diagonal edges through the axis lie exactly in planes
    # of pixel-centre rays (u - cx = v - cy): such rays graze the shared edge and miss both triangles.
    # A tiny in-plane jitter of the interior vertices (pad stays flat) breaks that degeneracy.
    interior = (np.abs(x) < cfg.radius) & (np.abs(y) < cfg.radius)
    jitter = np.random.default_rng(0).uniform(-0.02, 0.02, size=(2,) + x.shape) * (g[1] - g[0])
    x, y = x + jitter[0] * interior, y + jitter[1] * interior
    vertices = np.stack([x.ravel(), y.ravel(), np.full(x.size, cfg.height)], 1)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    v00 = (i * (n + 1) + j).ravel()
    v10, v01, v11 = v00 + n + 1, v00 + 1, v00 + n + 2
    # alternate the diagonal so the pad has no preferred direction
    flip = ((i + j) % 2 == 1).ravel()
    t1 = np.where(flip[:, None], np.stack([v00, v10, v01], 1), np.stack([v00, v10, v11], 1))
    t2 = np.where(flip[:, None], np.stack([v10, v11, v01], 1), np.stack([v00, v11, v01], 1))
    return vertices, np.concatenate([t1, t2])


def _orient_inward(cfg: DomeConfig, vertices: np.ndarray, faces: np.ndarray) -> trimesh.Trimesh:
    """Flip every face whose geometric normal disagrees with the analytic inward normal."""
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    inward = dome_inward_normals(cfg, tri.mean(axis=1))
    flip = np.einsum("ij,ij->i", normal, inward) < 0
    faces = faces.copy()
    faces[flip] = faces[flip][:, ::-1]
    return trimesh.Trimesh(vertices, faces, process=False)


def _ray_hit(cfg: DomeConfig, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where rays from the dome-frame origin meet the surface, and the inward normal there.

    Parameters
    ----------
    directions : (N, 3) float, unit, dome frame

    Returns
    -------
    points : (N, 3) float, mm, dome frame
    normals : (N, 3) float, unit, inward, dome frame
    """
    d = np.asarray(directions, dtype=float)
    a = cfg.radius
    if cfg.shape == "flat":
        with np.errstate(divide="ignore"):
            t = np.where(d[:, 2] > NORMAL_EPS, cfg.height / d[:, 2], np.inf)
        normals = np.tile([0.0, 0.0, -1.0], (len(d), 1))
        return t[:, None] * d, normals
    if cfg.shape == "capsule":
        return _capsule_hit(cfg, d)
    c = a if cfg.shape == "hemisphere" else cfg.height
    t = 1.0 / np.sqrt((d[:, 0] ** 2 + d[:, 1] ** 2) / a**2 + d[:, 2] ** 2 / c**2)
    p = t[:, None] * d
    n = -p / np.array([a**2, a**2, c**2])
    return p, n / np.linalg.norm(n, axis=1, keepdims=True)


def _capsule_hit(cfg: DomeConfig, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, zc = cfg.radius, cfg.height - cfg.radius
    rho = np.hypot(d[:, 0], d[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        t_wall = np.where(rho > NORMAL_EPS, a / rho, np.inf)
    on_wall = t_wall * d[:, 2] <= zc
    # far root of |t d - c|^2 = a^2 with c = (0, 0, zc)
    b = d[:, 2] * zc
    t_cap = b + np.sqrt(np.maximum(b**2 - zc**2 + a**2, 0.0))
    t = np.where(on_wall, t_wall, t_cap)
    p = t[:, None] * d
    n_cap = -(p - [0.0, 0.0, zc]) / a
    with np.errstate(invalid="ignore"):
        n_wall = -np.stack([d[:, 0] / rho, d[:, 1] / rho, np.zeros(len(d))], 1)
    return p, np.where(on_wall[:, None], n_wall, n_cap)


def _direction(polar_deg, azimuth_deg) -> np.ndarray:
    th, ph = np.radians(polar_deg), np.radians(azimuth_deg)
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)


def dome_surface_point(cfg: DomeConfig, polar_deg: float, azimuth_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Point of the surface seen from the dome-frame origin in a given direction.

    Parameters
    ----------
    cfg : DomeConfig
    polar_deg : float, degrees
        Angle of the ray from +z (0 = apex).
    azimuth_deg : float, degrees
        Angle of the ray from +x toward +y.

    Returns
    -------
    point : (3,) float, mm, dome frame
    inward_normal : (3,) float, unit, dome frame, pointing toward the camera

    Raises
    ------
    ConfigError
        When the ray leaves the dome through its open base or misses the flat pad.
    """
    check_dome(cfg)
    d = _direction(float(polar_deg), float(azimuth_deg))[None]
    if cfg.shape != "flat" and not 0 <= polar_deg < 90:
        raise ConfigError(f"polar angle {polar_deg} deg is off the dome (it must be in [0, 90) deg)")
    p, n = _ray_hit(cfg, d)
    if not np.all(np.isfinite(p)) or (cfg.shape == "flat" and np.max(np.abs(p[0, :2])) > cfg.radius):
        raise ConfigError(f"polar angle {polar_deg} deg at azimuth {azimuth_deg} deg misses the flat pad")
    return p[0], n[0]


def project_to_dome(cfg: DomeConfig, points: np.ndarray) -> np.ndarray:
    """Move points along their ray from the dome-frame origin onto the surface.

    Parameters
    ----------
    points : (N, 3) float, mm, dome frame (not at the origin)

    Returns
    -------
    (N, 3) float, mm, dome frame, on the analytic surface
    """
    points = np.asarray(points, dtype=float)
    if cfg.shape == "flat":
        out = points.copy()
        out[:, 2] = cfg.height
        return out
    d = points / np.linalg.norm(points, axis=1, keepdims=True)
    return _ray_hit(cfg, d)[0]


def dome_inward_normals(cfg: DomeConfig, points: np.ndarray) -> np.ndarray:
    """Exact inward normals of the analytic surface at (or radially nearest to) ``points``.

    Parameters
    ----------
    points : (N, 3) float, mm, dome frame

    Returns
    -------
    (N, 3) float, unit, dome frame, pointing toward the camera
    """
    points = np.asarray(points, dtype=float)
    if cfg.shape == "flat":
        return np.tile([0.0, 0.0, -1.0], (len(points), 1))
    d = points / np.linalg.norm(points, axis=1, keepdims=True)
    return _ray_hit(cfg, d)[1]
