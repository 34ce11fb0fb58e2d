"""The sensor's rays for normal integration (:class:`RayGeometry`) and the log-range gradient that normals give
along them (:mod:`.integrate`'s docstring derives it), in float64 and, over a box, float32.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING, TypeAlias

import numpy as np

from ..core.camera import depth_to_points, pixel_derivatives
from ..core.errors import ShapeError
from ..core.tolerances import INTEGRATION_MIN_FACING

if TYPE_CHECKING:  # torch is optional (the full-frame path passes tensors): named for the type checker only
    import torch


Array: TypeAlias = "np.ndarray | torch.Tensor"
"""A numpy array, or a torch tensor where :mod:`.fullframe` calls the shared arithmetic."""


@dataclasses.dataclass(frozen=True)
class RayGeometry:
    """Per-sensor arrays the integration needs, computed once per model/camera."""

    rays: np.ndarray
    """(H, W, 3) float64, unit, camera frame -- viewing ray of every pixel centre."""
    d_u: np.ndarray
    """(H, W, 3) float64 -- derivative of the ray along u (per pixel)."""
    d_v: np.ndarray
    """(H, W, 3) float64 -- derivative of the ray along v (per pixel)."""
    log_range: np.ndarray
    """(H, W) float64 -- log of the undeformed reference's range along the ray, log(mm); NaN off the gel."""
    points: np.ndarray
    """(H, W, 3) float32, mm, camera frame -- the undeformed surface (NaN off the gel)."""

    @classmethod
    def from_reference(cls, rays: np.ndarray, reference_depth: np.ndarray) -> RayGeometry:
        """From ``Camera.rays`` and the reference depth ((H, W) mm, z; NaN off the gel)."""
        if rays.shape != reference_depth.shape + (3,):
            raise ShapeError(f"rays {rays.shape} and reference depth {reference_depth.shape} do not match")
        d_u, d_v = pixel_derivatives(rays)
        with np.errstate(invalid="ignore", divide="ignore"):
            log_range = np.log(reference_depth / rays[..., 2])
            points = depth_to_points(reference_depth, rays).astype(np.float32)
        return cls(rays, d_u, d_v, log_range, points)

    # float32 copies for the per-frame box solver, made once per sensor
    @functools.cached_property
    def rays32(self) -> np.ndarray:
        return self.rays.astype(np.float32)

    @functools.cached_property
    def d_u32(self) -> np.ndarray:
        return self.d_u.astype(np.float32)

    @functools.cached_property
    def d_v32(self) -> np.ndarray:
        return self.d_v.astype(np.float32)


def log_range_gradient(normals: np.ndarray, geo: RayGeometry) -> tuple[np.ndarray, np.ndarray]:
    """(p, q): d log(rho)/du and d log(rho)/dv, each (H, W) float64, from normals ((H, W, 3) unit, camera frame)."""
    return _gradient64(normals, geo.rays, geo.d_u), _gradient64(normals, geo.rays, geo.d_v)


def _gradient64(normals: np.ndarray, rays: np.ndarray, d: np.ndarray) -> np.ndarray:
    """-(n . d) / (n . ray) per pixel, float64 (``d`` the ray's derivative along u or v; (..., 3) each)."""
    den = np.minimum(np.einsum("...k,...k->...", normals, rays), -INTEGRATION_MIN_FACING)
    return -np.einsum("...k,...k->...", normals, d) / den


def _gradient32(normals: Array, rays: Array, d_u: Array, d_v: Array) -> tuple[Array, Array]:
    """:func:`log_range_gradient` in float32 over a box (every argument cropped to it); numpy or torch."""
    n0, n1, n2 = normals[..., 0], normals[..., 1], normals[..., 2]

    def dot(v: Array) -> Array:
        return n0 * v[..., 0] + n1 * v[..., 1] + n2 * v[..., 2]

    den = dot(rays).clip(max=-INTEGRATION_MIN_FACING)
    return -dot(d_u) / den, -dot(d_v) / den
