"""Diffuse interreflection of the gel surface: a radiosity gather over surface patches.

Physics followed: the radiosity equation for Lambertian surfaces (Goral, Torrance, Greenberg &
Battaile, "Modeling the interaction of light between diffuse surfaces", SIGGRAPH 1984; Cohen &
Wallace, *Radiosity and Realistic Image Synthesis*, 1993, ch. 2), truncated after one or two bounces
(the Neumann series of the radiosity operator, each term one more bounce), with the point-to-patch
form factor ``cos_p cos_q A_q / (pi r^2)`` and no visibility test (a smooth dent in a concave dome
barely occludes itself; the cosines cut back faces). The same one-bounce term is what Nayar, Ikeuchi
& Kanade ("Shape from interreflections", IJCV 1991) add to photometric stereo.

In linear image units (``Press.linear`` = exposure * a/pi * irradiance, so rho = exposure * a/pi up to
the LED intensity gauge), light leaving patch q with linear value D_q = rho_q S_q (direct shading S of
:func:`nlipscalib.core.leds.led_shading`) reaches receiver p and leaves it as::

    B(p) = (a_p / pi) * sum_q D_q max(0, n_p . w_pq) max(0, n_q . w_qp) A_q / r_pq^2

The receiver's dimensionless reflectance a_p is proportional to its linear albedo (a_p = kappa rho_p,
kappa = pi / exposure in the LED gauge), so ``B(p) = kappa rho_p G(p)`` with
``G(p) = (1/pi) sum_q D_q (cos cos A / r^2)``: one global constant per channel, which
:mod:`nlipscalib.solver.indirect` fits to the capture of the undeformed dome.
"""

from __future__ import annotations

import numpy as np

from ..core.camera import Camera, pixel_derivatives
from ..core.dome import dome_inward_normals, project_to_dome
from ..core.sensor import DomeConfig
from ..core.tolerances import NORMAL_EPS
from . import threads
from .blas import blas_threads


def pixel_solid_angle(camera: Camera) -> np.ndarray:
    """Solid angle that each pixel's viewing rays span.

    Returns
    -------
    (H, W) float64, steradians -- |d ray/du x d ray/dv| of the unit rays (:func:`pixel_derivatives`).
    """
    d_u, d_v = pixel_derivatives(camera.rays)
    return np.linalg.norm(np.cross(d_u, d_v), axis=-1)


def block_sum(a: np.ndarray, size: int) -> np.ndarray:
    """Sum (H, W, ...) over size x size blocks -> (ceil(H/size), ceil(W/size), ...) float64, zero padding.

    Images of up to 4 channels go through OpenCV's area resampling (a block mean for an integer factor, times
    size^2): ten times faster than NumPy's sum over the two block axes (0.5 against 6 ms at 640x480x3), equal
    to 1e-13 relative.
    """
    import cv2

    H, W = a.shape[:2]
    h, w = -(-H // size), -(-W // size)
    if H == h * size and W == w * size and a.dtype == np.float64 and a.flags.c_contiguous:
        pad = a  # no padding needed: sum the blocks of the array itself (no copy)
    else:
        pad = np.zeros((h * size, w * size) + a.shape[2:], dtype=np.float64)
        pad[:H, :W] = a
    if a.ndim == 2 or (a.ndim == 3 and a.shape[2] <= 4):
        out = cv2.resize(pad, (w, h), interpolation=cv2.INTER_AREA) * float(size * size)
        return out.reshape((h, w) + a.shape[2:])  # cv2 drops a single channel's axis
    return pad.reshape(h, size, w, size, *a.shape[2:]).sum(axis=(1, 3))


def surface_patches(
    points: np.ndarray,
    normals: np.ndarray,
    valid: np.ndarray,
    camera: Camera,
    size: int = 4,
    min_cos: float = 0.2,
    window: tuple[slice, slice] | None = None,
    solid_angle: np.ndarray | None = None,
) -> dict:
    """Visible surface as size x size pixel patches: area-weighted centroid, normal and area.

    Parameters
    ----------
    points : (H, W, 3) float, mm, camera frame.
    normals : (H, W, 3) float, unit, camera frame, toward the camera.
    valid : (H, W) bool -- pixels that see the gel.
    camera : Camera
    size : patch side, pixels; the image is zero-padded to a multiple of it.
    min_cos : |n . ray| is clipped below this in the area (grazing pixels would get huge areas).
    window : (row slice, column slice) or None -- the arrays are this window of the camera's image
        (starting on a patch boundary): the patches of that window only.
    solid_angle : (H, W) float64 or None -- :func:`pixel_solid_angle` of the camera, when known.

    Returns
    -------
    dict with points (h, w, 3) float64 mm; normals (h, w, 3) float64 unit; area (h, w) float64 mm^2
    (0 where no pixel sees the gel); pixel_area (H, W) float64 mm^2 (the weights, for
    :func:`patch_mean`); solid_angle (H, W) float64 sr; size.
    """
    window = (slice(None), slice(None)) if window is None else tuple(window)
    solid_angle = pixel_solid_angle(camera) if solid_angle is None else solid_angle
    rng = np.linalg.norm(points, axis=-1)
    cos = np.abs(np.sum(normals * camera.rays[window], axis=-1))
    area = np.where(valid, solid_angle[window] * rng**2 / np.maximum(cos, min_cos), 0.0)
    total = block_sum(area, size)
    per_area = 1.0 / np.maximum(total, 1e-30)
    centroid = block_sum(np.where(valid[..., None], points, 0.0) * area[..., None], size) * per_area[..., None]
    mean_n = block_sum(np.where(valid[..., None], normals, 0.0) * area[..., None], size)
    mean_n /= np.maximum(np.linalg.norm(mean_n, axis=-1, keepdims=True), NORMAL_EPS)
    return {
        "points": centroid,
        "normals": mean_n,
        "area": total,
        "pixel_area": area,
        "solid_angle": solid_angle,
        "size": size,
    }


def patch_mean(patches: dict, values: np.ndarray) -> np.ndarray:
    """Area-weighted mean of per-pixel values over each patch.

    Parameters
    ----------
    patches : from :func:`surface_patches`.
    values : (L, H, W, 3) or (H, W, ...) float.

    Returns
    -------
    (L, h, w, 3) or (h, w, ...) float64.
    """
    w, size = patches["pixel_area"], patches["size"]
    per_area = 1.0 / np.maximum(patches["area"], 1e-30)
    if values.ndim == 4:
        return np.stack(threads.map_items(lambda v: block_sum(v * w[..., None], size) * per_area[..., None], values))
    return block_sum(values * w.reshape(w.shape + (1,) * (values.ndim - 2)), size) * per_area.reshape(
        per_area.shape + (1,) * (values.ndim - 2)
    )


def off_view_patches(
    dome: DomeConfig, camera_position: np.ndarray, camera: Camera, seen: np.ndarray, step_deg: float = 2.0
) -> dict:
    """Patches of the analytic dome that the camera does not see (beyond its field of view).

    They light the visible surface too (on the default twin about 40 % of the one-bounce light comes
    from outside the 100 deg view), so the gather needs them.

    Parameters
    ----------
    dome : DomeConfig -- the design's surface.
    camera_position : (3,) float, mm, dome frame.
    camera : Camera
    seen : (H, W) bool -- pixels whose surface the visible patches already hold.
    step_deg : polar / azimuth sampling step, degrees.

    Returns
    -------
    dict with points (K, 3) mm camera frame, normals (K, 3) unit toward the camera, area (K,) mm^2.
    """
    polar = np.radians(np.arange(step_deg / 2, 90.0, step_deg))
    azim = np.radians(np.arange(step_deg / 2, 360.0, step_deg))
    th, ph = np.meshgrid(polar, azim, indexing="ij")

    def hits(t: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
        pts = project_to_dome(dome, d)
        return pts.reshape(t.shape + (3,)), dome_inward_normals(dome, pts).reshape(t.shape + (3,))

    pts, nrm = hits(th, ph)
    h = np.radians(step_deg) / 2
    d_t = hits(th + h, ph)[0] - hits(th - h, ph)[0]
    d_p = hits(th, ph + h)[0] - hits(th, ph - h)[0]
    area = np.linalg.norm(np.cross(d_t, d_p), axis=-1)
    pts = (pts - np.asarray(camera_position, float)).reshape(-1, 3)
    nrm, area = nrm.reshape(-1, 3), area.reshape(-1)
    uv = camera.project(pts)
    H, W = camera.shape
    inside = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] > -0.5) & (uv[:, 0] < W - 0.5)
    inside &= (uv[:, 1] > -0.5) & (uv[:, 1] < H - 0.5)
    iu = np.clip(np.round(np.nan_to_num(uv[:, 0])).astype(int), 0, W - 1)
    iv = np.clip(np.round(np.nan_to_num(uv[:, 1])).astype(int), 0, H - 1)
    keep = ~(inside & seen[iv, iu]) & np.all(np.isfinite(pts), axis=1) & (area > 0)
    return {"points": pts[keep], "normals": nrm[keep], "area": area[keep]}


GATHER_BLOCK_FLOATS = 1 << 18
"""Receiver-by-emitter entries per block of :func:`gather` (1 MiB of float32): its (block, K) temporaries then
stay in the CPU's cache. 2.5-3x faster than 2048 receivers per block (900 receivers x 6,800 emitters x 12 LEDs:
0.05 against 0.15 s)."""


def gather(
    points: np.ndarray, normals: np.ndarray, emitters: dict, radiance: np.ndarray, chunk: int | None = None
) -> np.ndarray:
    """Irradiance-like gather ``G(p) = (1/pi) sum_q D_q cos_p cos_q A_q / r^2`` (one diffuse bounce
    for a receiver of reflectance 1).

    Parameters
    ----------
    points : (M, 3) float, mm, camera frame -- receivers.
    normals : (M, 3) float, unit, camera frame, toward the camera -- receivers.
    emitters : dict with points (K, 3) mm, normals (K, 3) unit, area (K,) mm^2.
    radiance : (L, K, 3) float -- D_q per LED and channel, linear image units.
    chunk : receivers per block (default: :data:`GATHER_BLOCK_FLOATS` / K, at least 16).

    Returns
    -------
    (L, M, 3) float32 -- linear image units per unit receiver reflectance.

    Notes
    -----
    Every pairwise term is a matrix product (r^2 = |p|^2 + |q|^2 - 2 p.q, r cos_p = n_p.q - n_p.p,
    r cos_q = n_q.p - n_q.q), so BLAS does the M x K work.
    """
    L = radiance.shape[0]
    rad = np.ascontiguousarray(np.asarray(radiance, np.float32).transpose(1, 0, 2).reshape(-1, L * 3))
    pe = np.asarray(emitters["points"], np.float64)
    ne = np.asarray(emitters["normals"], np.float64)
    ae = np.asarray(emitters["area"], np.float32)
    pr_all = np.asarray(points, np.float64)
    nr_all = np.asarray(normals, np.float64)
    out = np.empty((len(pr_all), L * 3), np.float32)
    chunk = chunk or max(16, GATHER_BLOCK_FLOATS // max(len(pe), 1))
    qq = np.sum(pe * pe, axis=1)
    nq_q = np.sum(ne * pe, axis=1)

    def receivers(blocks: list[int]) -> None:
        for s in blocks:
            pr, nr = pr_all[s : s + chunk], nr_all[s : s + chunk]
            # float64 for the cancelling differences, float32 for the products that follow
            r2 = (np.sum(pr * pr, axis=1)[:, None] + qq[None] - 2.0 * (pr @ pe.T)).astype(np.float32)
            cp = (nr @ pe.T - np.sum(nr * pr, axis=1)[:, None]).astype(np.float32)  # r cos_p
            cq = (pr @ ne.T - nq_q[None]).astype(np.float32)  # r cos_q
            np.maximum(cp, 0.0, out=cp)
            np.maximum(cq, 0.0, out=cq)
            tiny = r2 < 1e-12  # a patch does not light itself
            np.maximum(r2, 1e-12, out=r2)
            g = cp * cq / (r2 * r2) * ae
            g[tiny] = 0.0
            out[s : s + chunk] = g @ rad

    # the blocks split over the thread pool, BLAS on one thread: its own threads on these small products
    # synchronised more than they computed. The blocks are the same whatever the thread count, and so are
    # the result's bits.
    starts = list(range(0, len(pr_all), chunk))
    with blas_threads(1):
        threads.map_items(lambda part: receivers(starts[part]), threads.chunks(len(starts)) if starts else [])
    return out.reshape(-1, L, 3).transpose(1, 0, 2) / np.float32(np.pi)


def upsample(patch_values: np.ndarray, shape: tuple[int, int], size: int) -> np.ndarray:
    """Bilinear upsampling of (L, h, w, 3) patch values to (L, H, W, 3) pixels (patch centres at
    (i + 0.5) * size - 0.5, cv2's INTER_LINEAR convention for an integer factor)."""
    import cv2

    H, W = shape
    L, h, w = patch_values.shape[:3]
    out = np.empty((L, H, W, 3), np.float32)
    for i in range(L):
        big = cv2.resize(np.asarray(patch_values[i], np.float32), (w * size, h * size), interpolation=cv2.INTER_LINEAR)
        out[i] = big[:H, :W]
    return out


__all__ = [
    "block_sum",
    "gather",
    "off_view_patches",
    "patch_mean",
    "pixel_solid_angle",
    "surface_patches",
    "upsample",
]
