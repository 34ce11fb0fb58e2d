"""Interreflection compensation from a capture of the undeformed dome.

The image model (docs/conventions.md) is direct light only, but the coated dome also lights itself:
light from an LED reflects off one part of the dome onto another (about 17 % of the signal on the
default twin with one bounce). That extra light biases NLiPs toward normals facing the bright side.

On the undeformed dome the geometry is known (``Press.reference``), so the indirect light of every
LED and pixel can be measured as what the direct model does not explain::

    indirect_ic(p) = I_ic(p) - rho_c * S_ic(p)      (S: direct model shading on the reference geometry)

A press changes the indirect light only near the contact (the dent is small next to the dome), so
subtracting the reference's indirect light from the press's images removes most of the bias. The
same procedure works on the real sensor: capture the undeformed dome once, with the press's
exposure and LEDs.

The albedo rho_c (one per channel: the coating is uniform) is not the least-squares fit of
``rho_c S`` to the reference images: indirect light only ever adds, so that fit would absorb part of
it. It is fitted where the direct light dominates most (the samples with the smallest ratio
I / S, which is rho_c plus a non-negative indirect share), see :func:`fit_reference_albedo`.

What the reference cannot hold is the dent's own interreflection: the dent's flanks light each other
and its tilted normals see the rest of the dome differently. :func:`dent_indirect` estimates that
change with one diffuse bounce over the visible surface, from a first solve's geometry and albedo
(``solve_press(..., dent_interreflection=True)``, the default with a reference). On the one-bounce twin
it cuts the contact error left after reference compensation by a quarter to a half (benchmarks/RESULTS.md).
"""

from __future__ import annotations

import numpy as np

from ..core.capture import Press
from ..core.leds import led_shading
from ..errors import CaptureError, ShapeError


def reference_shading(press: Press, leds=None) -> tuple[np.ndarray, np.ndarray]:
    """Direct model shading of every LED on the reference (undeformed) geometry.

    Parameters
    ----------
    press : Press -- with ``reference``.
    leds : sequence of Led or None -- default ``press.leds``.

    Returns
    -------
    shading : (L, H, W, 3) float64 -- Psi_ic (n_s.d)^mu max(0, cos) / r^2; 0 off the gel.
    valid : (H, W) bool -- pixels that see the gel.
    """
    if press.reference is None:
        raise CaptureError(f"{press.folder}: interreflection compensation needs the reference (reference.npz)")
    leds = press.leds if leds is None else tuple(leds)
    ref = press.reference
    valid = np.isfinite(ref.depth)
    rays = press.camera.rays
    pts = np.where(valid, ref.depth, 0.0)[..., None] / rays[..., 2:3] * rays  # (H, W, 3) mm
    shading = led_shading(pts, ref.normals.astype(np.float64), leds)
    shading[:, ~valid] = 0.0
    return shading, valid


def fit_reference_albedo(images: np.ndarray, shading: np.ndarray, usable: np.ndarray, quantile: float = 0.01):
    """Uniform albedo per channel of the undeformed dome, robust to the (additive) indirect light.

    Parameters
    ----------
    images : (L, H, W, 3) float -- linear reference images.
    shading : (L, H, W, 3) float -- direct model shading (:func:`reference_shading`).
    usable : (L, H, W, 3) bool -- samples to use (lit, unsaturated, on the gel).
    quantile : the albedo is this quantile of I / S over the brightest-lit half of the usable samples.

    Returns
    -------
    (3,) float64 -- rho_c, linear image units per unit shading.
    """
    albedo = np.empty(3)
    for c in range(3):
        s, i = shading[..., c][usable[..., c]], images[..., c][usable[..., c]]
        if s.size == 0:
            raise CaptureError("no usable reference samples to fit the albedo on")
        # Where the LED shines straight onto the surface the direct light dominates the indirect
        # light most; the low quantile of I/S there is rho plus the least indirect share (and noise).
        bright = s >= np.median(s)
        albedo[c] = float(np.quantile(i[bright] / s[bright], quantile))
    return albedo


def estimate_indirect(reference: Press, leds=None, quantile: float = 0.01, smooth_px: float = 2.0) -> np.ndarray:
    """Indirect (interreflected) light of every LED and pixel, from a capture of the undeformed dome.

    Parameters
    ----------
    reference : Press -- the undeformed dome (with ``reference``), same camera, LEDs and exposure as
        the presses it will be subtracted from.
    leds : sequence of Led or None -- the LED model (e.g. from ``calibrate-leds``); default the capture's.
    quantile : see :func:`fit_reference_albedo`.
    smooth_px : Gaussian sigma, pixels, applied to the estimate: indirect light varies slowly over
        the dome, the per-pixel difference also holds the reference's sensor/render noise.

    Returns
    -------
    (L, H, W, 3) float32 -- linear image units (``Press.linear`` scale); 0 off the gel.
    """
    import cv2

    shading, valid = reference_shading(reference, leds)
    images = reference.linear(reference.led_images).astype(np.float64)
    usable = ~reference.saturated(reference.led_images) & (shading > 0) & valid[None, :, :, None]
    albedo = fit_reference_albedo(images, shading, usable, quantile)
    indirect = images - albedo * shading
    indirect[:, ~valid] = 0.0
    if smooth_px > 0:
        # Normalised convolution so the gel's silhouette does not darken the estimate.
        w = cv2.GaussianBlur(valid.astype(np.float32), (0, 0), smooth_px)
        for i in range(len(indirect)):
            blurred = cv2.GaussianBlur(indirect[i].astype(np.float32), (0, 0), smooth_px)
            indirect[i] = np.where(valid[..., None], blurred / np.maximum(w, 1e-6)[..., None], 0.0)
    return indirect.astype(np.float32)


def compensate(images: np.ndarray, indirect: np.ndarray) -> np.ndarray:
    """Subtract the indirect light from linear LED images.

    Parameters
    ----------
    images : (L, H, W, 3) float -- linear, ``Press.linear`` scale.
    indirect : (L, H, W, 3) float -- from :func:`estimate_indirect`.

    Returns
    -------
    (L, H, W, 3) float32 -- clipped at 0 (where the estimate exceeds the image the pixel is in the
    dent's shadow or the estimate is noise; the solver treats near-zero samples as shadow).
    """
    if np.shape(images) != np.shape(indirect):
        raise ShapeError(f"indirect light {np.shape(indirect)} must match the images {np.shape(images)}")
    return np.maximum(np.asarray(images, np.float32) - np.asarray(indirect, np.float32), 0.0)


# ---------------------------------------------------------------------------------------------------
# Dent-aware correction: the dent's own interreflection
#
# The reference capture holds the indirect light of the undeformed dome; a press also changes it where
# the gel moved (the dent's flanks light each other, and its tilted normals see the rest of the dome
# differently). That change is estimated with one Lambertian bounce over the *visible* surface. In
# linear image units (Press.linear = exposure * a/pi * irradiance, rho = exposure * a/pi), light that
# leaves patch q with linear direct value D_q = rho_q S_q reaches pixel p and leaves it as
#
#     B(p) = (a/pi) * sum_q D_q max(0, n_p . w_pq) max(0, n_q . w_qp) A_q / r_pq^2
#
# with a the coating's (dimensionless) reflectance: the unknown exposure cancels, only a/pi remains.
# The dome outside the camera's view is missing from both B_press and B_reference, so it cancels in
# their difference (it is ~40 % of the indirect light of the default twin, so B alone would not do).


def pixel_solid_angle(camera) -> np.ndarray:
    """Solid angle that each pixel's viewing rays span.

    Parameters
    ----------
    camera : Camera

    Returns
    -------
    (H, W) float64, steradians -- |d ray/du x d ray/dv| of the unit rays (central differences).
    """
    rays = camera.rays
    return np.linalg.norm(np.cross(np.gradient(rays, axis=1), np.gradient(rays, axis=0)), axis=-1)


def surface_patches(points, normals, radiance, valid, camera, size: int = 4, min_cos: float = 0.2) -> dict:
    """Visible surface as size x size pixel patches: centroid, normal, area and emitted direct light.

    Parameters
    ----------
    points : (H, W, 3) float, mm, camera frame.
    normals : (H, W, 3) float, unit, camera frame, toward the camera.
    radiance : (L, H, W, 3) float -- direct light per LED (linear image units, ``rho * S``).
    valid : (H, W) bool -- pixels that see the gel.
    camera : Camera
    size : patch side, pixels; the image is zero-padded to a multiple of it.
    min_cos : |n . ray| is clipped below this in the area (grazing pixels would get huge areas).

    Returns
    -------
    dict with
        points (h, w, 3) float64 mm -- area-weighted centroid; normals (h, w, 3) float64 unit;
        area (h, w) float64 mm^2 -- 0 where no pixel sees the gel; radiance (L, h, w, 3) float64 --
        area-weighted mean direct light.
    """
    H, W = valid.shape
    h, w = -(-H // size), -(-W // size)
    rays = camera.rays
    rng = np.linalg.norm(points, axis=-1)
    cos = np.abs(np.sum(normals * rays, axis=-1))
    area = np.where(valid, pixel_solid_angle(camera) * rng**2 / np.maximum(cos, min_cos), 0.0)

    def block_sum(a):  # (H, W, ...) -> (h, w, ...), zero padding
        pad = np.zeros((h * size, w * size) + a.shape[2:])
        pad[:H, :W] = a
        return pad.reshape(h, size, w, size, *a.shape[2:]).sum(axis=(1, 3))

    weight = area[..., None]
    total = block_sum(area)
    per_area = 1.0 / np.maximum(total, 1e-30)
    centroid = block_sum(np.where(valid[..., None], points, 0.0) * weight) * per_area[..., None]
    mean_n = block_sum(np.where(valid[..., None], normals, 0.0) * weight)
    mean_n /= np.maximum(np.linalg.norm(mean_n, axis=-1, keepdims=True), 1e-30)
    rad = np.stack([block_sum(np.where(valid[..., None], r, 0.0) * weight) for r in radiance])
    return {"points": centroid, "normals": mean_n, "area": total, "radiance": rad * per_area[None, ..., None]}


def one_bounce(points, normals, emitters: dict, reflectance, chunk: int = 256) -> np.ndarray:
    """One diffuse bounce of the emitters' direct light onto receiver points.

    Parameters
    ----------
    points : (M, 3) float, mm, camera frame -- receivers.
    normals : (M, 3) float, unit, camera frame, toward the camera -- receivers.
    emitters : dict from :func:`surface_patches`, restricted to patches with area > 0 and flattened:
        points (K, 3), normals (K, 3), area (K,), radiance (L, K, 3).
    reflectance : float or (3,) float -- the coating's reflectance a per channel (dimensionless).
    chunk : receivers per block; the block's (chunk, K, 3) float32 differences bound the memory.

    Returns
    -------
    (L, M, 3) float32 -- B, linear image units (see the section comment above). Mutual visibility is
    not tested (a smooth dent in a concave dome barely occludes itself; the cosines cut back faces).
    """
    L = emitters["radiance"].shape[0]
    rad = np.ascontiguousarray(emitters["radiance"].transpose(1, 0, 2).reshape(-1, L * 3), np.float32)
    pe = emitters["points"].astype(np.float32)
    ne = emitters["normals"].astype(np.float32)
    ae = emitters["area"].astype(np.float32)
    out = np.empty((len(points), L * 3), np.float32)
    for s in range(0, len(points), chunk):
        d = pe[None] - np.asarray(points[s : s + chunk], np.float32)[:, None]  # (m, K, 3), p -> q
        r2 = np.einsum("mkc,mkc->mk", d, d)
        inv_r = 1.0 / np.sqrt(np.maximum(r2, 1e-12))
        cos_p = np.maximum(np.einsum("mkc,mc->mk", d, np.asarray(normals[s : s + chunk], np.float32)) * inv_r, 0.0)
        cos_q = np.maximum(-np.einsum("mkc,kc->mk", d, ne) * inv_r, 0.0)
        g = cos_p * cos_q * inv_r**2 * ae
        g[r2 < 1e-12] = 0.0  # a patch does not light itself
        out[s : s + chunk] = g @ rad
    scale = np.broadcast_to(np.asarray(reflectance, np.float32) / np.float32(np.pi), (3,))
    return out.reshape(-1, L, 3).transpose(1, 0, 2) * scale


def dent_indirect(camera, leds, reference, result, reflectance=0.8, patch_px: int | None = None) -> np.ndarray:
    """Change of the indirect light that a press's dent causes, from a solve's geometry and albedo.

    ``B(estimated surface) - B(reference surface)`` at the reconstructed pixels (see the section
    comment above :func:`pixel_solid_angle`): the reconstructed pixels take the solve's points, normals
    and albedo, every other gel pixel keeps the reference geometry. Add it to the reference capture's
    indirect light (:func:`estimate_indirect`) before compensating the press's images again.

    Parameters
    ----------
    camera : Camera
    leds : sequence of Led -- the LED model the solve used.
    reference : Reference -- the undeformed surface (``Press.reference``).
    result : SolveResult -- a solve of the press compensated with the reference's indirect light.
    reflectance : float or (3,) float -- the coating's reflectance a (dimensionless; the twin's 0.8).
    patch_px : patch side, pixels (cost ~ receivers x all patches / patch_px^4); None: the long side
        of the image over 80, at least 2 (4 at 320x240, 8 at 640x480).

    Returns
    -------
    (L, H, W, 3) float32 -- linear image units (``Press.linear`` scale); 0 away from the reconstructed
    pixels.
    """
    import cv2

    H, W = camera.shape
    patch_px = max(2, round(max(H, W) / 80)) if patch_px is None else int(patch_px)
    valid = np.isfinite(reference.depth)
    moved = result.reconstructed & valid
    rays = camera.rays
    ref_points = np.where(valid, reference.depth, 0.0)[..., None] / rays[..., 2:3] * rays
    ref_normals = np.where(valid[..., None], reference.normals, 0.0).astype(np.float64)
    points = np.where(moved[..., None], result.points, ref_points)
    normals = np.where(moved[..., None], result.normals, ref_normals).astype(np.float64)
    # The coating is uniform: the unmoved surface gets the solve's typical albedo, so B_est - B_ref
    # holds the geometry's change (and real albedo variation), not a global albedo mismatch.
    ref_albedo = np.median(result.albedo[moved], axis=0).astype(np.float64) if moved.any() else np.zeros(3)
    albedo = np.where(moved[..., None], result.albedo, ref_albedo)
    before = surface_patches(
        ref_points, ref_normals, ref_albedo * _shading(ref_points, ref_normals, valid, leds), valid, camera, patch_px
    )
    after = surface_patches(points, normals, albedo * _shading(points, normals, valid, leds), valid, camera, patch_px)
    h, w = before["area"].shape
    receivers = np.zeros((h * patch_px, w * patch_px), bool)
    receivers[:H, :W] = moved
    receivers = receivers.reshape(h, patch_px, w, patch_px).any(axis=(1, 3)) & (after["area"] > 0)
    delta = np.zeros((len(leds), h, w, 3), np.float32)
    b_after = one_bounce(after["points"][receivers], after["normals"][receivers], _emitters(after), reflectance)
    b_before = one_bounce(before["points"][receivers], before["normals"][receivers], _emitters(before), reflectance)
    delta[:, receivers] = b_after - b_before
    # Patch centres sit at (i + 0.5) * patch_px - 0.5: cv2's INTER_LINEAR convention for this factor.
    out = np.empty((len(leds), H, W, 3), np.float32)
    for i in range(len(leds)):
        out[i] = cv2.resize(delta[i], (w * patch_px, h * patch_px), interpolation=cv2.INTER_LINEAR)[:H, :W]
    out[:, ~moved] = 0.0
    return out


def _shading(points, normals, valid, leds) -> np.ndarray:
    """(L, H, W, 3) float64 direct model shading, 0 off the gel."""
    shading = led_shading(points, normals, leds)
    shading[:, ~valid] = 0.0
    return shading


def _emitters(patches: dict) -> dict:
    """The patches that see the gel, flattened for :func:`one_bounce`."""
    keep = patches["area"] > 0
    return {
        "points": patches["points"][keep],
        "normals": patches["normals"][keep],
        "area": patches["area"][keep],
        "radiance": patches["radiance"][:, keep],
    }
