"""The indirect (interreflected) term of the image model, fitted to data and applied to a solved surface.

Image model with interreflection (one or two diffuse bounces, :mod:`nlipscalib.solver.radiosity`)::

    I_ic(p) = rho_pc * ( S_ic(p) + kappa_c * G_ic(p) )

S is the direct shading (``core.leds.led_shading``), G the gather of the surface's own direct light
(``D_q = rho_q S_q``) over the visible surface plus, when the sensor design is known, the dome beyond the
camera's view; kappa_c = a_p / rho_p (reflectance per unit linear albedo, = pi / exposure in the LED
gauge) is one constant per channel. Nothing assumes a uniform albedo: rho is fitted per pixel, and the
only global unknown, kappa, is fitted to the capture of the undeformed dome (:func:`fit_indirect`).
The coating's reflectance follows as a = kappa * median(rho) and is reported.

How much indirect light there is, is therefore measured, not assumed: kappa comes out ~0 on a capture
without interreflection (a textured albedo is absorbed by the per-pixel rho, it does not correlate with
G across the LEDs), and :func:`fit_indirect` switches the term off when its share of the light is below
``tolerances.INDIRECT_MIN_SHARE``.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np

from ..core import masks, tolerances
from ..core.camera import Camera, depth_to_points
from ..core.capture import Press
from ..core.errors import CaptureError, ConfigError
from ..core.leds import Leds, disk_falloff, disk_shading, led_arrays, led_shading
from ..core.sensor import DomeConfig, capture_design
from . import radiosity, reuse, threads
from .exposure import no_light_reason
from .image_stats import led_levels, lit_leds

PATCH_TARGET = 80
"""Patches along the image's long side (the patch side is the long side over this, at least 2 px)."""
FIT_PATCH_TARGET = 40
"""The same for the fit on the undeformed dome (slowly varying light: coarse patches suffice)."""


AUTO_THRESHOLD_SAID = f"(auto threshold {tolerances.INDIRECT_MIN_SHARE})"
"""How :func:`fit_indirect`'s ``reason`` names the rule of "auto": the LED calibration, whose rule is another
(:func:`nlipscalib.solver.calibration_term.calibration_reason`), puts its own words in its place."""


@dataclasses.dataclass(frozen=True)
class IndirectModel:
    """The fitted indirect term (:func:`fit_indirect`)."""

    kappa: tuple[float, float, float]
    """Reflectance per unit linear albedo, per channel (0: no interreflection)."""
    reflectance: tuple[float, float, float]
    """The coating's dimensionless reflectance a = kappa * median(rho), per channel (the twin's: 0.8)."""
    share: float
    """Median over the gel of indirect / direct light on the undeformed dome."""
    bounces: int
    """Diffuse bounces modelled (1 or 2)."""
    enabled: bool
    """Whether the term is applied (auto: share >= INDIRECT_MIN_SHARE; or forced)."""
    reason: str
    """Why it is (not) applied, for the report."""
    off_view: dict | None = dataclasses.field(default=None, repr=False, compare=False)
    """Patches of the dome beyond the view (points, normals, area) or None without a design."""
    off_view_albedo: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Linear albedo given to the off-view dome (median of the fitted rho)."""
    fitted_light: tuple | None = dataclasses.field(default=None, repr=False, compare=False)
    """(kappa G (L, h, w, 3) float32 on the fitted capture's patches, patch side): the undeformed
    dome's indirect light per unit receiver albedo."""

    def with_reflectance(self, reflectance: float | tuple[float, float, float]) -> IndirectModel:
        """This model with the coating's reflectance set (one value or per channel, in (0, 1]) instead of
        fitted: kappa = a / the typical albedo, the fitted light scaled alike (exact for one bounce; with two,
        the second bounce keeps the fitted kappa's share)."""
        a = checked_reflectance(reflectance)
        kappa = a / np.maximum(np.asarray(self.off_view_albedo), 1e-30)
        light = self.fitted_light
        if light is not None:
            ratio = kappa / np.maximum(np.asarray(self.kappa), 1e-30)
            light = ((light[0] * ratio).astype(np.float32), light[1])
        return dataclasses.replace(
            self,
            kappa=tuple(float(v) for v in kappa),
            reflectance=tuple(float(v) for v in a),
            fitted_light=light,
            reason=self.reason + f"; reflectance set to {np.round(a, 3).tolist()}",
        )

    def with_gain(self, gain: np.ndarray) -> IndirectModel:
        """This model for images ``gain`` (3,) times as bright as the fitted capture's, per channel (LEDs aged, the
        exposure changed: :func:`.led_checks.reference_gain`). The albedo solved on them is ``gain`` times the
        fitted one, so kappa (reflectance per unit albedo) is divided by it and the off-view dome's albedo
        multiplied; the fitted light (per unit receiver albedo) and the coating's reflectance stay: for one bounce
        every term of the image model is then ``gain`` times the fitted capture's, as the images are."""
        gain = np.asarray(gain, float)
        return dataclasses.replace(
            self,
            kappa=tuple(float(v) for v in np.asarray(self.kappa) / gain),
            off_view_albedo=tuple(float(v) for v in np.asarray(self.off_view_albedo) * gain),
        )

    def undeformed_light(self, shape: tuple[int, int]) -> np.ndarray:
        """(L, H, W, 3) float32 -- the fitted capture's indirect light per unit receiver albedo
        (multiply by the pixel's albedo; add to the direct shading for the undeformed model)."""
        return np.asarray(self.undeformed_light_per_led(shape))

    def undeformed_light_per_led(self, shape: tuple[int, int]) -> radiosity.Upsampled:
        """:meth:`undeformed_light` upsampled one LED at a time as it is read (:class:`radiosity.Upsampled`), for
        a reader that takes one LED's (H, W, 3) image at a time (the contact classification)."""
        if self.fitted_light is None:
            raise CaptureError("this interreflection model holds no fitted light")
        light, size = self.fitted_light
        return radiosity.Upsampled(light, shape, size)

    def to_json(self) -> dict:
        return {
            "kappa": list(self.kappa),
            "coating_reflectance": list(self.reflectance),
            "indirect_share": self.share,
            "bounces": self.bounces,
            "enabled": self.enabled,
            "reason": self.reason,
            "off_view_dome": self.off_view is not None,
        }


def checked_reflectance(reflectance: float | tuple[float, float, float]) -> np.ndarray:
    """(3,) float -- a coating reflectance given as one value or per channel, each in (0, 1]; else ConfigError."""
    a = np.broadcast_to(np.asarray(reflectance, float), (3,))
    if not np.all((a > 0) & (a <= 1)):
        raise ConfigError(f"the coating reflectance must be in (0, 1], got {reflectance}")
    return a


def design_of(press: Press) -> tuple[DomeConfig, np.ndarray] | None:
    """The sensor design's dome and camera position (mm, dome frame) a capture was made with, or None.

    From its meta (:func:`nlipscalib.core.sensor.capture_design`): ``meta["design"]`` (device captures:
    ``nlips capture --port``), ``meta["provenance"]["scene"]`` (twin, emulated sensor), or the shipped design
    that ``meta["provenance"]["design"]`` names (device captures made before the design was recorded).
    """
    return capture_design(press.meta)[0]


def patch_size(camera: Camera) -> int:
    """Patch side, pixels, for a solved surface (:data:`PATCH_TARGET` patches along the long side)."""
    return max(2, round(max(camera.shape) / PATCH_TARGET))


def fit_patch_size(camera: Camera) -> int:
    """Patch side, pixels, for the undeformed dome (:data:`FIT_PATCH_TARGET` patches along the long side)."""
    return max(2, round(max(camera.shape) / FIT_PATCH_TARGET))


def direct_shading(
    camera: Camera, leds: Leds, depth: np.ndarray, normals: np.ndarray, radius: float = 0.0
) -> np.ndarray:
    """Direct shading of a surface at every pixel (``core.leds.led_shading``; LEDs emitting from disks of
    ``radius`` mm: ``core.leds.disk_shading``), 0 off the gel.

    Computed once per solve for the reference surface and shared by the indirect fit, the contact
    classification and the outer loop (a full-frame evaluation costs ~0.4 s; a solve needed six).

    Parameters
    ----------
    camera : Camera
    leds : sequence of Led, length L
    depth : (H, W) float, mm (z), camera frame; NaN off the gel.
    normals : (H, W, 3) float, unit, camera frame, toward the camera.
    radius : the LEDs' emitting disk radius, mm (their centres and axes ``leds``); 0: point LEDs.

    Returns
    -------
    (L, H, W, 3) float64 -- shading factor per LED and channel.
    """
    valid = np.isfinite(depth)
    pts = depth_to_points(np.where(valid, depth, 0.0), camera.rays)
    nrm = np.where(valid[..., None], normals, 0.0).astype(np.float64)
    return _shading_on_threads(pts, nrm, valid, tuple(leds), radius)


def term_shading(points: np.ndarray, normals: np.ndarray, leds: Leds, radius: float = 0.0) -> np.ndarray:
    """The indirect term's direct light of its LEDs: ``core.leds.led_shading``, or ``core.leds.disk_shading`` of
    disks of ``radius`` mm (> 0; the solve's ``--led-model disks``): the term shades with the LED model the solve
    does (a point term under a disk solve put the disks' loss on one-bounce presses, benchmarks/RESULTS.md,
    s33-disklose). (L, ..., 3) float64."""
    return disk_shading(points, normals, leds, radius) if radius > 0 else led_shading(points, normals, tuple(leds))


def term_key(leds: Leds, radius: float = 0.0) -> tuple:
    """The term's LEDs as named in the keys of what it caches (shading, surfaces, fits, off-view light): the LEDs
    alone for point LEDs (the keys as before disks were threaded through), with the disks' radius else, so a disk
    result is never read back by a point solve nor the other way round."""
    return tuple(leds) if not radius > 0 else (tuple(leds), ("disk radius mm", float(radius)))


def _shading_on_threads(
    points: np.ndarray, normals: np.ndarray, valid: np.ndarray, leds: Leds, radius: float = 0.0
) -> np.ndarray:
    """``led_shading`` (``disk_shading`` at ``radius`` > 0) of a grid of points, 0 where not ``valid``, by blocks
    of rows on the thread pool.

    Parameters
    ----------
    points, normals : (h, w, 3) float64, mm and unit, camera frame (any finite values where not valid).
    valid : (h, w) bool
    leds : tuple of Led, length L
    radius : the LEDs' disk radius, mm; 0: points.

    Returns
    -------
    (L, h, w, 3) float64 -- the same numbers as one ``led_shading`` call (each point's own arithmetic).
    """
    out = np.empty((len(leds),) + valid.shape + (3,))

    def rows(block: slice):  # written in place by blocks of rows, one per thread: no (L, h, w, 3) temporaries
        if radius > 0:
            out[:, block] = disk_shading(points[block], normals[block], leds, radius)
        else:
            led_shading(points[block], normals[block], leds, out=out[:, block])
        out[:, block][:, ~valid[block]] = 0.0

    threads.map_items(rows, threads.chunks(valid.shape[0]))
    return out


def reference_shading(
    camera: Camera, leds: Leds, depth: np.ndarray, normals: np.ndarray, defer: bool = False, radius: float = 0.0
) -> np.ndarray | reuse.Deferred:
    """:func:`direct_shading` of the undeformed surface, reused for the next press of the same sensor in this
    process (:mod:`nlipscalib.solver.reuse`); read-only.

    ``defer``: return a :class:`~nlipscalib.solver.reuse.Deferred` instead, which names the shading by its key
    and computes it only when a consumer needs its values (:func:`reuse.values`): a warm process whose consumers
    (:func:`reference_surface`, the contact's smoothed undeformed images) all find their own results on disk
    does not compute the 88 MB (640x480) array at all.

    Not kept on disk: only a process that misses those consumers' entries needs it (a cold one, which computes
    them from it), and there it costs ~0.2 s to compute against ~0.08 s to read, while writing it cost every
    cold 640x480 command 0.1-0.8 s of system time and took a third of the sensor's cache (benchmarks/RESULTS.md,
    s17-f). ``radius``: the LEDs' disk radius, mm (:func:`term_shading`; in the key, :func:`term_key`)."""
    leds = tuple(leds)
    key = (camera, term_key(leds, radius), surface_digest(depth, normals))
    shading = reuse.deferred("shading", key, lambda: direct_shading(camera, leds, depth, normals, radius))
    return shading if defer else shading.values()


def reference_surface(
    camera: Camera,
    leds: Leds,
    depth: np.ndarray,
    normals: np.ndarray,
    size: int | None = None,
    shading: np.ndarray | reuse.Deferred | None = None,
    radius: float = 0.0,
) -> Surface:
    """:class:`Surface` of the undeformed surface, reused for the next press of the same sensor (in this
    process and the next); its arrays are read-only (:meth:`Surface.replaced` copies what it changes).
    ``shading``: its :func:`direct_shading` (or :func:`reference_shading`'s deferred one, read only when the
    surface is made here), or None. ``radius``: the LEDs' disk radius, mm (0: points; :func:`term_key`)."""
    leds = tuple(leds)
    size = patch_size(camera) if size is None else int(size)

    def make() -> Surface:
        surf = Surface(camera, leds, np.array(depth), np.array(normals), size, reuse.values(shading), radius)
        reuse.freeze(surf.patches, surf.shading, surf.keep, surf.valid, surf.depth, surf.normals)
        return surf

    key = (camera, term_key(leds, radius), size, surface_digest(depth, normals))
    return reuse.reused("surface", key, make, persist=True)


def surface_digest(depth: np.ndarray, normals: np.ndarray) -> str:
    """``reuse.digest(depth, normals)``: the undeformed surface's name in the keys of its shading, its patches (at
    each patch size) and the off-view dome's light. Worked out once per pair of read-only arrays (a loaded
    capture's reference: 6 ms at 640x480, and a solve names it three times); writable ones could change in place
    and are hashed anew."""
    if any(not isinstance(a, np.ndarray) or a.flags.writeable for a in (depth, normals)):
        return reuse.digest(depth, normals)
    # the store holds both arrays (depth as its ``keep``, normals in the value): no other array takes their ids
    kept = reuse.reused(
        "surface digest", (id(depth), id(normals)), lambda: (normals, reuse.digest(depth, normals)), keep=depth
    )
    return kept[1]


REPLACED_PATCH_ROWS = 2
"""Patch rows per pool task of :meth:`Surface.replaced`: a band's direct shading (12 LEDs, 640 px wide, 8 px patches:
16 rows) takes 3 MB of float64, averaged into its patches while still in the cache. 1 to 8 timed alike within the
2-core VM's noise (53-63 ms of CPU for a cube press's auto ROI box)."""


class Surface:
    """The (reference or solved) surface as patches, with its direct shading per patch.

    Parameters
    ----------
    camera : Camera
    leds : sequence of Led
    depth : (H, W) float, mm (z), camera frame; NaN off the gel.
    normals : (H, W, 3) float, unit, camera frame, toward the camera.
    size : patch side, pixels (default :func:`patch_size`).
    shading : (L, H, W, 3) float64 or None -- :func:`direct_shading` of this surface when the caller
        has it already (None: computed here).
    radius : the LEDs' emitting disk radius, mm (``leds`` their centres and axes); 0: point LEDs. Every shading
        of the surface (its own, :meth:`replaced`'s, the off-view dome's at its gathers) uses it.
    """

    def __init__(
        self,
        camera: Camera,
        leds: Leds,
        depth: np.ndarray,
        normals: np.ndarray,
        size: int | None = None,
        shading: np.ndarray | None = None,
        radius: float = 0.0,
    ):
        self.camera, self.leds, self.radius = camera, tuple(leds), float(radius)
        self.valid = np.isfinite(depth)
        self.depth, self.normals = np.asarray(depth), np.asarray(normals)
        self.size = patch_size(camera) if size is None else int(size)
        pts = depth_to_points(np.where(self.valid, depth, 0.0), camera.rays)
        nrm = np.where(self.valid[..., None], normals, 0.0).astype(np.float64)
        self.patches = radiosity.surface_patches(pts, nrm, self.valid, camera, self.size)
        if shading is None:
            shading = direct_shading(camera, self.leds, depth, normals, self.radius)
        self.shading = radiosity.patch_mean(self.patches, shading)  # (L, h, w, 3) patch means
        self.keep = self.patches["area"] > 0

    def replaced(self, depth: np.ndarray, normals: np.ndarray, changed: np.ndarray) -> Surface:
        """This surface with ``depth`` and ``normals`` at the ``changed`` pixels (a solved region).

        Only the patches over the changed pixels' bounding box are recomputed (geometry and direct
        shading); the numbers equal those of a new ``Surface`` of the whole changed surface, the shading's patch
        means to ~1e-16 relative: they average each LED's channel-free falloff
        (:func:`~nlipscalib.core.leds.led_falloff`) and multiply by its Psi after, where a new ``Surface`` averages
        the three channels' shading. A third of the per-pixel work: 57 -> 42 ms of one core per call on a cube
        press's auto ROI, and the same result.npz on the twin's presses (benchmarks/RESULTS.md, s22-ind).

        By bands of :data:`REPLACED_PATCH_ROWS` patch rows on the thread pool, each band's pixels, patches and
        shading's patch means made together (each pixel's and each patch's own arithmetic: the same bits as the
        whole box at once). Why: the outer loop waits for it before every gather, and it ran the box's geometry
        and patches on the main thread (18 ms of a cube press's 336x332 auto ROI, 28 ms of a 640x480 frame) and
        wrote the box's per-pixel shading whole (32 MB and 88 MB of float64) before averaging it.

        Parameters
        ----------
        depth : (H, W) float, mm; normals : (H, W, 3) float, unit -- the new surface (read in the box).
        changed : (H, W) bool

        Returns
        -------
        Surface
        """
        new = copy.copy(self)
        if not changed.any():
            return new
        s, H = self.size, self.valid.shape[0]
        pr, pc, win = _patch_window(changed, s)
        depth, normals = np.asarray(depth), np.asarray(normals)
        new.valid, new.depth, new.normals = self.valid.copy(), self.depth.copy(), self.normals.copy()
        new.patches = dict(self.patches)
        for key in ("points", "normals", "area", "pixel_area"):
            new.patches[key] = self.patches[key].copy()
        new.shading = self.shading.copy()
        psi = led_arrays(self.leds)[3][:, None, None, :]  # (L, 1, 1, 3) each LED's intensity per channel

        def band(rows: slice) -> None:  # patch rows ``rows`` of the window: their pixels' geometry and shading
            patch_rows = slice(pr.start + rows.start, pr.start + rows.stop)
            px = (slice(patch_rows.start * s, min(patch_rows.stop * s, H)), win[1])
            d = np.where(changed[px], depth[px], self.depth[px])
            n = np.where(changed[px][..., None], normals[px], self.normals[px])
            valid = np.isfinite(d)
            pts = depth_to_points(np.where(valid, d, 0.0), self.camera.rays[px])
            nrm = np.where(valid[..., None], n, 0.0).astype(np.float64)
            sub = radiosity.surface_patches(
                pts, nrm, valid, self.camera, s, window=px, solid_angle=self.patches["solid_angle"]
            )
            falloff = disk_falloff(pts, nrm, self.leds, self.radius)  # led_falloff at radius 0
            falloff[:, ~valid] = 0.0
            new.valid[px], new.depth[px], new.normals[px] = valid, d, n
            for key in ("points", "normals", "area"):
                new.patches[key][patch_rows, pc] = sub[key]
            new.patches["pixel_area"][px] = sub["pixel_area"]
            # the channels' shading is the falloff times each LED's Psi: averaged once, then scaled per channel
            new.shading[:, patch_rows, pc] = radiosity.patch_mean(sub, falloff[..., None]) * psi

        threads.map_items(band, threads.chunks(pr.stop - pr.start, -(-(pr.stop - pr.start) // REPLACED_PATCH_ROWS)))
        new.keep = new.patches["area"] > 0
        return new

    def emitters(self) -> dict:
        """The kept patches as a gather's emitters (points, normals, area, and their cells on the patch grid)."""
        k = self.keep
        out = {key: self.patches[key][k] for key in ("points", "normals", "area")}
        out["cells"] = radiosity.patch_cells(k)
        return out

    def receivers(self) -> tuple[np.ndarray, np.ndarray]:
        return self.patches["points"][self.keep], self.patches["normals"][self.keep]

    def seen(self) -> dict:
        """The keywords of a gather among the kept patches that leaves out the pairs this surface hides from each
        other (:class:`radiosity.Occluders`): the occluders and the receivers' cells."""
        area = np.where(self.keep, self.patches["area"], 0.0)
        return {
            "occluders": radiosity.Occluders.of(self.patches["points"], area),
            "cells": radiosity.patch_cells(self.keep),
        }


def _patch_window(pixels: np.ndarray, size: int) -> tuple[slice, slice, tuple[slice, slice]]:
    """(patch rows, patch columns, pixel window) of the patches over the bounding box of ``pixels``
    ((H, W) bool, not empty); the pixel window starts on a patch boundary and ends with the image."""
    rows, cols = np.nonzero(pixels)
    H, W = pixels.shape
    pr, pc = slice(rows.min() // size, rows.max() // size + 1), slice(cols.min() // size, cols.max() // size + 1)
    return pr, pc, (slice(pr.start * size, min(pr.stop * size, H)), slice(pc.start * size, min(pc.stop * size, W)))


def _window_mean(patches: dict, values: np.ndarray, pr: slice, pc: slice, win: tuple[slice, slice]) -> np.ndarray:
    """:func:`radiosity.patch_mean` over the patches [pr, pc] only: ``values`` (L, h, w, 3) are the
    pixels of their window ``win`` (from :func:`_patch_window`); the same numbers as the whole image's."""
    sub = {"pixel_area": patches["pixel_area"][win], "area": patches["area"][pr, pc], "size": patches["size"]}
    return radiosity.patch_mean(sub, values)


def _gather_all(
    surface: Surface,
    factors: radiosity.FormFactors,
    rho_patch: np.ndarray,
    off_unit: np.ndarray | None,
    off_albedo: np.ndarray,
    bounces: int,
    kappa: np.ndarray | None = None,
):
    """G (L, K, 3) at the surface's patches: the visible patches' and the off-view dome's direct light,
    gathered once (and, with bounces=2, the first bounce's light gathered again, scaled by kappa).
    ``factors``: the surface's kept patches' pairwise terms (:func:`_surface_factors`); ``off_unit``: the
    off-view dome's gather for a unit albedo (linear in it), or None."""
    direct = rho_patch[None] * surface.shading[:, surface.keep]  # (L, K, 3)
    g = factors.gather(direct)
    if off_unit is not None:
        g = g + off_unit * np.asarray(off_albedo)
    if bounces >= 2 and kappa is not None:
        first = np.asarray(kappa)[None, None] * rho_patch[None] * g  # light leaving after one bounce
        g = g + factors.gather(first)
    return g


def _surface_factors(cache: dict) -> radiosity.FormFactors:
    """The pairwise terms of the fit's gathers (every kept patch of ``cache["surface"]`` lighting every other),
    made at the first gather and kept in ``cache``: every alternation of every fit sharing the cache (a press's
    rough fit and refit: four gathers) gathers over the same patches, only their light changes."""
    if "factors" not in cache:
        surf = cache["surface"]
        cache["factors"] = radiosity.FormFactors(*surf.receivers(), surf.emitters(), **surf.seen())
    return cache["factors"]


def fit_indirect(
    reference: Press,
    leds: Leds | None = None,
    *,
    mode: str = "auto",
    bounces: int = 1,
    iterations: int = 3,
    exclude: np.ndarray | None = None,
    shading: np.ndarray | None = None,
    cache: dict | None = None,
    warm: bool = False,
    radius: float = 0.0,
) -> IndirectModel:
    """Fit the indirect term to a capture of the undeformed dome (known geometry ``reference.reference``).

    Alternates (per channel) the per-pixel albedo rho_p (least squares over the LEDs of
    ``S + kappa G``) and kappa (least squares of ``I - rho S`` against ``rho G``), on patch means.

    Parameters
    ----------
    reference : Press -- the undeformed dome, with ``reference`` (depth, normals).
    leds : sequence of Led or None -- the LED model (default the capture's).
    mode : "auto" (apply when the fitted share is significant), "on" (always), "off" (fit nothing).
    bounces : 1 or 2 diffuse bounces.
    iterations : alternations of rho and kappa.
    exclude : (H, W) bool or None -- pixels not to fit on (a press's contact, when the press itself
        stands in for the undeformed capture); they still emit light.
    shading : (L, H, W, 3) float64, a :class:`~nlipscalib.solver.reuse.Deferred` of it, or None --
        :func:`direct_shading` of the reference surface with ``leds``, when the caller has it (None: computed
        here; a deferred one is read only when the surface's patches are not kept, :func:`reference_surface`).
    cache : dict or None -- shared by fits of the same capture with the same ``leds`` (e.g. a rough
        fit and a refit with a different ``exclude``): holds what does not depend on ``exclude``
        (patches, the off-view dome's light, the linear images, the gathers' pairwise terms), filled by the
        first fit.
    warm : start from the last fit that shared ``cache`` (its kappa and gathered light: the albedo starts as the
        least-squares one of ``S + kappa G``) instead of kappa = 0; a refit without a press's contact then needs
        an alternation fewer (``light_and_contact.REFIT_ALTERNATIONS``). Without an earlier fit in ``cache``: from
        kappa = 0.
    radius : the LEDs' emitting disk radius, mm (``leds`` their centres and axes: the solve's disks); 0: point
        LEDs. The term is fitted with the LED model the solve uses (:func:`term_shading`).

    Returns
    -------
    IndirectModel
    """
    if mode == "off":
        return IndirectModel((0.0,) * 3, (0.0,) * 3, 0.0, bounces, False, "interreflection off (requested)")
    if mode not in ("auto", "on"):
        raise ConfigError(f"interreflection must be auto, on or off, got {mode!r}")
    if reference.reference is None:
        raise CaptureError(f"{reference.folder}: the interreflection term needs the reference surface (reference.npz)")
    leds = reference.leds if leds is None else tuple(leds)
    cache = {} if cache is None else cache
    if not cache:
        cache.update(_fit_inputs(reference, leds, shading, radius))
    surf, off = cache["surface"], cache["off"]
    img, frac = _patch_data(cache, exclude)
    ok = frac > tolerances.INDIRECT_PATCH_USABLE  # patches wholly usable for that LED and channel
    S = surf.shading[:, surf.keep]
    fitted = ok.any(axis=0)  # (K, 3) patches with data
    if not fitted.any():
        why = no_light_reason(reference, surf.valid, cache["live"])
        raise CaptureError(f"{reference.folder}: no usable pixel to fit the interreflection term on{why}")
    start = cache.get("last") if warm else None
    kappa, G, off_albedo = _alternate(img, S, ok, cache, bounces, iterations, start)
    cache["last"] = (kappa, G)
    # the receiver's albedo multiplies both terms: the share is kappa G / S
    on = fitted.all(axis=1)
    share = float(np.median((kappa * G)[:, on].sum(axis=(0, 2)) / np.maximum(S[:, on].sum(axis=(0, 2)), 1e-30)))
    reflectance = tuple(float(k * a) for k, a in zip(kappa, off_albedo))
    enabled = mode == "on" or share >= tolerances.INDIRECT_MIN_SHARE
    reason = (
        f"interreflection {'on' if enabled else 'off'}: fitted indirect share {share:.3f} of the direct light "
        f"{AUTO_THRESHOLD_SAID}, coating reflectance {np.round(reflectance, 3).tolist()}"
        + (f"; {cache['design_note']}" if cache["design_note"] else "")
    )
    if mode == "on":
        reason += " (forced on)"
    light = np.zeros(surf.shading.shape, np.float32)
    light[:, surf.keep] = kappa * G  # per unit receiver albedo
    return IndirectModel(
        tuple(float(k) for k in kappa),
        reflectance,
        share,
        bounces,
        enabled,
        reason,
        off,
        tuple(float(a) for a in off_albedo),
        (light, surf.size),
    )


def fit_patch_share(
    reference: Press,
    leds: Leds,
    exclude: np.ndarray,
    *,
    shading: np.ndarray | reuse.Deferred | None = None,
    cache: dict | None = None,
    radius: float = 0.0,
) -> float:
    """The share of the patches :func:`fit_indirect` can fit on over the whole gel that it still can with
    ``exclude`` left out (0 when it can fit on none at all).

    A press that stands in for the undeformed capture leaves its contact out of its own fit; this says whether
    what is left (of an explicit ``--roi`` box's outside: none when the box covers the gel, a thin ring when it
    covers most of it) is enough to fit the term on (``light_and_contact``, :data:`tolerances.INDIRECT_FIT_MIN_SHARE`).

    Parameters
    ----------
    reference : Press -- the capture to fit on, with ``reference`` (depth, normals).
    leds : sequence of Led -- the LED model.
    exclude : (H, W) bool -- the pixels the fit would leave out.
    shading, cache, radius : as :func:`fit_indirect`'s; ``cache`` is filled here for the fit that follows, which
        then reads the patch data with this ``exclude`` from it instead of working them out again.
    """
    cache = {} if cache is None else cache
    if not cache:
        cache.update(_fit_inputs(reference, leds, shading, radius))
    every = (_patch_data(cache, None)[1] > tolerances.INDIRECT_PATCH_USABLE).any(axis=(0, 2)).sum()
    left = (_patch_data(cache, exclude)[1] > tolerances.INDIRECT_PATCH_USABLE).any(axis=(0, 2)).sum()
    return float(left / every) if every else 0.0


def _patch_data(cache: dict, exclude: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The kept patches' mean images and usable fractions, (L, K, 3) each, leaving out ``exclude`` (H, W) bool.

    The means over every pixel are worked out once per capture (kept in ``cache``); with ``exclude``, only the
    patches over the excluded pixels are recomputed, and kept in ``cache`` for the next call that leaves out the
    same pixels (:func:`fit_patch_share`'s, then the fit's: a box over most of a 640x480 frame recomputes most of
    the patches)."""
    last = cache.get("excluded")
    if exclude is not None and last is not None and np.array_equal(last[0], exclude):
        return last[1]
    data = _patch_data_uncached(cache, exclude)
    if exclude is not None:
        cache["excluded"] = (exclude.copy(), data)  # a copy: the caller's array may change after
    return data


def _patch_data_uncached(cache: dict, exclude: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_patch_data` worked out."""
    surf, lin, usable = cache["surface"], cache["linear"], cache["usable"]
    if "image_means" not in cache:
        if usable is None:  # every sample of the gel usable: the patch weights, zero off the gel, mask alone
            cache["image_means"] = radiosity.patch_mean(surf.patches, lin)
            one = radiosity.patch_mean(surf.patches, _usable(cache, (slice(None), slice(None))))
            cache["usable_means"] = np.broadcast_to(one, (len(lin),) + one.shape[1:])  # each LED's alike
        else:
            cache["image_means"] = radiosity.patch_mean(surf.patches, lin * usable)
            cache["usable_means"] = radiosity.patch_mean(surf.patches, usable)
    img, frac = cache["image_means"], cache["usable_means"]
    if exclude is not None and exclude.any():
        pr, pc, win = _patch_window(exclude, surf.size)
        usable = _usable(cache, win)  # a copy
        usable[:, exclude[win]] = 0.0
        sub_lin = lin[:, win[0], win[1]]
        img, frac = img.copy(), frac.copy()
        img[:, pr, pc] = _window_mean(surf.patches, sub_lin * usable, pr, pc, win)
        frac[:, pr, pc] = _window_mean(surf.patches, usable, pr, pc, win)
    return img[:, surf.keep], frac[:, surf.keep]


def _usable(cache: dict, window: tuple[slice, slice]) -> np.ndarray:
    """(L, h, w, 3) or (1, h, w, 3) float32, a new array -- 1 where a sample of the pixels in ``window`` (rows,
    columns) is usable, else 0 (off the gel, saturated, or of a dead LED): ``cache["usable"]`` there, or, when that
    is None (every sample of the gel usable), the gel's mask, the same for every LED."""
    usable = cache["usable"]
    if usable is not None:
        return usable[:, window[0], window[1]].copy()
    gel = cache["surface"].valid[window]
    return np.repeat(gel[None, ..., None], 3, axis=3).astype(np.float32)


def _alternate(
    img: np.ndarray,
    S: np.ndarray,
    ok: np.ndarray,
    cache: dict,
    bounces: int,
    iterations: int,
    start: tuple[np.ndarray, np.ndarray] | None = None,
):
    """Alternate the per-patch albedo and kappa ``iterations`` times (G depends on the emitters' albedo):
    (kappa (3,), G (L, K, 3) the gathered light per unit kappa, the off-view dome's albedo (3,)).

    ``img`` (L, K, 3) patch means, ``S`` (L, K, 3) their direct shading, ``ok`` (L, K, 3) wholly usable;
    ``cache``: :func:`fit_indirect`'s (the surface, the off-view dome's unit light, the pairwise terms)."""
    fitted = ok.any(axis=0)
    kappa, G = (np.zeros(3), np.zeros_like(S)) if start is None else start
    rho = _albedo(img, S if start is None else S + kappa * G, ok)

    def typical(values: np.ndarray):  # median over the patches with data; the others take it as their albedo
        return np.array([np.median(values[fitted[:, c], c]) if fitted[:, c].any() else 0.0 for c in range(3)])

    off_albedo = typical(rho)

    for _ in range(iterations):
        rho = np.where(fitted, rho, typical(rho))
        off_albedo = typical(rho)
        G = _gather_all(cache["surface"], _surface_factors(cache), rho, cache["off_unit"], off_albedo, bounces, kappa)
        # reflectance = kappa x albedo is at most 1: on very noisy or tiny captures the free fit can
        # exceed it (seen: 1.16 at 96x72, 2 spp), and an unphysical term then derails the solve
        kappa = np.minimum(_profile_kappa(img, S, G, ok), 1.0 / np.maximum(off_albedo, 1e-30))
        rho = _albedo(img, S + kappa * G, ok)
    return kappa, G, off_albedo


def _fit_inputs(reference: Press, leds: Leds, shading: np.ndarray | reuse.Deferred | None, radius: float = 0.0) -> dict:
    """What :func:`fit_indirect` needs besides ``exclude``: the surface as patches, the off-view dome
    and its light for a unit albedo (both the sensor's alone: reused, :mod:`.reuse`), the linear
    images, the usable samples and the live LEDs. ``radius``: the LEDs' disk radius, mm (0: points)."""
    ref = reference.reference
    size = fit_patch_size(reference.camera)
    surf = reference_surface(reference.camera, leds, ref.depth, ref.normals, size, shading, radius)
    design, design_note = capture_design(reference.meta)
    off = off_unit = None
    if design is not None:
        # the surface's digest, not the depth's alone: the light is gathered at its patches' points and normals
        surface = surface_digest(ref.depth, ref.normals)
        key = (reference.camera, term_key(leds, radius), surf.size, repr(design[0]), tuple(design[1]), surface)
        off, off_unit = reuse.reused(
            "off_view", key, lambda: _off_view_light(reference.camera, leds, surf, design), persist=True
        )
    # float32 (as loaded) is enough: the patch means multiply by float64 areas and sum in float64, and
    # a 0/1 usable mask multiplies exactly; float64 copies of these (L, H, W, 3) arrays cost 0.25 s
    lin = reference.linear_led_images
    live = lit_leds(led_levels(lin, surf.valid))
    saturated = reference.saturated_led_images
    usable = None  # the usual case, every LED live and nothing saturated on the gel: no (L, H, W, 3) mask
    if not live.all() or (saturated.any() and saturated[:, surf.valid].any()):
        usable = (~saturated).astype(np.float32)
        usable[:, ~surf.valid] = 0.0
        usable[~live] = 0.0  # a dead LED's dark image says nothing about the light
    return {
        "surface": surf,
        "off": off,
        "off_unit": off_unit,
        "design_note": design_note,
        "linear": lin,
        "usable": usable,
        "live": live,
    }


def _off_view_light(
    camera: Camera, leds: Leds, surf: Surface, design: tuple[DomeConfig, np.ndarray]
) -> tuple[dict, np.ndarray]:
    """The dome beyond the view as patches, and its direct light (``surf``'s LED model, :attr:`Surface.radius`)
    gathered at ``surf`` for a unit albedo."""
    off = radiosity.off_view_patches(design[0], design[1], camera, surf.valid, step_deg=3.0)
    off_s = term_shading(off["points"], off["normals"], leds, surf.radius)
    return off, radiosity.gather(*surf.receivers(), off, off_s)


def _albedo(img: np.ndarray, model: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(K, 3) least-squares albedo per patch and channel of img ~ rho * model over the LEDs."""
    num = (img * model * ok).sum(0)
    den = (model * model * ok).sum(0)
    return num / np.maximum(den, 1e-30)


def _profile_kappa(
    img: np.ndarray,
    S: np.ndarray,
    G: np.ndarray,
    ok: np.ndarray,
    kappa_max: float | None = None,
    steps: int | None = None,
) -> np.ndarray:
    """(3,) kappa >= 0 minimising the residual of img ~ rho_p (S + kappa G) with every patch's rho_p
    profiled out (its least-squares value for that kappa): a 1-D search per channel, exact for the
    per-patch albedo (alternating rho and kappa would crawl: G and S are strongly correlated over LEDs).

    With M = S + kappa G, the profiled residual of a patch is sum I^2 - (a + kappa b)^2 / (c + 2 kappa d
    + kappa^2 e) with a = sum I S, b = sum I G, c = sum S S, d = sum S G, e = sum G G over the LEDs.

    ``steps``: points of the coarse grid that finds the best kappa's neighbourhood (default
    :data:`KAPPA_GRID_STEPS`); Newton's method on the gain's slope then finishes it (:func:`_profile_channel`).
    """
    steps = KAPPA_GRID_STEPS if steps is None else steps
    w = ok.astype(np.float64)
    a, b = (w * img * S).sum(0), (w * img * G).sum(0)
    c, d, e = (w * S * S).sum(0), (w * S * G).sum(0), (w * G * G).sum(0)
    # the channels are independent searches: one per pool task (three in turn took ~13 ms of one core per call
    # at 640x480 while the other waited; the same operations per channel, so the same bits)
    per_channel = [[np.ascontiguousarray(x[:, ch]) for x in (a, b, c, d, e)] for ch in range(3)]
    return np.array(threads.map_items(lambda sums: _profile_channel(sums, kappa_max, steps), per_channel))


def _profile_channel(sums: list[np.ndarray], kappa_max: float | None, steps: int) -> float:
    """:func:`_profile_kappa`'s search in one channel: ``sums`` the per-patch sums a .. e (K,) float64 of that
    channel; 0 when no patch has both terms, or when the gain falls from kappa = 0 on.

    A coarse grid over [0, top] brackets the best kappa between the best grid point's neighbours; Newton's method
    on the gain's slope (safeguarded by bisection of the bracket) then finds where the slope is zero, to
    :data:`KAPPA_REL_TOL` of ``top``. Why not grids all the way: the 400-point grid and three 50-point
    refinements it replaces took 15-17 ms of one core per call (three calls in a press's fits) for an answer
    0.2-3.3e-6 (relative) from the gain's maximum; this takes ~1.3 ms (benchmarks/RESULTS.md, s22-ind)."""
    a, b, c, d, e = sums
    # kappa G comparable to S at most: search up to the ratio that makes them equal
    has = (c > 0) & (d > 0)
    if not has.any():
        return 0.0
    top = kappa_max or float(10 * np.median(c[has]) / np.median(d[has]))
    ks = np.linspace(0.0, top, steps)
    gain = _profile_gain(*sums, ks, np.empty((len(a), steps)), np.empty((len(a), steps)))
    i = int(np.argmax(gain))
    low, high, kappa = ks[max(i - 1, 0)], ks[min(i + 1, steps - 1)], ks[i]
    live = [x[(c > 0) | (e > 0)] for x in sums]  # a patch left out (no usable sample) has every sum 0
    if i == 0 and _profile_slopes(*live, 0.0)[0] <= 0:
        return 0.0  # the gain falls from kappa = 0: no indirect light in this channel
    for _ in range(_KAPPA_NEWTON_STEPS):
        slope, curvature = _profile_slopes(*live, kappa)
        if slope > 0:
            low = kappa
        else:
            high = kappa
        step = kappa - slope / curvature if curvature < 0 else None
        new = step if step is not None and low < step < high else 0.5 * (low + high)
        done = abs(new - kappa) <= KAPPA_REL_TOL * top
        kappa = new
        if done:
            break
    return float(kappa)


KAPPA_GRID_STEPS = 100
"""Points of :func:`_profile_kappa`'s coarse grid over [0, top] (top: kappa G ten times S). On the twin's one-bounce
640x480 presses the best kappa is ~top / 30, so the best point's neighbours bracket it within ~a third of it."""
KAPPA_REL_TOL = 1e-12
"""Newton's last step in :func:`_profile_channel`, relative to the search's range, below which kappa is taken."""
_KAPPA_NEWTON_STEPS = 60
"""Most Newton (or bisection) steps of :func:`_profile_channel` (each halves the bracket at least when bisecting)."""


def _profile_slopes(
    a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, e: np.ndarray, kappa: float
) -> tuple[float, float]:
    """(first, second) derivative in kappa of :func:`_profile_gain`'s sum of (a + k b)^2 / (c + 2 k d + k^2 e) at
    k = ``kappa``; ``a`` .. ``e`` (K,) float64 per-patch sums of patches with c > 0 or e > 0 (D > 0)."""
    n = a + kappa * b
    den = c + 2 * kappa * d + kappa * kappa * e
    slope_den = 2 * (d + kappa * e)
    first = 2 * n * b / den - n * n * slope_den / den**2
    second = (
        2 * b * b / den - 4 * n * b * slope_den / den**2 - 2 * n * n * e / den**2 + 2 * (n * slope_den) ** 2 / den**3
    )
    return float(first.sum()), float(second.sum())


def _profile_gain(
    a: np.ndarray,
    b: np.ndarray,
    c: np.ndarray,
    d: np.ndarray,
    e: np.ndarray,
    ks: np.ndarray,
    num: np.ndarray,
    den: np.ndarray,
) -> np.ndarray:
    """(n,) -- sum over the patches of (a + k b)^2 / (c + 2 k d + k^2 e) at each k of ``ks`` (n,): the part of
    :func:`_profile_kappa`'s profiled residual that depends on kappa. ``a`` .. ``e`` (K,) float64 per-patch sums;
    ``num``, ``den`` (K, n) float64 scratch, overwritten. In place, no fresh (K, n) temporaries: 15 -> 13 ms a
    call inside a 640x480 solve (1,200 patches), 41 -> 18 ms in a process whose allocator hands out fresh pages
    for them; the same operations in the same order, so the same bits."""
    np.multiply(b[:, None], ks, out=num)
    num += a[:, None]
    np.square(num, out=num)
    np.multiply(2 * ks, d[:, None], out=den)
    np.add(c[:, None], den, out=den)
    den += ks**2 * e[:, None]
    np.maximum(den, 1e-300, out=den)
    num /= den
    return num.sum(0)


def surface_indirect(
    model: IndirectModel,
    camera: Camera,
    leds: Leds,
    depth: np.ndarray,
    normals: np.ndarray,
    albedo: np.ndarray,
    receivers: np.ndarray,
    size: int | None = None,
    shading: np.ndarray | None = None,
    surface: Surface | None = None,
    window: tuple[slice, slice] | None = None,
    radius: float = 0.0,
) -> np.ndarray:
    """Indirect light ``B = kappa rho_p G(p)`` of a surface, at the receiver pixels.

    Parameters
    ----------
    model : IndirectModel -- from :func:`fit_indirect` (enabled).
    camera : Camera
    leds : sequence of Led, length L
    depth : (H, W) float, mm (z), camera frame -- the whole visible surface (solved where known, the
        undeformed reference elsewhere); NaN off the gel.
    normals : (H, W, 3) float, unit, camera frame, toward the camera.
    albedo : (H, W, 3) float -- linear albedo rho per pixel (``SolveResult.albedo`` scale).
    receivers : (H, W) bool -- pixels that need the term (the solve's mask).
    size : patch side, pixels (default :func:`patch_size`; the undeformed dome's smooth light needs
        no more than :func:`fit_patch_size`).
    shading : (L, H, W, 3) float64 or None -- :func:`direct_shading` of this surface, when the caller
        has it; None: computed here.
    surface : Surface or None -- this surface as patches when the caller has it (e.g. from
        :meth:`Surface.replaced`); ``depth``, ``normals``, ``size`` and ``shading`` are then not read.
    window : (rows, columns) slices or None -- the part of the frame to return; it holds every receiver (the
        outer loop's box: no whole-frame array per pass, whose pages cost ~35 ms to touch at 640x480). None:
        the whole frame.
    radius : the LEDs' disk radius, mm, of a surface made here (0: points; ``surface`` carries its own).

    Returns
    -------
    (L, H, W, 3) float32, or (L, h, w, 3) over ``window`` -- linear image units (``Press.linear`` scale); 0
    outside ``receivers``.
    """
    surf = surface if surface is not None else Surface(camera, leds, depth, normals, size, shading, radius)
    albedo, rho_patch = _gel_albedo(surf, albedo)
    size = surf.size
    h, w = surf.patches["area"].shape
    H, W = camera.shape
    grid = np.zeros((h * size, w * size), bool)
    grid[:H, :W] = receivers
    want = grid.reshape(h, size, w, size).any(axis=(1, 3))
    # one patch of margin, diagonals too, so the bilinear upsampling never blends with an unset neighbour
    want = _dilate(want) & surf.keep
    G_all = _gather_at(surf, rho_patch, model, want)
    g = np.zeros((len(surf.leds), h, w, 3), np.float32)
    g[:, want] = G_all
    rows, cols = (range(H), range(W)) if window is None else (range(H)[window[0]], range(W)[window[1]])
    if receivers[rows.start : rows.stop, cols.start : cols.stop].sum() != receivers.sum():
        raise ValueError(f"the window {window} must hold every receiver")
    B = np.zeros((len(surf.leds), len(rows), len(cols), 3), np.float32)
    if not receivers.any():
        return B
    # upsample only the patches around the receivers (one patch of margin: the bilinear weights of every
    # receiver pixel then come from inside the window, the same numbers as upsampling the whole grid)
    pr, pc, _ = _patch_window(receivers, size)
    pr, pc = slice(max(pr.start - 1, 0), min(pr.stop + 1, h)), slice(max(pc.start - 1, 0), min(pc.stop + 1, w))
    win = (slice(pr.start * size, min(pr.stop * size, H)), slice(pc.start * size, min(pc.stop * size, W)))
    per_led = radiosity.Upsampled(g[:, pr, pc], (win[0].stop - win[0].start, win[1].stop - win[1].start), size)
    # the patch window's part inside the returned one (outside it: no receiver, no light)
    r0, r1 = max(win[0].start, rows.start), min(win[0].stop, rows.stop)
    c0, c1 = max(win[1].start, cols.start), min(win[1].stop, cols.stop)
    scaled_into(
        B[:, r0 - rows.start : r1 - rows.start, c0 - cols.start : c1 - cols.start],
        per_led,
        (slice(r0 - win[0].start, r1 - win[0].start), slice(c0 - win[1].start, c1 - win[1].start)),
        np.asarray(model.kappa, np.float32) * albedo[r0:r1, c0:c1].astype(np.float32),
        ~receivers[r0:r1, c0:c1],
    )
    return B


def _gel_albedo(surf: Surface, albedo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the albedo on the gel, NaN read as 0 and 0 off it, (H, W, 3); its patch means (h, w, 3) float64) of
    ``albedo`` (H, W, 3) on ``surf``, by bands of patch rows on the thread pool.

    Why: both are whole-frame passes, of an auto ROI's solve too, and ran on the main thread in each outer pass
    while the other core waited (~6 ms of one core warm, 13-20 ms with the fresh pages of a solve, at 640x480).
    Each pixel's own arithmetic, and each patch's mean from its own pixels (:func:`_window_mean`), so the same
    numbers as over the whole frame at once."""
    size, valid = surf.size, surf.valid
    clean = np.empty(albedo.shape, np.result_type(albedo, 0.0))
    rho_patch = np.empty(surf.patches["area"].shape + albedo.shape[2:])

    def band(pr: slice) -> None:
        rows = slice(pr.start * size, min(pr.stop * size, len(clean)))
        clean[rows] = np.where(valid[rows][..., None], np.nan_to_num(albedo[rows]), 0.0)
        rho_patch[pr] = _window_mean(surf.patches, clean[rows], pr, slice(None), (rows, slice(None)))

    threads.map_items(band, threads.chunks(len(rho_patch)))
    return clean, rho_patch


def scaled_into(
    out: np.ndarray, per_led: radiosity.Upsampled, part: tuple[slice, slice], scale: np.ndarray, dark: np.ndarray
) -> None:
    """``out[i] = scale * per_led[i][part]``, 0 where ``dark``, one LED per task on the thread pool.

    ``out`` (L, h, w, 3) float32, written; ``per_led`` the upsampled patch light; ``part`` (rows, columns) of its
    images that ``out`` holds; ``scale`` (h, w, 3) or (3,) float32, e.g. kappa times the albedo; ``dark`` (h, w)
    bool, no receiver. Also the outer loop's first light (``outer_loop._first_light``).

    Why: on a 640x480 whole frame the upsampling, the product, the zeroing and the copy into the result, each over
    (L, H, W, 3) float32 arrays of 44 MB, took 0.13-0.21 s of one core in the last outer pass while the other waited
    (0.10 s now, both cores; sphere1). Per LED the same operations in the same order, so the same bits as all LEDs
    at once.

    The scale and the dark pixels are spelt out per channel first, (h, w, 3): a product with a (3,) scale and a
    zeroing by an (h, w) mask ran three elements per inner loop (1.3 and 1.4 ms per LED at 640x480, against 0.4
    and 0.9 ms); the same values per element."""
    scale = np.ascontiguousarray(np.broadcast_to(scale, out.shape[1:]))
    # an auto ROI's box lies on the gel throughout: no pixel to zero, and the zeroing's pass (~4 ms a pass) skipped
    dark = np.repeat(dark[..., None], out.shape[-1], axis=-1) if dark.any() else None

    def one_led(i: int) -> None:
        np.multiply(scale, per_led[i][part], out=out[i])
        if dark is not None:
            np.copyto(out[i], 0.0, where=dark)

    threads.map_items(one_led, range(len(per_led)))


def _dilate(mask: np.ndarray) -> np.ndarray:
    """``mask`` (h, w) bool of patches grown by its 8-neighbourhood: every patch a bilinear weight of its pixels
    reaches (by the cross, the diagonal patch was left out: unset, 0, it was blended into a receiver box's corner
    pixels, up to ~0.06 deg of normals at a few dozen pixels of /tmp/keep's presses; benchmarks/RESULTS.md,
    s35-wideedge)."""
    return masks.dilate(mask, iterations=1, structure=masks.SQUARE)


def _gather_at(surf: Surface, rho_patch: np.ndarray, model: IndirectModel, want: np.ndarray) -> np.ndarray:
    """(L, n, 3) G at the patches ``want`` (visible surface and off-view dome as emitters).

    The visible surface's light goes through :func:`radiosity.gather_grid` (far patches grouped: a fifth of the
    pairwise terms at 640x480, the light within ~1 % of the exact gather's); the fit on the undeformed dome
    (:func:`_gather_all`) keeps the exact gather, on its coarser patches."""
    keep = surf.keep
    area = np.where(keep, surf.patches["area"], 0.0)
    points, normals = surf.patches["points"], surf.patches["normals"]
    direct = rho_patch[None] * surf.shading
    direct[:, ~keep] = 0.0
    g = radiosity.gather_grid(points, normals, area, direct, want)
    off = model.off_view
    off_direct = None
    if off is not None:
        off_direct = term_shading(off["points"], off["normals"], surf.leds, surf.radius)
        off_direct = off_direct * np.asarray(model.off_view_albedo)
        # the dome beyond the view is seen from every patch (no visibility test): its segments leave the view, and
        # the undeformed dome there hides nothing; on the bench's sphere press the dent hid 0.06 % of its light at
        # the dent's patches (2 % at most), and testing it took 8 times the gather's time (0.15 against 0.012 s)
        g = g + radiosity.gather(points[want], normals[want], off, off_direct)
    if model.bounces >= 2:
        # second bounce: the first bounce's light over the whole visible surface, gathered again
        g1 = radiosity.gather_grid(points, normals, area, direct, keep)
        if off is not None:
            g1 = g1 + radiosity.gather(points[keep], normals[keep], off, off_direct)
        second = np.zeros_like(direct)
        second[:, keep] = np.asarray(model.kappa)[None, None] * rho_patch[keep][None] * g1
        g = g + radiosity.gather_grid(points, normals, area, second, want)
    return g
