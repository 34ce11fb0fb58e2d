"""Diffuse interreflection of the gel surface: a radiosity gather over surface patches.

Physics followed: the radiosity equation for Lambertian surfaces (Goral, Torrance, Greenberg &
Battaile, "Modeling the interaction of light between diffuse surfaces", SIGGRAPH 1984; Cohen &
Wallace, *Radiosity and Realistic Image Synthesis*, 1993, ch. 2), truncated after one or two bounces
(the Neumann series of the radiosity operator, each term one more bounce), with the point-to-patch
form factor ``cos_p cos_q A_q / (pi r^2)`` times the pair's visibility V_pq in {0, 1} (the cosines cut back
faces). The surface is a depth map over the image, so V is a screen-space test against it (:func:`_hidden`): a
pair is hidden where a patch between them on the image stands on the camera's side of their segment. The
undeformed dome, concave as the camera sees it, hides nothing (its gathers are those without the test, bit
for bit); a bump pressed 1.5 mm proud of the gel hides, from its flanks, part of the gel beyond it, whose light
the term without V over-counted by ~1.5 % of the direct light of the LEDs on the contact's side and leaned the
solved normals outward (docs/experiments/RESULTS.md, issue 6). The dome beyond the view is not tested (seen from
every patch). The same one-bounce term is what Nayar, Ikeuchi & Kanade ("Shape from interreflections", IJCV
1991) add to photometric stereo.

In linear image units (``Press.linear`` = exposure * a/pi * irradiance, so rho = exposure * a/pi up to
the LED intensity gauge), light leaving patch q with linear value D_q = rho_q S_q (direct shading S of
:func:`nlipscalib.core.leds.led_shading`) reaches receiver p and leaves it as::

    B(p) = (a_p / pi) * sum_q D_q V_pq max(0, n_p . w_pq) max(0, n_q . w_qp) A_q / r_pq^2

The receiver's dimensionless reflectance a_p is proportional to its linear albedo (a_p = kappa rho_p,
kappa = pi / exposure in the LED gauge), so ``B(p) = kappa rho_p G(p)`` with
``G(p) = (1/pi) sum_q D_q (cos cos A / r^2)``: one global constant per channel, which
:mod:`nlipscalib.solver.indirect` fits to the capture of the undeformed dome.

:func:`gather` sums every receiver-emitter pair; :func:`gather_grid`, for a surface's patch grid, lights a tile of
receivers with far clusters of patches as single aggregate patches (two-level hierarchical radiosity, Hanrahan,
Salzman & Aupperle 1991), a fifth of the pairs at 640x480 for an error of the light of ~1 % at most near a dent.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from ..core import tolerances
from ..core.blas import blas_threads, serial_matmul
from ..core.camera import Camera, pixel_derivatives
from ..core.dome import dome_inward_normals, project_to_dome
from ..core.sensor import DomeConfig
from ..core.tolerances import NORMAL_EPS
from . import threads


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
    per_pixel = values.shape[1:] if values.ndim == 4 else values.shape  # (H, W, ...) of one image
    extra = (1,) * (len(per_pixel) - 2)
    # the weights spelt out over the channels (the same products): broadcast along a length-1 last axis, NumPy
    # multiplies three elements per inner loop (1.3 against 0.8 ms per 640x480 RGB image)
    w = np.ascontiguousarray(np.broadcast_to(w.reshape(w.shape + extra), per_pixel))
    per_area = per_area.reshape(per_area.shape + extra)
    if values.ndim == 4:
        return np.stack(threads.map_items(lambda v: block_sum(v * w, size) * per_area, values))
    return block_sum(values * w, size) * per_area


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
    points: np.ndarray,
    normals: np.ndarray,
    emitters: dict,
    radiance: np.ndarray,
    chunk: int | None = None,
    occluders: Occluders | None = None,
    cells: np.ndarray | None = None,
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
    occluders : Occluders or None -- the surface that hides pairs from each other (:func:`_hidden`); None: every
        pair sees the other (the cosines alone cut back faces). With it, ``cells`` (M, 2) float, the receivers'
        (row, column) on its patch grid, and ``emitters["cells"]`` (K, 2) the emitters' (:func:`patch_cells`).

    Returns
    -------
    (L, M, 3) float32 -- linear image units per unit receiver reflectance.

    Notes
    -----
    Every pairwise term is a matrix product (r^2 = |p|^2 + |q|^2 - 2 p.q, r cos_p = n_p.q - n_p.p,
    r cos_q = n_q.p - n_q.q), so BLAS does the M x K work.
    """
    pairs = _Pairs(points, normals, emitters, chunk, occluders, cells)
    return _gather_blocks(pairs, pairs.factors, radiance)


def _gather_blocks(pairs: _Pairs, factors_of: Callable[[int], np.ndarray], radiance: np.ndarray) -> np.ndarray:
    """(L, M, 3) float32 -- each block's pairwise terms ``factors_of(s)`` (chunk, K) times the radiance rows, on
    the pool: one copy for :func:`gather` (terms made per block) and :meth:`FormFactors.gather` (terms kept)."""
    rad = _radiance_rows(radiance)
    out = np.empty((pairs.receivers, rad.shape[1]), np.float32)

    def block(s: int) -> None:
        out[s : s + pairs.chunk] = serial_matmul(factors_of(s), rad)  # the same bits whatever BLAS's thread count

    pairs.on_pool(block)
    return _gathered(out, len(radiance))


class FormFactors:
    """:func:`gather`'s pairwise terms between fixed receivers and emitters, made once and applied to several
    radiances: ``FormFactors(points, normals, emitters).gather(radiance)`` has the same bits as ``gather(points,
    normals, emitters, radiance)`` (the same blocks, each the same product).

    Why: the indirect term's fit (:func:`nlipscalib.solver.indirect.fit_indirect`) gathers the light of the same
    patches once per alternation, four times in a press's rough fit and refit, and the terms cost ten times their
    product with the light (1,200 x 1,200 patches at 640x480: ~12 ms against ~1 ms of one core). Holds them:
    receivers x emitters float32 (5.8 MB at 1,200 patches).

    Parameters
    ----------
    points, normals, emitters, chunk, occluders, cells : as :func:`gather`'s.
    """

    def __init__(
        self,
        points: np.ndarray,
        normals: np.ndarray,
        emitters: dict,
        chunk: int | None = None,
        occluders: Occluders | None = None,
        cells: np.ndarray | None = None,
    ):
        self._pairs = _Pairs(points, normals, emitters, chunk, occluders, cells)
        self._blocks: dict[int, np.ndarray] = {}

        def block(s: int) -> None:
            self._blocks[s] = self._pairs.factors(s)

        self._pairs.on_pool(block)

    def gather(self, radiance: np.ndarray) -> np.ndarray:
        """(L, M, 3) float32 -- :func:`gather` of ``radiance`` (L, K, 3) from these emitters at these receivers."""
        return _gather_blocks(self._pairs, self._blocks.__getitem__, radiance)


class _Pairs:
    """The receivers and emitters of :func:`gather` as float64 arrays, cut into blocks of ``chunk`` receivers (the
    same blocks whatever the thread count, so the same bits)."""

    def __init__(
        self,
        points: np.ndarray,
        normals: np.ndarray,
        emitters: dict,
        chunk: int | None,
        occluders: Occluders | None = None,
        cells: np.ndarray | None = None,
    ):
        if occluders is not None and (cells is None or emitters.get("cells") is None):
            raise ValueError("a gather with occluders needs the receivers' cells and the emitters' 'cells'")
        cells_q = None if occluders is None else emitters["cells"]
        self.emitters = _Emitters.of(emitters["points"], emitters["normals"], emitters["area"], cells_q)
        self.pr = np.asarray(points, np.float64)
        self.nr = np.asarray(normals, np.float64)
        self.occluders = occluders
        self.cells = None if cells is None else np.asarray(cells, np.float32)
        self.receivers = len(self.pr)
        self.chunk = chunk or max(16, GATHER_BLOCK_FLOATS // max(len(self.emitters.points), 1))

    def factors(self, s: int) -> np.ndarray:
        """(chunk, K) float32 -- :func:`_pair_factors` of the receivers from ``s`` on."""
        c = self.chunk
        seen = None if self.occluders is None else (self.occluders, self.cells[s : s + c])
        return _pair_factors(self.pr[s : s + c], self.nr[s : s + c], self.emitters, seen)

    def on_pool(self, block: Callable[[int], None]) -> None:
        """``block(s)`` for every block's first receiver ``s``: the blocks split over the thread pool, BLAS on one
        thread (its own threads on these small products synchronised more than they computed; the products' bits do
        not rely on it: :func:`nlipscalib.core.blas.serial_matmul`)."""
        starts = list(range(0, self.receivers, self.chunk))

        def part(blocks: list[int]) -> None:
            for s in blocks:
                block(s)

        with blas_threads(1):
            threads.map_items(lambda p: part(starts[p]), threads.chunks(len(starts)) if starts else [])


def _radiance_rows(radiance: np.ndarray) -> np.ndarray:
    """(K, L*3) float32, C-contiguous -- (L, K, 3) radiance as the rows a block of pairwise terms multiplies."""
    L = radiance.shape[0]
    return np.ascontiguousarray(np.asarray(radiance, np.float32).transpose(1, 0, 2).reshape(-1, L * 3))


def _gathered(rows: np.ndarray, leds: int) -> np.ndarray:
    """(L, M, 3) float32 G from the (M, L*3) products of the pairwise terms with the radiance rows (pi G)."""
    return rows.reshape(-1, leds, 3).transpose(1, 0, 2) / np.float32(np.pi)


class _Emitters(NamedTuple):
    """The k emitter patches of a gather, with the two per-emitter terms every receiver's pairs use."""

    points: np.ndarray
    """(k, 3) float64, mm."""
    normals: np.ndarray
    """(k, 3) float64, unit."""
    area: np.ndarray
    """(k,) float32, mm^2."""
    sq_norm: np.ndarray
    """(k,) float64: ``|q|^2`` of each point q."""
    normal_dot_point: np.ndarray
    """(k,) float64: ``n_q . q``."""
    cells: np.ndarray | None = None
    """(k, 2) float32 or None: each emitter's place on the patch grid (row, column, :func:`patch_cells`; finite, off
    the grid too), where :func:`_hidden`'s segments end; None: no visibility test."""

    @classmethod
    def of(
        cls, points: np.ndarray, normals: np.ndarray, area: np.ndarray, cells: np.ndarray | None = None
    ) -> _Emitters:
        pe, ne = np.asarray(points, np.float64), np.asarray(normals, np.float64)
        cells = None if cells is None else np.asarray(cells, np.float32)
        return cls(pe, ne, np.asarray(area, np.float32), np.sum(pe * pe, axis=1), np.sum(ne * pe, axis=1), cells)

    def take(self, idx: np.ndarray) -> _Emitters:
        """The emitters ``idx`` (an index array) of these."""
        return _Emitters(*(None if a is None else a[idx] for a in self))


class Occluders(NamedTuple):
    """A surface as the camera sees it, on its patch grid: what can hide one patch from another (:func:`_hidden`).

    Make it with :meth:`of`; the gathers that take it (:func:`gather`, :class:`FormFactors`, :func:`gather_grid`)
    then drop the pairs whose straight segment passes behind it."""

    points: np.ndarray
    """(h + 2, w + 2, 3) float32, mm, camera frame -- the patches' centroids with a border of one patch; NaN where
    there is no surface (off the gel, the border): nothing hides there."""
    box: tuple[float, float, float, float] | None
    """(first row, last row, first column, last column) on the bordered grid around the patches that can hide
    others (:func:`_proud`), or None where none can (a flat or concave surface: the undeformed dome)."""

    @classmethod
    def of(cls, points: np.ndarray, area: np.ndarray) -> Occluders:
        """Of a patch grid: ``points`` (h, w, 3) float, mm, camera frame; ``area`` (h, w) float, 0 where no patch."""
        h, w = area.shape
        grid = np.full((h + 2, w + 2, 3), np.nan, np.float32)
        grid[1:-1, 1:-1] = np.where((np.asarray(area) > 0)[..., None], points, np.nan)
        rows, cols = np.nonzero(_proud(grid))
        if not len(rows):
            return cls(grid, None)
        m = VISIBILITY_BOX_MARGIN
        return cls(grid, (rows.min() - m, rows.max() + m, cols.min() - m, cols.max() + m))


def _above(s: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(...) float32, mm -- how far the points ``s`` stand on the camera's side of the lines through ``a`` and ``b``
    (all (..., 3) float32, camera frame, the camera at the origin), measured in the plane through the camera and
    the line, perpendicular to it; NaN where a point is NaN."""
    u = b - a
    along = np.einsum("...c,...c->...", a, u) / np.maximum(np.einsum("...c,...c->...", u, u), np.float32(1e-12))
    toward_cam = along[..., None] * u - a  # from the line to the camera, perpendicular to it
    norm = np.sqrt(np.einsum("...c,...c->...", toward_cam, toward_cam))
    return np.einsum("...c,...c->...", s - a, toward_cam) / np.maximum(norm, np.float32(1e-12))


def _proud(grid: np.ndarray) -> np.ndarray:
    """(h + 2, w + 2) bool -- the patches of a bordered grid (:class:`Occluders`) that stand more than
    :data:`~nlipscalib.core.tolerances.VISIBILITY_HEIGHT_MM` on the camera's side of the segment between their
    neighbours k patches away on either side (k of :data:`PROUD_SCALES`, along the rows, columns or diagonals).

    Why: the point of a surface that stands farthest on the camera's side of a segment stands above its own
    neighbours along it too, at some scale; :func:`_hidden` samples only the box of these patches. Four directions
    and these scales are a sampling of that, not a proof: on the bench's true sphere, coin and cube surfaces
    (the dent's patches, every emitter) the pairs that 6 samples over the whole segment hid and the box's samples
    did not carried 0.1 %, 0.7 % and 0.05 % of the light (the box's denser samples hid more than that beside). A
    concave surface seen from inside (the undeformed dome) or a flat one has none, and its gathers test no
    pair."""
    h2, w2 = grid.shape[:2]
    proud = np.zeros((h2, w2), bool)
    tol = np.float32(tolerances.VISIBILITY_HEIGHT_MM)
    for k in PROUD_SCALES:
        if 2 * k >= max(h2, w2):
            break
        for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
            r, c = k * dr, k * abs(dc)
            if 2 * r >= h2 or 2 * c >= w2:
                continue
            rows, cols = slice(r, h2 - r), slice(c, w2 - c)
            back = grid[: h2 - 2 * r, : w2 - 2 * c] if dc >= 0 else grid[: h2 - 2 * r, 2 * c :]
            ahead = grid[2 * r :, 2 * c :] if dc >= 0 else grid[2 * r :, : w2 - 2 * c]
            with np.errstate(invalid="ignore"):
                proud[rows, cols] |= _above(grid[rows, cols], back, ahead) > tol
    return proud


PROUD_SCALES = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32)
"""Neighbour distances, patches, at which :func:`_proud` looks for patches that stand out: a bump up to ~64 patches
wide (~20 mm at the twin's 640x480, 8 px patches) stands out at one of them."""
VISIBILITY_BOX_MARGIN = 2
"""Patches added around the proud patches' box (:attr:`Occluders.box`): a bump's flank beside its proud top."""


def patch_cells(mask: np.ndarray) -> np.ndarray:
    """(n, 2) float32 -- the (row, column) on the patch grid of ``mask``'s (h, w) True entries, in row-major order
    (the order of ``points[mask]``)."""
    return np.stack(np.nonzero(mask), axis=1).astype(np.float32)


def _hidden(
    pr: np.ndarray, cells: np.ndarray, emitters: _Emitters, occluders: Occluders, among: np.ndarray | None = None
) -> np.ndarray:
    """(m, k) bool -- whether the segment from each of m receivers ``pr`` (m, 3) (mm; on the patch grid at ``cells``
    (m, 2)) to each emitter passes behind the ``occluders``' surface.

    The surface is a depth map over the image: the light travels on the camera's side of it, and a segment point
    farther from the camera than the surface at its pixel is inside the gel. Tested at
    :data:`VISIBILITY_SAMPLES` points of the straight line between the two patches on the grid, within the box of
    the patches that can hide (:attr:`Occluders.box`; a pair whose line misses it is seen): the patch s there
    hides the pair when it lies on the camera's side of the segment's line (in the plane through the camera and
    the segment, the ray to s meets that line behind s), by more than
    :data:`~nlipscalib.core.tolerances.VISIBILITY_HEIGHT_MM`. On a concave surface seen from inside (the
    undeformed dome) every patch between two others lies beyond their segment: nothing is hidden, and nothing is
    tested. A sample off the grid or off the gel (an emitter of the dome beyond the view: its part of the segment
    outside the view) hides nothing. ``among`` (m, k) bool or None: the pairs to test (the others come out seen),
    e.g. those whose form factor is not 0."""
    hidden = np.zeros((len(pr), len(emitters.points)), bool)
    if occluders.box is None or not hidden.size:
        return hidden
    # the pairs to test first, then every step per pair (the same float32 operations as on the whole (m, k) array):
    # a pair whose two ends lie beyond the same side of the box misses it, and its line is not clipped
    # (benchmarks/RESULTS.md, s43-viscost)
    ends_apart = np.bitwise_and.outer(_outcode(cells, occluders.box), _outcode(emitters.cells, occluders.box)) == 0
    i, j = np.nonzero(ends_apart if among is None else ends_apart & among)
    r0 = np.take(cells[:, 0] + np.float32(1), i)  # on the bordered grid
    c0 = np.take(cells[:, 1] + np.float32(1), i)
    dr = np.take(emitters.cells[:, 0] + np.float32(1), j) - r0
    dc = np.take(emitters.cells[:, 1] + np.float32(1), j) - c0
    t0, t1 = _clip(r0, c0, dr, dc, occluders.box)
    cross = t1 > t0  # the pairs whose line crosses the box
    if not cross.all():
        i, j, r0, c0, dr, dc, t0, t1 = (a[cross] for a in (i, j, r0, c0, dr, dc, t0, t1))
    if not len(i):
        return hidden
    span = t1 - t0
    # one coordinate at a time (np.take of 1-D arrays): a third of the time of (n, 3) rows and einsum; each step
    # below is the float32 operation of the plain expression in its comment, in its order, written in place
    p = [np.take(np.ascontiguousarray(pr[:, c], np.float32), i) for c in range(3)]
    u = [np.take(np.ascontiguousarray(emitters.points[:, c], np.float32), j) for c in range(3)]
    for c in range(3):
        u[c] -= p[c]  # q - p
    along, length = _dot(p, u), _dot(u, u)
    np.maximum(length, np.float32(1e-12), out=length)
    along /= length  # (p . u) / max(u . u, 1e-12)
    toward_cam = u  # from the segment's line to the camera, perpendicular to it: along u - p
    for c in range(3):
        toward_cam[c] *= along
        toward_cam[c] -= p[c]
    norm = _dot(toward_cam, toward_cam)
    np.sqrt(norm, out=norm)
    # a patch s hides the pair where s . toward_cam exceeds p . toward_cam by the margin
    reach = _dot(p, toward_cam)
    norm *= np.float32(tolerances.VISIBILITY_HEIGHT_MM)
    reach += norm
    h2, w2 = occluders.points.shape[:2]
    grid = [np.ascontiguousarray(occluders.points[..., c]).ravel() for c in range(3)]
    # a box on the grid keeps every sample on it (a sample strays from the box by float32 rounding only, far less
    # than the half patch that would move its nearest patch): clipping it to the grid then changes nothing
    on_grid = occluders.box[0] >= 0 and occluders.box[1] <= h2 - 1 and occluders.box[2] >= 0
    on_grid = on_grid and occluders.box[3] <= w2 - 1
    n = len(i)
    seen_behind = np.zeros(n, bool)
    # the loop's arrays made once and written in place (out=), not made afresh at every step
    t, at, height, part = (np.empty(n, np.float32) for _ in range(4))
    row, col, above = np.empty(n, np.intp), np.empty(n, np.intp), np.empty(n, bool)  # intp: take converts no index
    r0 += np.float32(0.5)  # + 0.5 and cut toward zero: the nearest patch (the grid's rows and columns are >= 0)
    c0 += np.float32(0.5)
    for f in (np.arange(VISIBILITY_SAMPLES, dtype=np.float32) + np.float32(0.5)) / np.float32(VISIBILITY_SAMPLES):
        np.multiply(span, f, out=t)
        t += t0  # t0 + f * span
        for start, step, size, index in ((r0, dr, h2, row), (c0, dc, w2, col)):
            np.multiply(t, step, out=at)
            at += start  # start + t * step
            if not on_grid:
                np.clip(at, 0, size - 0.5, out=at)
            index[...] = at  # cut toward zero, as astype
        row *= w2
        row += col
        np.take(grid[0], row, out=height, mode="clip")  # every index is on the grid: "clip" is not buffered
        height *= toward_cam[0]
        for c in (1, 2):
            np.take(grid[c], row, out=part, mode="clip")
            part *= toward_cam[c]
            height += part
        np.greater(height, reach, out=above)  # NaN (no surface) compares False
        seen_behind |= above
    hidden[i[seen_behind], j[seen_behind]] = True
    return hidden


def _outcode(cells: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
    """(n,) uint8 -- which sides of ``box`` (bordered grid) the (n, 2) ``cells`` (unbordered grid, float32) lie
    beyond, one bit a side (Cohen & Sutherland's outcodes): a line whose two ends share a bit misses the box.

    A side's bit is set VISIBILITY_OUTCODE_MARGIN beyond it: such a line misses the box by that much, and
    :func:`_clip`'s float32 arithmetic finds it missing too (rounding errs by ~1e-5 of a patch), so the pairs left
    out are some of those it would leave out, never others."""
    r, c = cells[:, 0] + np.float32(1), cells[:, 1] + np.float32(1)
    m = VISIBILITY_OUTCODE_MARGIN
    code = (r < box[0] - m).astype(np.uint8)
    code |= (r > box[1] + m).astype(np.uint8) << 1
    code |= (c < box[2] - m).astype(np.uint8) << 2
    code |= (c > box[3] + m).astype(np.uint8) << 3
    return code


VISIBILITY_OUTCODE_MARGIN = 0.01
"""Patches beyond a side of :attr:`Occluders.box` at which :func:`_outcode` sets that side's bit."""


def _dot(a: list[np.ndarray], b: list[np.ndarray]) -> np.ndarray:
    """(n,) float32 -- ``a[0] * b[0] + a[1] * b[1] + a[2] * b[2]`` of three (n,) float32 coordinates each, summed
    in that order (the same bits), with one array made for the products."""
    out = a[0] * b[0]
    part = np.empty_like(out)
    for c in (1, 2):
        np.multiply(a[c], b[c], out=part)
        out += part
    return out


def _clip(
    r0: np.ndarray, c0: np.ndarray, dr: np.ndarray, dc: np.ndarray, box: tuple[float, float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """(t0, t1) (m, k) float32 -- the part [t0, t1] of t in [0, 1] where the lines (r0 + t dr, c0 + t dc) lie in
    ``box`` (first row, last row, first column, last column); t1 <= t0 where a line misses it (Liang & Barsky's
    clipping)."""
    t0 = np.zeros(np.broadcast_shapes(r0.shape, dr.shape), np.float32)
    t1 = np.ones_like(t0)
    with np.errstate(divide="ignore", invalid="ignore"):
        for start, step, lo, hi in ((r0, dr, box[0], box[1]), (c0, dc, box[2], box[3])):
            a, b = (np.float32(lo) - start) / step, (np.float32(hi) - start) / step
            t0 = np.fmax(t0, np.minimum(a, b))  # a line along an edge (step 0): inf or NaN, fmax/fmin skip NaN
            t1 = np.fmin(t1, np.maximum(a, b))
    return t0, t1


VISIBILITY_SAMPLES = 6
"""Points of each pair's grid line :func:`_hidden` tests, evenly spaced over its part in :attr:`Occluders.box`
(against 32 there, 6 left out 15 % of the light that 32 hid on the bench's true sphere's dent, 20 % on the coin's;
4: 21 % and 28 %, for 20 % less time)."""


Seen = tuple[Occluders, np.ndarray]
"""(the occluders, the receivers' (m, 2) cells on their grid): what :func:`_pair_factors` tests the pairs against."""


def _pair_light(
    pr: np.ndarray, nr: np.ndarray, emitters: _Emitters, rad: np.ndarray, seen: Seen | None = None
) -> np.ndarray:
    """(m, L*3) float32 -- ``sum_q rad_q cos_p cos_q A_q / r^2`` (pi G) of m receivers over k emitters: pr, nr (m, 3)
    float64 receiver points (mm) and normals; rad (k, L*3) float32; ``seen``: the pairs these occluders hide
    (:func:`_hidden`) left out, or None."""
    return serial_matmul(_pair_factors(pr, nr, emitters, seen), rad)  # the same bits whatever BLAS's thread count


def _pair_factors(pr: np.ndarray, nr: np.ndarray, emitters: _Emitters, seen: Seen | None = None) -> np.ndarray:
    """(m, k) float32 -- the terms ``cos_p cos_q A_q / r^2`` of :func:`_pair_light` (its arguments but ``rad``), 0
    for a pair that ``seen``'s occluders hide (:func:`_hidden`; ``seen`` None: none is).

    By blocks of :data:`PAIR_BLOCK_FLOATS` terms: each term is its pair's own arithmetic, so the same bits as the
    whole block at once. The three (m, 3) x (3, k) products too, as long as no block has a single row where the
    whole has several: BLAS's matrix product (gemm) gives a row the same dot products whatever rows share the
    call, but NumPy multiplies a single row as a matrix-vector product (gemv), whose last bits differ; a one-row
    tail joins the block before it."""
    m = len(pr)
    out = np.empty((m, len(emitters.points)), np.float32)
    rows = max(2, PAIR_BLOCK_FLOATS // max(len(emitters.points), 1))
    starts = list(range(0, m, rows))
    if len(starts) > 1 and m - starts[-1] == 1:
        starts.pop()
    for s, e in zip(starts, starts[1:] + [m]):
        _pair_factors_into(out[s:e], pr[s:e], nr[s:e], emitters)
        if seen is not None:
            block = out[s:e]
            block[_hidden(pr[s:e], seen[1][s:e], emitters, seen[0], among=block > 0)] = 0.0
    return out


PAIR_BLOCK_FLOATS = 1 << 15
"""Receiver-by-emitter terms per block of :func:`_pair_factors` (256 KiB of float64): its float64 temporaries (four
alive at once) then stay in a core's 2 MiB L2 cache. The gather's blocks (:data:`GATHER_BLOCK_FLOATS`) made them
2 MiB each: 2.1 -> 1.5 ms per block of 197 x 1,324 terms (an auto ROI's off-view gather, 2-core Xeon VM)."""


def _pair_factors_into(out: np.ndarray, pr: np.ndarray, nr: np.ndarray, emitters: _Emitters) -> None:
    """:func:`_pair_factors` of one block into ``out`` (m, k) float32; in place, each step the same operation
    as ``(|p|^2 + |q|^2 - 2 p.q)``, ``n_p.q - n_p.p``, ``n_q.p - n_q.q`` and ``cp * cq / (r2 * r2) * A``."""
    pe, ne = emitters.points, emitters.normals
    # float64 for the cancelling differences, float32 for the products that follow
    r2 = np.sum(pr * pr, axis=1)[:, None] + emitters.sq_norm[None]
    pq = pr @ pe.T
    pq *= 2.0
    r2 -= pq
    r2 = r2.astype(np.float32)
    cp = nr @ pe.T
    cp -= np.sum(nr * pr, axis=1)[:, None]  # r cos_p
    cp = cp.astype(np.float32)
    cq = pr @ ne.T
    cq -= emitters.normal_dot_point[None]  # r cos_q
    cq = cq.astype(np.float32)
    np.maximum(cp, 0.0, out=cp)
    np.maximum(cq, 0.0, out=cq)
    tiny = r2 < 1e-12  # a patch does not light itself
    np.maximum(r2, 1e-12, out=r2)
    cp *= cq
    r2 *= r2
    cp /= r2
    np.multiply(cp, emitters.area, out=out)
    out[tiny] = 0.0


CLUSTER_SIZE = 4
"""Side, in patches, of the emitter clusters of :func:`gather_grid` (a cluster of 4 x 4 patches, 32 x 32 pixels at
640x480). 8 left more of the surface near every tile (a third more pairwise terms at the same error), 2 saved too
little (0.3 of the exact gather's terms against 0.2)."""
TILE_SIZE = 8
"""Side, in patches, of the receiver tiles of :func:`gather_grid` (one set of emitters per tile). 4: fewer terms
(0.16 against 0.2 of the exact gather's) but more, smaller products, slower on the whole."""


def gather_grid(
    points: np.ndarray,
    normals: np.ndarray,
    area: np.ndarray,
    radiance: np.ndarray,
    receivers: np.ndarray,
    ratio: float | None = None,
    visibility: bool = True,
) -> np.ndarray:
    """:func:`gather` of a surface's patch grid at some of its patches, with far emitters grouped.

    A two-level hierarchical radiosity gather (Hanrahan, Salzman & Aupperle, "A rapid hierarchical radiosity
    algorithm", SIGGRAPH 1991): the receivers go by tiles of :data:`TILE_SIZE` x :data:`TILE_SIZE` patches and
    the emitters by clusters of :data:`CLUSTER_SIZE` x :data:`CLUSTER_SIZE`; a cluster whose radius is below
    ``ratio`` times its distance to every patch of a tile lights that tile as one patch (its aggregate: area
    centroid, the direction and length of its vector area ``sum A_q n_q``, the area-weighted mean radiance),
    every other cluster patch by patch, as in :func:`gather`. The aggregate's form factor errs by about ratio^2
    (the error bound from the cluster's solid angle, HSA's "estimate" oracle); see
    :data:`~nlipscalib.core.tolerances.GATHER_CLUSTER_RATIO` for what that does to a solve. Which clusters are
    grouped depends on the tile's patches, not on which of them are receivers: a receiver's light does not depend
    on the other receivers.

    Parameters
    ----------
    points : (h, w, 3) float, mm, camera frame -- patch centroids.
    normals : (h, w, 3) float, unit, camera frame, toward the camera.
    area : (h, w) float, mm^2 -- 0 where a patch does not emit.
    radiance : (L, h, w, 3) float -- D_q per LED and channel, linear image units.
    receivers : (h, w) bool -- patches to light (with an area: where the surface is).
    ratio : cluster radius over distance below which a cluster is one emitter (default
        :data:`~nlipscalib.core.tolerances.GATHER_CLUSTER_RATIO`; 0: the exact gather's terms).
    visibility : leave out the pairs that the grid's own surface hides from each other (:func:`_hidden`, a
        cluster tested at its area-weighted place on the grid); False: every pair sees the other.

    Returns
    -------
    (L, M, 3) float32 -- G at the M receivers in row-major order (``receivers``' True entries), as :func:`gather`.
    """
    ratio = tolerances.GATHER_CLUSTER_RATIO if ratio is None else ratio
    h, w = area.shape
    L = radiance.shape[0]
    rad = np.asarray(radiance, np.float32).transpose(1, 2, 0, 3).reshape(h, w, L * 3)
    emits = area > 0
    n_fine = int(emits.sum())
    coarse = _clusters(points, normals, area, rad, CLUSTER_SIZE)
    occluders = Occluders.of(points, area) if visibility else None
    emitters = _Emitters.of(
        np.concatenate([points[emits], coarse["points"]]),
        np.concatenate([normals[emits], coarse["normals"]]),
        np.concatenate([area[emits], coarse["area"]]),
        np.concatenate([patch_cells(emits), coarse["cells"]]) if visibility else None,
    )
    rad_all = np.ascontiguousarray(np.concatenate([rad[emits], coarse["radiance"]]), np.float32)
    fine_id = np.full((h, w), -1)
    fine_id[emits] = np.arange(n_fine)
    members = _blocks(fine_id, CLUSTER_SIZE, -1)[coarse["index"]]  # (C, size^2) fine emitters of each cluster
    out = np.zeros((h, w, L * 3), np.float32)
    t = TILE_SIZE
    tiles = [(i, j) for i in range(0, h, t) for j in range(0, w, t) if receivers[i : i + t, j : j + t].any()]

    def light(tile: tuple[int, int]) -> None:
        win = (slice(tile[0], tile[0] + t), slice(tile[1], tile[1] + t))
        own = points[win][emits[win] | receivers[win]]
        centre = own.mean(axis=0)
        reach = np.linalg.norm(own - centre, axis=1).max()
        gap = np.linalg.norm(coarse["points"] - centre, axis=1) - reach  # to the tile's nearest patch, at least
        far = (gap > 0) & (coarse["radius"] < ratio * gap)
        near = members[~far].ravel()
        idx = np.concatenate([near[near >= 0], n_fine + np.flatnonzero(far)])
        rec = receivers[win]
        pr, nr = np.asarray(points[win][rec], np.float64), np.asarray(normals[win][rec], np.float64)
        seen = None if occluders is None else (occluders, patch_cells(rec) + np.asarray(tile, np.float32))
        out[win][rec] = _pair_light(pr, nr, emitters.take(idx), rad_all[idx], seen)

    # one tile per task: the tiles near a dent hold more emitters than the rest (BLAS on one thread, as in gather)
    with blas_threads(1):
        threads.map_items(light, tiles)
    return out[receivers].reshape(-1, L, 3).transpose(1, 0, 2) / np.float32(np.pi)


def _blocks(a: np.ndarray, size: int, fill: float) -> np.ndarray:
    """(h, w, ...) -> (ceil(h/size) * ceil(w/size), size^2, ...): the size x size blocks' entries, row-major blocks,
    padded with ``fill``."""
    h, w = a.shape[:2]
    hb, wb = -(-h // size), -(-w // size)
    pad = np.full((hb * size, wb * size) + a.shape[2:], fill, dtype=a.dtype)
    pad[:h, :w] = a
    blocks = pad.reshape(hb, size, wb, size, *a.shape[2:]).swapaxes(1, 2)
    return blocks.reshape(hb * wb, size * size, *a.shape[2:])


def _clusters(points: np.ndarray, normals: np.ndarray, area: np.ndarray, rad: np.ndarray, size: int) -> dict:
    """The emitting patches of a grid grouped by size x size blocks, as aggregate patches.

    ``points``, ``normals`` (h, w, 3), ``area`` (h, w) (0: no emitter), ``rad`` (h, w, L*3). Returns a dict with, per
    cluster with an emitter (C of them): index (C,) int, its row-major block number; points (C, 3) float64 mm, the
    area centroid; normals (C, 3) unit and area (C,) mm^2, the direction and length of the vector area
    sum A_q n_q (what lights a far receiver: sum A_q n_q . w for a common direction w); radiance (C, L*3) float32,
    area-weighted mean; radius (C,) mm, the farthest member's distance from the centroid plus its half diagonal;
    cells (C, 2) float32, the area-weighted mean (row, column) of its members on the grid."""
    a = _blocks(np.asarray(area, np.float64), size, 0.0)  # (B, s^2)
    total = a.sum(axis=1)
    index = np.flatnonzero(total > 0)
    a, total = a[index], total[index]
    p = _blocks(np.asarray(points, np.float64), size, 0.0)[index]
    centre = np.einsum("bk,bkc->bc", a, p) / total[:, None]
    vec = np.einsum("bk,bkc->bc", a, _blocks(np.asarray(normals, np.float64), size, 0.0)[index])
    length = np.linalg.norm(vec, axis=1)
    radiance = np.einsum("bk,bkc->bc", a, _blocks(rad, size, 0.0)[index]) / total[:, None]
    extent = np.linalg.norm(p - centre[:, None], axis=2) + np.sqrt(a / 2)
    h, w = area.shape[:2]
    rows, cols = np.meshgrid(np.arange(h, dtype=np.float64), np.arange(w, dtype=np.float64), indexing="ij")
    cells = _blocks(np.stack([rows, cols], axis=-1), size, 0.0)[index]
    return {
        "cells": (np.einsum("bk,bkc->bc", a, cells) / total[:, None]).astype(np.float32),
        "index": index,
        "points": centre,
        "normals": vec / np.maximum(length, NORMAL_EPS)[:, None],
        "area": length,
        "radiance": radiance.astype(np.float32),
        "radius": np.where(a > 0, extent, 0.0).max(axis=1),
    }


def upsample(patch_values: np.ndarray, shape: tuple[int, int], size: int) -> np.ndarray:
    """Bilinear upsampling of (L, h, w, 3) patch values to (L, H, W, 3) pixels (patch centres at
    (i + 0.5) * size - 0.5, cv2's INTER_LINEAR convention for an integer factor), over the patches that hold
    light only: a patch whose value is 0 in every LED and channel is no surface (off the gel, or not gathered),
    and a pixel beside one takes its bilinear weights over the others, renormalised (:func:`edge_gain`)."""
    H, W = shape
    gain = edge_gain(patch_values, shape, size)
    out = np.empty((len(patch_values), H, W, 3), np.float32)
    for i in range(len(patch_values)):
        out[i] = _upsample_one(patch_values[i], shape, size, gain)
    return out


EdgeGain = tuple[tuple[np.ndarray, np.ndarray], np.ndarray]
"""((rows, columns) (n,) int of the pixels, their gain (n, 1) float32): what :func:`edge_gain` returns."""


def edge_gain(patch_values: np.ndarray, shape: tuple[int, int], size: int) -> EdgeGain | None:
    """The pixels (H, W image) whose bilinear weights reach a patch that holds no light (``patch_values`` (L, h, w, 3)
    0 in every LED and channel) and some that do, and what :func:`upsample` multiplies plain bilinear upsampling by
    there: 1 / the weight of the patches that hold light. None when every patch holds light (or none does): plain
    bilinear, the same bits. Elsewhere the pixels keep plain bilinear's bits.

    Why: the indirect light is 0 on the patches off the gel, and plain bilinear upsampling blended it in at the
    gel's outline: on a view that sees past the gel (the ideal wide twin, 160x120, 4 px patches) the outer pixel's
    light came out 11 % low and the next one's 3 % (7.8 and 2.2 % of the captured light), against the render's
    bounce light and a gather at each pixel (benchmarks/RESULTS.md, s35-wideedge)."""
    holds = np.any(np.asarray(patch_values) != 0, axis=(0, 3))
    if holds.all() or not holds.any():
        return None
    import cv2

    h, w = holds.shape
    weight = cv2.resize(holds.astype(np.float32), (w * size, h * size), interpolation=cv2.INTER_LINEAR)
    weight = weight[: shape[0], : shape[1]]
    # a patch a pixel reads weighs at least (1 / (2 size))^2: half that tells a left-out patch from rounding
    short = (weight > 0) & (weight < 1.0 - 0.5 / (2 * size) ** 2)
    rows, cols = np.nonzero(short)
    return (rows, cols), (1.0 / weight[rows, cols])[:, None]


def _upsample_one(
    patch_values: np.ndarray, shape: tuple[int, int], size: int, gain: EdgeGain | None = None
) -> np.ndarray:
    """(H, W, 3) float32 -- :func:`upsample` of one LED's (h, w, 3) patch values (a view of cv2's result), its
    pixels at the patches that hold no light renormalised by ``gain`` (:func:`edge_gain`) when given."""
    import cv2

    H, W = shape
    h, w = patch_values.shape[:2]
    big = cv2.resize(np.asarray(patch_values, np.float32), (w * size, h * size), interpolation=cv2.INTER_LINEAR)
    out = big[:H, :W]
    if gain is not None:
        out[gain[0]] *= gain[1]
    return out


class Upsampled:
    """:func:`upsample` of (L, h, w, 3) patch values read one LED at a time: ``stack[i]`` is LED i's (H, W, 3) float32
    image, the same numbers as ``upsample(...)[i]``; ``np.asarray(stack)`` the whole (L, H, W, 3) array.

    Why: a reader that takes the images one by one (the contact classification's block means) then never holds the
    whole stack, a fresh 44 MB array at 640x480 with 12 LEDs whose first touch (page faults) cost more than the
    upsampling itself, and the images are upsampled on the threads that read them."""

    def __init__(self, patch_values: np.ndarray, shape: tuple[int, int], size: int):
        self.patch_values, self.image_shape, self.size = patch_values, tuple(shape), size
        self.gain = edge_gain(patch_values, self.image_shape, size)

    def __len__(self) -> int:
        return len(self.patch_values)

    def __getitem__(self, index: int) -> np.ndarray:
        return _upsample_one(self.patch_values[index], self.image_shape, self.size, self.gain)

    def __array__(self, dtype: np.typing.DTypeLike = None, copy: bool | None = None) -> np.ndarray:
        out = upsample(self.patch_values, self.image_shape, self.size)
        return out if dtype is None else out.astype(dtype, copy=False)


__all__ = [
    "block_sum",
    "edge_gain",
    "FormFactors",
    "gather",
    "gather_grid",
    "Occluders",
    "off_view_patches",
    "patch_cells",
    "patch_mean",
    "pixel_solid_angle",
    "surface_patches",
    "upsample",
    "Upsampled",
]
