"""Wide-angle camera model: intrinsics, lens distortion, projection and per-pixel viewing rays.

Conventions (docs/conventions.md): camera frame is OpenCV's (x right, y down, z forward, mm);
pixel coordinates (u, v) = (column, row) with pixel centres at integers, so pixel [row, col]
of an (H, W) array sits at u = col, v = row.

Two lens models are supported, both with OpenCV's coefficient order so that calibrations made
with ``cv2.fisheye.calibrate`` or ``cv2.calibrateCamera`` drop straight in:

- ``"fisheye"`` (Kannala-Brandt, ``cv2.fisheye``): theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8)
- ``"brown"`` (Brown-Conrady, ``cv2.projectPoints``): coefficients (k1, k2, p1, p2, k3)

Projection and unprojection are written in numpy rather than calling OpenCV so that the core stays
light (the solver needs rays, not OpenCV); tests check both against OpenCV to 1e-6 px.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from functools import cached_property

import numpy as np

from .errors import ConfigError, ShapeError
from .tolerances import MAX_IMAGE_PIXELS

LENS_MODELS = ("fisheye", "brown")
_N_COEFFS = {"fisheye": 4, "brown": 5}
_NEWTON_ITERS = 30
"""Most Newton iterations of the lens inversions; they stop once no pixel's step exceeds _NEWTON_STEP_TOL
(4-5 iterations for the default fisheye, converged to the last bit: later steps are ulp-sized)."""
_NEWTON_STEP_TOL = 1e-15
"""Largest step, relative to the largest unknown (radians or normalised coordinates), that ends a Newton loop."""


def _converged(steps: Sequence[np.ndarray], values: Sequence[np.ndarray]) -> bool:
    """No step of ``steps`` exceeds _NEWTON_STEP_TOL times the largest of ``values`` (and 1)."""
    size = max(1.0, max(float(np.max(np.abs(v), initial=0.0)) for v in values))
    return all(float(np.max(np.abs(d), initial=0.0)) <= _NEWTON_STEP_TOL * size for d in steps)


@dataclasses.dataclass(frozen=True)
class Camera:
    """Intrinsics and lens distortion of the sensor camera."""

    width: int
    """Image width in pixels."""
    height: int
    """Image height in pixels."""
    fx: float
    """Focal length along u, pixels."""
    fy: float
    """Focal length along v, pixels."""
    cx: float
    """Principal point u, pixels (pixel centres at integers)."""
    cy: float
    """Principal point v, pixels."""
    model: str = "fisheye"
    """Lens model: ``"fisheye"`` (Kannala-Brandt, 4 coefficients) or ``"brown"`` (5 coefficients)."""
    dist: tuple[float, ...] | None = None
    """Distortion coefficients in OpenCV order for ``model``; None (the default): zeros, as many as ``model``
    takes (docs/formats.md: a meta.json without ``dist`` has an undistorted lens of either model)."""

    def __post_init__(self):
        if self.model not in LENS_MODELS:
            raise ConfigError(f"camera.model must be one of {LENS_MODELS}, got {self.model!r}")
        if self.dist is None:
            object.__setattr__(self, "dist", (0.0,) * _N_COEFFS[self.model])
        self._check_types()
        object.__setattr__(self, "dist", tuple(float(c) for c in self.dist))
        if len(self.dist) != _N_COEFFS[self.model]:
            raise ConfigError(
                f"camera.dist for model {self.model!r} needs {_N_COEFFS[self.model]} coefficients, got {len(self.dist)}"
            )
        if self.width < 2 or self.height < 2:
            raise ConfigError(f"camera size must be at least 2x2, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise ConfigError(f"camera focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    def _check_types(self) -> None:
        """ConfigError naming the key whose value is of the wrong type (a hand-edited meta.json or model file),
        before a comparison fails with Python's "'<' not supported between instances of 'str' and 'int'"."""
        from .config import is_finite_number, is_number, is_whole_number

        for key in ("width", "height"):
            if not is_whole_number(getattr(self, key)):
                raise ConfigError(f"camera.{key} must be a whole number of pixels, got {getattr(self, key)!r}")
        for key in ("fx", "fy", "cx", "cy"):
            if not is_finite_number(getattr(self, key)):
                raise ConfigError(f"camera.{key} must be a finite number of pixels, got {getattr(self, key)!r}")
        if not isinstance(self.dist, (list, tuple)) or not all(is_number(c) for c in self.dist):
            raise ConfigError(f"camera.dist must be a list of numbers, got {self.dist!r}")

    # ------------------------------------------------------------------ construction / io
    @classmethod
    def from_fov(
        cls,
        width: int = 640,
        height: int = 480,
        hfov_deg: float = 100.0,
        model: str = "fisheye",
        dist: tuple[float, ...] | None = None,
    ) -> Camera:
        """Camera whose horizontal field of view is ``hfov_deg`` edge to edge, centred principal point.

        The focal length is chosen so that the ray at the left/right image border makes an angle of
        hfov/2 with the optical axis *after* distortion, so the field of view is what you asked for.
        """
        if not 1.0 < hfov_deg < 179.0:
            raise ConfigError(f"camera.hfov_deg must be in (1, 179), got {hfov_deg}")
        dist = tuple(dist) if dist is not None else (0.0,) * _N_COEFFS[model]
        half = math.radians(hfov_deg) / 2
        if model == "fisheye":
            k = dist
            reach = half * (1 + k[0] * half**2 + k[1] * half**4 + k[2] * half**6 + k[3] * half**8)
        else:
            r = math.tan(half)
            k1, k2, _, _, k3 = dist
            reach = r * (1 + k1 * r**2 + k2 * r**4 + k3 * r**6)
        f = (width / 2) / reach
        return cls(width, height, f, f, (width - 1) / 2, (height - 1) / 2, model, dist)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self) | {"dist": list(self.dist)}

    @classmethod
    def from_dict(cls, d: object) -> Camera:
        # ``d`` comes from a file (meta.json, camera.json, a model's sensor): set() of a number or a string said
        # "'int' object is not iterable" or took the string's letters for unknown keys
        if not isinstance(d, dict):
            raise ConfigError(f"'camera' must be a mapping of intrinsics ('width', 'height', 'fx', ...), got {d!r}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ConfigError(f"camera has unknown keys {sorted(unknown)}; expected {sorted(known)}")
        missing = {"width", "height", "fx", "fy", "cx", "cy"} - set(d)
        if missing:
            raise ConfigError(f"camera is missing keys {sorted(missing)}")
        camera = cls(**{k: (tuple(v) if k == "dist" and isinstance(v, list) else v) for k, v in d.items()})
        if camera.width * camera.height > MAX_IMAGE_PIXELS:  # a file from elsewhere: docs/formats.md
            raise ConfigError(
                f"camera size {camera.width}x{camera.height}: more than the {MAX_IMAGE_PIXELS} pixels nlipscalib reads"
            )
        return camera

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the images this camera makes."""
        return (self.height, self.width)

    def scaled(self, factor: float) -> Camera:
        """The same lens on an image resampled by ``factor`` (used by coarse-to-fine solvers).

        Pixel centres map as u' = (u + 0.5) * factor - 0.5, which is what ``cv2.resize`` with
        INTER_AREA does.
        """
        w, h = round(self.width * factor), round(self.height * factor)
        sx, sy = w / self.width, h / self.height
        return dataclasses.replace(
            self,
            width=w,
            height=h,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
        )

    # ------------------------------------------------------------------ geometry
    def pixel_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """u, v : (H, W) float64, pixels -- coordinates of every pixel centre."""
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        return u, v

    @cached_property
    def rays(self) -> np.ndarray:
        """rays : (H, W, 3) float64, unit, camera frame -- viewing direction of every pixel centre."""
        u, v = self.pixel_grid()
        return self.unproject(np.stack([u, v], axis=-1))

    def project(self, points: np.ndarray) -> np.ndarray:
        """Project 3D points to pixels.

        Parameters
        ----------
        points : (..., 3) float, mm, camera frame

        Returns
        -------
        uv : (..., 2) float64, pixels. Points behind a pinhole ("brown") camera give NaN.
        """
        p = _check_last_dim(points, 3, "points")
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        if self.model == "fisheye":
            rho = np.hypot(x, y)
            theta = np.arctan2(rho, z)
            k1, k2, k3, k4 = self.dist
            t2 = theta**2
            theta_d = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
            with np.errstate(invalid="ignore", divide="ignore"):
                scale = np.where(rho > 1e-12, theta_d / np.maximum(rho, 1e-300), 1.0 / np.where(z > 0, z, np.nan))
            mx, my = x * scale, y * scale
        else:
            with np.errstate(invalid="ignore", divide="ignore"):
                zz = np.where(z > 0, z, np.nan)
            mx, my = self._brown_distort(x / zz, y / zz)
        return np.stack([self.fx * mx + self.cx, self.fy * my + self.cy], axis=-1)

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Viewing ray of pixel positions.

        Parameters
        ----------
        uv : (..., 2) float, pixels

        Returns
        -------
        rays : (..., 3) float64, unit, camera frame
        """
        uv = _check_last_dim(uv, 2, "uv")
        mx = (uv[..., 0] - self.cx) / self.fx
        my = (uv[..., 1] - self.cy) / self.fy
        if self.model == "fisheye":
            theta_d = np.hypot(mx, my)
            theta = self._fisheye_undistort_angle(theta_d)
            with np.errstate(invalid="ignore", divide="ignore"):
                s = np.where(theta_d > 1e-12, np.sin(theta) / np.maximum(theta_d, 1e-300), 1.0)
            d = np.stack([mx * s, my * s, np.cos(theta)], axis=-1)
        else:
            a, b = self._brown_undistort(mx, my)
            d = np.stack([a, b, np.ones_like(a)], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    # ------------------------------------------------------------------ lens internals
    def _fisheye_undistort_angle(self, theta_d: np.ndarray) -> np.ndarray:
        # Newton on f(theta) = theta (1 + k1 t^2 + ...) - theta_d; monotone for sane lenses.
        k1, k2, k3, k4 = self.dist
        theta = np.array(theta_d, dtype=np.float64)
        for _ in range(_NEWTON_ITERS):
            t2 = theta**2
            f = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - theta_d
            df = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            step = f / df
            theta = theta - step
            if _converged([step], [theta]):
                break
        return theta

    def _brown_distort(self, a: np.ndarray, b: np.ndarray):
        k1, k2, p1, p2, k3 = self.dist
        r2 = a * a + b * b
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        x = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
        y = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
        return x, y

    def _brown_undistort(self, mx: np.ndarray, my: np.ndarray):
        # Newton in 2D with a numeric Jacobian: robust for the strong distortion of wide lenses,
        # where OpenCV's fixed-point iteration can stall.
        a, b = np.array(mx, dtype=np.float64), np.array(my, dtype=np.float64)
        h = 1e-7
        for _ in range(_NEWTON_ITERS):
            x, y = self._brown_distort(a, b)
            xa, ya = self._brown_distort(a + h, b)
            xb, yb = self._brown_distort(a, b + h)
            j11, j21 = (xa - x) / h, (ya - y) / h
            j12, j22 = (xb - x) / h, (yb - y) / h
            ex, ey = x - mx, y - my
            det = j11 * j22 - j12 * j21
            da, db = (j22 * ex - j12 * ey) / det, (-j21 * ex + j11 * ey) / det
            a, b = a - da, b - db
            if _converged([da, db], [a, b]):
                break
        return a, b


def depth_to_points(depth: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Surface points from depth along the optical axis: ``x = z / ray_z * ray``.

    Parameters
    ----------
    depth : (...) float, mm -- z in the camera frame (not range).
    rays : (..., 3) float, unit, camera frame -- the pixels' viewing rays (``Camera.rays``).

    Returns
    -------
    (..., 3) float, mm, camera frame.
    """
    depth = np.asarray(depth)
    if rays.shape[-1:] != (3,) or depth.shape != rays.shape[:-1]:  # a (H, 1) depth broadcast silently
        raise ShapeError(f"depth must be (...) and rays (..., 3), one (...), got {depth.shape} and {rays.shape}")
    return depth[..., None] / rays[..., 2:3] * rays


def pixel_derivatives(table: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Derivatives of a per-pixel table along u (columns) and v (rows): the one stencil for ray tables.

    Second-order differences, one-sided (second order too) at the image border: the lens is smooth at the
    pixel scale, so the O(h^2) error is far below image noise, and the border has no first-order bias.

    Parameters
    ----------
    table : (H, W, ...) float -- e.g. ``Camera.rays`` or rays over their z.

    Returns
    -------
    d_u, d_v : (H, W, ...) float64 -- per pixel.
    """
    table = np.asarray(table, np.float64)
    if table.ndim < 2 or min(table.shape[:2]) < 3:  # edge_order 2 needs three samples along each axis
        raise ShapeError(f"a per-pixel table needs at least 3 x 3 pixels, got {table.shape}")
    return np.gradient(table, axis=1, edge_order=2), np.gradient(table, axis=0, edge_order=2)


def _check_last_dim(arr: np.ndarray, n: int, name: str) -> np.ndarray:
    arr = np.asarray(arr, dtype=np.float64)
    if arr.ndim < 1 or arr.shape[-1] != n:
        raise ShapeError(f"{name} must have shape (..., {n}), got {arr.shape}")
    return arr
