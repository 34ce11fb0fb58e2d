"""The analytic gel surface of a dome design, in the dome frame (mm): shape rules, ray hits, normals.

Pure numpy, shared by the twin's meshes (sim/dome.py) and everything that needs the undeformed surface
of a design without rendering (device/, the solver's reference).

Shape rules (checked by :func:`check_dome`):

* ``hemisphere``: sphere of ``radius``; ``height`` is ignored.
* ``fingertip``: prolate half-ellipsoid, needs ``height > radius``.
* ``oblate``: flattened half-ellipsoid, needs ``height < radius`` (``height == radius`` is a hemisphere).
* ``capsule``: cylinder of ``radius`` capped by a hemisphere, total height ``height > radius``.
* ``flat``: square pad of half side ``radius`` at ``z = height > 0``, seen from below.
"""

from __future__ import annotations

import numpy as np

from .camera import Camera
from .errors import ConfigError
from .sensor import DomeConfig, SensorDesign
from .surface_files import Reference
from .tolerances import NORMAL_EPS


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


def _direction(polar_deg: float | np.ndarray, azimuth_deg: float | np.ndarray) -> np.ndarray:
    th, ph = np.radians(polar_deg), np.radians(azimuth_deg)
    return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)


def press_angles(point: np.ndarray) -> tuple[float, float]:
    """The press location ``(polar_deg, azimuth_deg)`` of a dome-frame point: the direction from the dome-frame
    origin in which :func:`dome_surface_point` meets it (docs/conventions.md, ``nlips render --polar --azimuth``).

    Parameters
    ----------
    point : (3,) float, mm, dome frame

    Returns
    -------
    polar_deg : float, degrees from +z (0 = apex)
    azimuth_deg : float, degrees from +x toward +y, in [0, 360)
    """
    x, y, z = (float(c) for c in point)
    return float(np.degrees(np.arctan2(np.hypot(x, y), z))), float(np.degrees(np.arctan2(y, x)) % 360.0)


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


def reference_surface(design: SensorDesign, camera: Camera | None = None) -> Reference:
    """The undeformed gel surface of a design as the camera sees it, computed analytically.

    Every pixel's viewing ray (:attr:`Camera.rays`, exact lens model) leaves the camera centre at
    ``design.camera.position`` (dome frame) and is intersected with the analytic surface. The pixel sees
    the gel when the first surface the ray meets is seen from inside (the coated side, as in the twin's
    one-sided mesh); a ray that misses the gel, meets its outside first or leaves through the open base
    gets NaN depth and zero normals.

    Parameters
    ----------
    design : SensorDesign
    camera : core Camera or None
        The camera's calibrated intrinsics and lens (``nlips calibrate-camera``) when they differ from the
        design's; its centre stays at ``design.camera.position``.

    Returns
    -------
    Reference
        ``depth`` (H, W) float32, mm, z in the camera frame (NaN where not seen); ``normals`` (H, W, 3)
        float32, unit, camera frame, toward the camera (zero where not seen).
    """
    cfg = design.dome
    check_dome(cfg)
    camera = design.camera_model() if camera is None else camera
    h, w = camera.shape
    rays = camera.rays.reshape(-1, 3)
    origin = np.asarray(design.camera.position, dtype=float)
    t = _first_hit(cfg, origin, rays)
    with np.errstate(invalid="ignore"):
        points_dome = origin + t[:, None] * rays
    seen = np.isfinite(t)
    normals = np.zeros_like(rays)
    normals[seen] = _inward_normals_at(cfg, points_dome[seen])
    seen &= np.einsum("ij,ij->i", normals, rays) < 0  # coated (inner) side faces the camera
    normals[~seen] = 0.0
    depth = np.where(seen, t * rays[:, 2], np.nan)
    return Reference(depth=depth.reshape(h, w).astype(np.float32), normals=normals.reshape(h, w, 3).astype(np.float32))


def _first_hit(cfg: DomeConfig, origin: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(N,) float: ray parameter (mm, unit rays) of the nearest surface hit in front of ``origin``; inf on miss."""
    if cfg.shape == "flat":
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (cfg.height - origin[2]) / d[:, 2]
            p = origin + t[:, None] * d
        on_pad = (t > 0) & (np.abs(p[:, 0]) <= cfg.radius) & (np.abs(p[:, 1]) <= cfg.radius)
        return np.where(on_pad, t, np.inf)
    if cfg.shape == "capsule":
        zc = cfg.height - cfg.radius
        wall = _quadric_hits(origin, d, np.array([1.0, 1.0, 0.0]), np.zeros(3), cfg.radius**2)
        cap = _quadric_hits(origin, d, np.ones(3), np.array([0.0, 0.0, zc]), cfg.radius**2)
        return np.minimum(_nearest(origin, d, wall, 0.0, zc), _nearest(origin, d, cap, zc, np.inf))
    c = cfg.radius if cfg.shape == "hemisphere" else cfg.height
    scale = 1.0 / np.array([cfg.radius, cfg.radius, c]) ** 2
    roots = _quadric_hits(origin, d, scale, np.zeros(3), 1.0)
    return _nearest(origin, d, roots, 0.0, np.inf)


def _quadric_hits(origin: np.ndarray, d: np.ndarray, scale: np.ndarray, centre: np.ndarray, rhs: float) -> np.ndarray:
    """(N, 2) roots t of sum_k scale_k (o + t d - centre)_k^2 = rhs; NaN where the ray misses."""
    o = origin - centre
    a = (scale * d * d).sum(1)
    b = 2.0 * (scale * o * d).sum(1)
    c = float((scale * o * o).sum()) - rhs
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(disc)
        roots = np.stack([(-b - sq) / (2 * a), (-b + sq) / (2 * a)], 1)
    return roots


def _nearest(origin: np.ndarray, d: np.ndarray, roots: np.ndarray, z_lo: float, z_hi: float) -> np.ndarray:
    """(N,) the smallest root in front of the camera whose point lies in z_lo <= z <= z_hi; inf if none."""
    z = origin[2] + roots * d[:, 2:3]
    ok = (roots > 0) & (z >= z_lo) & (z <= z_hi)
    return np.where(ok, roots, np.inf).min(axis=1)


def _inward_normals_at(cfg: DomeConfig, points: np.ndarray) -> np.ndarray:
    """(N, 3) unit inward normals of the analytic surface at ``points`` (dome frame, on the surface)."""
    if cfg.shape == "flat":
        return np.tile([0.0, 0.0, -1.0], (len(points), 1))
    if cfg.shape == "capsule":
        zc = cfg.height - cfg.radius
        n = -(points - [0.0, 0.0, zc])
        n[points[:, 2] < zc, 2] = 0.0  # cylinder wall
    else:
        c = cfg.radius if cfg.shape == "hemisphere" else cfg.height
        n = -points / np.array([cfg.radius, cfg.radius, c]) ** 2
    return n / np.linalg.norm(n, axis=1, keepdims=True)
