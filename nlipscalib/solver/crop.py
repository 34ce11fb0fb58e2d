"""A solve on its mask's bounding box: the crop's camera (the same lens, shifted), the finest level's data on the
crop (the LEDs kept, their usable samples, the log-depth prior), and the finest level's solution pasted back into
the whole image as the reconstruction."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.camera import Camera
from ..core.leds import Leds, disk_points, led_arrays
from ..core.reconstruction import Reconstruction as SolveResult  # the name nlips.py gives it
from .frame_box import FrameBox, frame_crop
from .options import SolverOptions
from .pyramid import checked_prior_weights
from .samples import exclusions, high_level


def crop_to_mask(mask: np.ndarray, camera: Camera) -> tuple[tuple[slice, slice], Camera]:
    """The mask's bounding box as (rows, cols) slices, and the camera of that crop (the same lens, shifted)."""
    rows, cols = np.nonzero(mask)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    cam = dataclasses.replace(camera, width=int(c1 - c0), height=int(r1 - r0), cx=camera.cx - c0, cy=camera.cy - r0)
    crop = (slice(r0, r1), slice(c0, c1))
    if "rays" in vars(camera):  # the whole image's rays are made: the crop's are theirs (Camera.rays, kept on it)
        vars(cam)["rays"] = camera.rays[crop]
    return crop, cam


@dataclasses.dataclass
class LevelData:
    """What the finest level is built from, on the mask's bounding box: the normalised images of the LEDs
    kept (dead ones dropped), their usable samples, the log-depth prior and its weights."""

    images: np.ndarray
    """(L', h, w, 3) float, as given: the pyramid's levels hold them divided by ``scale``
    (:func:`.pyramid.build_pyramid`)."""
    usable: np.ndarray
    """(L', h, w, 3) bool."""
    mask: np.ndarray
    """(h, w) bool -- the solve mask on the crop."""
    t0: np.ndarray
    """(h, w) float64 -- log prior depth (0 off the mask)."""
    w0: np.ndarray
    """(h, w) float -- the prior weights' multipliers."""
    leds: tuple
    """(positions, directions, mu, psi) of the LEDs kept (:func:`nlipscalib.core.leds.led_arrays`); of disk LEDs the
    positions (L, 7, 3) are their disks' quadrature points (:func:`nlipscalib.core.leds.disk_points`)."""
    kept: list
    """0-based indices of the LEDs kept."""
    usable_leds: np.ndarray
    """(H, W) int16 -- usable LEDs per pixel of the whole image (0 outside the crop)."""
    scale: float
    """The images' 99th percentile over usable samples, by which they were divided."""
    report: dict
    """:func:`exclusions`' report (its counts are the crop's)."""

    @classmethod
    def of(
        cls,
        images: np.ndarray | FrameBox,
        saturated: np.ndarray | None,
        mask: np.ndarray,
        crop: tuple[slice, slice],
        prior_depth: np.ndarray,
        prior_weights: np.ndarray | None,
        leds: Leds,
        opts: SolverOptions,
        led_radius: float = 0.0,
    ) -> LevelData:
        whole = images
        H, W = mask.shape
        # Per-pixel work runs in opts.dtype; the images need no more precision than that (16-bit data).
        dtype = np.float32 if opts.dtype == "float32" else np.float64
        images = frame_crop(images, crop).astype(dtype, copy=False)
        sat = None if saturated is None else saturated[:, crop[0], crop[1]]
        # the exclusions' thresholds are statistics of the whole images; outside the mask nothing is usable
        use, report = exclusions(images, sat, opts, whole=whole)
        m = mask[crop]
        if not m.all():
            use &= m[None, :, :, None]
        usable_leds = np.zeros((H, W), np.int16)
        usable_leds[crop] = (use[..., 0] | use[..., 1] | use[..., 2]).sum(axis=0, dtype=np.int16)
        scale = high_level(images, use)  # usable lies inside the crop
        kept = [i for i in range(len(leds)) if i not in report["dead_leds"]]
        every = len(kept) == len(leds)  # then no copy of the images and samples
        pos, dirs, mu, psi = led_arrays(leds)
        if led_radius > 0:  # disks: the kernel shades their quadrature points
            pos = disk_points(pos, dirs, led_radius)
        return cls(
            images=images if every else images[kept],
            usable=use if every else use[kept],
            mask=m,
            t0=np.log(np.where(m, prior_depth[crop], 1.0)),
            w0=checked_prior_weights(prior_weights, (H, W))[crop],
            leds=(pos[kept], dirs[kept], mu[kept], psi[kept]),
            kept=kept,
            usable_leds=usable_leds,
            scale=scale,
            report=report,
        )


def full_image(
    t_state: np.ndarray,
    out: dict,
    lv: dict,
    data: LevelData,
    mask: np.ndarray,
    crop: tuple[slice, slice],
    opts: SolverOptions,
) -> SolveResult:
    """The finest level's solution pasted into the whole image (NaN where not reconstructed: off the mask,
    no gradient, fewer than ``opts.min_leds`` usable LEDs); adds the pixel counts to ``data.report``."""
    H, W = mask.shape
    lm = lv["mask"]
    n_ok = out["has_gradient"] & (data.usable_leds[crop][lm] >= opts.min_leds)
    rec = np.zeros((H, W), bool)
    sub = np.zeros(lm.shape, bool)
    sub[lm] = n_ok
    rec[crop] = sub

    lost = None if n_ok.all() else ~n_ok

    def paste(values: np.ndarray, fill: float = np.nan):
        return _pasted(values, fill, (H, W), crop, lm, lost)

    depth = np.exp(t_state[lm])
    data.report.update(
        {
            "pixels_reconstructed": int(rec.sum()),
            "pixels_too_few_leds": int((mask & (data.usable_leds < opts.min_leds)).sum()),
            "pixels_no_gradient": int((~out["has_gradient"]).sum()),
        }
    )
    return SolveResult(
        depth=paste(depth),
        # core.camera.depth_to_points with the rays pre-divided by their z (q = ray / ray_z, geometry.py)
        points=paste(depth[:, None] * lv["q"]),
        normals=paste(out["normals"]),
        albedo=paste(out["albedo"].T * data.scale),
        residual=paste(out["residual"] * data.scale),
        confidence=paste(np.nan_to_num(out["confidence"]), 0.0),  # 0 outside: the same as after the paste
        usable_leds=data.usable_leds,
        mask=mask,
        reconstructed=rec,
        report=data.report,
    )


def _pasted(
    values: np.ndarray,
    fill: float,
    shape: tuple[int, int],
    crop: tuple[slice, slice],
    mask: np.ndarray,
    lost: np.ndarray | None,
) -> np.ndarray:
    """(H, W, ...) float32 image of a level's per-pixel ``values`` (N, ...) on ``mask`` (h, w) of the ``crop`` of an
    image of ``shape`` (H, W); ``fill`` elsewhere and at the pixels ``lost`` (N,) bool (None: none).

    Why not a filled image and a masked assignment: every pixel is written once (the crop's values cast straight into
    it where the mask is the whole crop, the ROI's usual case), with no float32 copy of ``values`` and no masks
    (a pass's six images: ~9 against ~3 ms of one core, 336 x 332 in 640 x 480; benchmarks/RESULTS.md, s21-cpu)."""
    full = np.empty(shape + values.shape[1:], np.float32)
    rows, cols = crop
    full[: rows.start], full[rows.stop :] = fill, fill
    full[rows, : cols.start], full[rows, cols.stop :] = fill, fill
    block = full[crop]  # a view: written through
    if mask.all():
        np.copyto(block, values.reshape(block.shape), casting="same_kind")  # astype's cast
        if lost is not None:
            block[lost.reshape(mask.shape)] = fill
        return full
    block[...] = fill
    vals = values.astype(np.float32)
    if lost is not None:
        vals[lost] = fill
    block[mask] = vals
    return full
