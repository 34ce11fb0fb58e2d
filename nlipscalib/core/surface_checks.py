"""What a capture's surfaces (reference.npz, gt.npz) promise beyond their array shapes.

docs/formats.md: depth in millimetres, normals unit and toward the camera (docs/conventions.md). A file that
breaks this -- depth written in metres, normals flipped or unnormalised by a lab's own converter -- has the
right shapes and loads as numbers: a solve then starts from a wrong prior and reports a confident, wrong
result (measured: 2.68 deg and 9.9 mm depth error instead of 0.40 deg / 0.026 mm, without a word).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .camera import Camera, depth_to_points
from .leds import Led
from .tolerances import FACING_AWAY_MAJORITY, SURFACE_SCALE_RATIO, UNIT_NORMAL_TOL

FACING_STRIDE = 8
"""The facing and scale checks look at every this-many-th pixel in both directions (a statistic; 4,800
pixels at 640x480, unprojected in a few milliseconds, where the whole frame's rays cost 75 ms)..."""
FACING_MIN_SAMPLES = 100
"""... or at every pixel of the gel when that grid holds fewer than this many of them (a small gel or image)."""


def surface_problem(
    depth: np.ndarray, normals: np.ndarray, valid: np.ndarray, camera: Camera, leds: Sequence[Led]
) -> str | None:
    """Why a surface breaks the format's promise, or None.

    Parameters
    ----------
    depth : (H, W) float, mm, camera frame -- z of the surface (NaN or anything where not ``valid``)
    normals : (H, W, 3) float, camera frame
    valid : (H, W) bool -- pixels that see the gel
    camera : the capture's camera
    leds : the capture's LEDs (their distance from the camera sets the scale a millimetre surface has)

    Returns
    -------
    str or None -- what is wrong, naming the array ('normals', 'depth'), for a message that names the file.
    """
    total = int(valid.sum())
    if total == 0:
        return None
    bad = non_unit_count(normals, valid)
    if bad:
        return f"array 'normals' is not a unit vector on {bad} of its {total} gel pixels"
    rows, cols = _sample(valid & np.isfinite(depth))
    if rows.size == 0:  # no finite depth on the gel: nothing to tell the orientation or the scale from
        return None
    rays = camera.unproject(np.stack([cols, rows], axis=-1).astype(np.float64))
    points = depth_to_points(depth[rows, cols].astype(np.float64), rays)
    facing_away = np.einsum("ij,ij->i", normals[rows, cols].astype(np.float64), points) >= 0
    if facing_away.mean() > FACING_AWAY_MAJORITY:
        return (
            f"array 'normals' points away from the camera on {100 * facing_away.mean():.0f} % of the gel "
            "(flipped? normals point toward the camera)"
        )
    gel_mm = float(np.median(np.linalg.norm(points, axis=-1)))
    led_mm = float(np.median([np.linalg.norm(led.position) for led in leds]))
    if not (led_mm / SURFACE_SCALE_RATIO <= gel_mm <= led_mm * SURFACE_SCALE_RATIO):
        return (
            f"array 'depth' puts the gel {gel_mm:.3g} mm from the camera (median) and its LEDs are {led_mm:.3g} mm "
            "from it: depth must be in millimetres"
        )
    return None


def _sample(where: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the pixels of ``where`` ((H, W) bool) that the facing and scale checks look at."""
    rows, cols = np.nonzero(where[::FACING_STRIDE, ::FACING_STRIDE])
    if rows.size >= FACING_MIN_SAMPLES:
        return rows * FACING_STRIDE, cols * FACING_STRIDE
    return np.nonzero(where)


def non_unit_count(normals: np.ndarray, where: np.ndarray) -> int:
    """How many of ``where``'s normals are not finite unit vectors (length 1 within ``UNIT_NORMAL_TOL``).

    Parameters
    ----------
    normals : (..., 3) float
    where : (...) bool -- the pixels that must hold a unit normal

    The squared length on the whole grid, no gather (every load of a press and every reused result runs this):
    |n|^2 - 1 ~ 2 (|n| - 1); NaN compares False and is counted.
    """
    squared = np.einsum("...k,...k->...", normals, normals)
    return int(np.count_nonzero(where & ~(np.abs(squared - 1.0) <= 2 * UNIT_NORMAL_TOL)))
