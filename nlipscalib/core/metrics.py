"""Accuracy metrics of a reconstruction against ground truth (Quéau et al. 2018 definitions).

- AAE: average angular error, degrees: mean over the mask M of the angle arccos(n_hat . n), computed as
  atan2(|n_hat x n|, n_hat . n) (:func:`angle_deg`).
- MabsE: mean absolute error of normal components, 1/(3|M|) sum_M ||n_hat - n||_1.
- depth RMSE, mm: sqrt(mean over M of (z_hat - z)^2).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .errors import CaptureError, ShapeError, check_kind

if TYPE_CHECKING:  # names in hints only: importing them here would make an import cycle
    from .reconstruction import Reconstruction
    from .surface_files import GroundTruth


ARRAY = (np.ndarray, list, tuple)
"""What a map argument of the metrics may be: an array, or nested lists NumPy makes one of."""


def _check(est: np.ndarray, gt: np.ndarray, mask: np.ndarray | None, name: str, last: int | None):
    named = ("normals", "gt_normals") if last else ("depth", "gt_depth")  # the metrics' own argument names
    for value, what in ((est, named[0]), (gt, named[1]), (mask, "mask")):
        # "could not convert string to float: 'a'" from NumPy named neither the function nor the argument
        check_kind(value, (*ARRAY, type(None)) if what == "mask" else ARRAY, f"{name}: {what}", "an array")
    est, gt = np.asarray(est, dtype=np.float64), np.asarray(gt, dtype=np.float64)
    if est.shape != gt.shape or (last is not None and est.shape[-1] != last):
        raise ShapeError(
            f"{name}: estimate {est.shape} and ground truth {gt.shape} must match"
            + (f" and end in {last}" if last else "")
        )
    grid = est.shape[:-1] if last else est.shape
    m = np.ones(grid, bool) if mask is None else np.asarray(mask, bool)
    if m.shape != grid:
        raise ShapeError(f"{name}: mask {m.shape} does not match {grid}")
    finite = np.isfinite(est).all(-1) & np.isfinite(gt).all(-1) if last else np.isfinite(est) & np.isfinite(gt)
    return est, gt, m & finite


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between corresponding 3-vectors: the one copy of the formula (angular error, normal change, LED tilt).

    atan2(|a x b|, a . b): exact at every angle, where arccos of a rounded cosine loses half its digits near 0
    and 180 deg (a float32 unit normal's cosine is off by ~1e-7, i.e. ~0.02 deg at 0), and independent of the
    vectors' lengths.

    Parameters
    ----------
    a, b : (..., 3) float, any length, one frame for both

    Returns
    -------
    (...) float64, degrees in [0, 180]; NaN where either is not finite or has zero length (no direction).
    """
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.shape[-1:] != (3,):
        raise ShapeError(f"angle_deg: {a.shape} and {b.shape} must match and end in 3")
    (ax, ay, az), (bx, by, bz) = np.moveaxis(a, -1, 0), np.moveaxis(b, -1, 0)
    # by components, not np.cross and np.linalg.norm: 4x faster, and the solver measures every iteration with it
    with np.errstate(invalid="ignore", over="ignore"):  # inf * 0 in a non-finite pixel: NaN below anyway
        sine = np.sqrt((ay * bz - az * by) ** 2 + (az * bx - ax * bz) ** 2 + (ax * by - ay * bx) ** 2)
        cosine = ax * bx + ay * by + az * bz
    # a non-finite component makes the cosine non-finite; sine = cosine = 0 only when a vector has no length
    ok = np.isfinite(cosine) & ((sine > 0) | (cosine != 0))
    return np.where(ok, np.degrees(np.arctan2(sine, cosine)), np.nan)


def angular_error_map(normals: np.ndarray, gt_normals: np.ndarray) -> np.ndarray:
    """Angle between estimated and true normals (:func:`angle_deg`).

    Parameters
    ----------
    normals, gt_normals : (..., 3) float, unit, one frame for both

    Returns
    -------
    (...) float64, degrees; NaN where either is not finite.
    """
    return angle_deg(normals, gt_normals)


def aae(normals: np.ndarray, gt_normals: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Average angular error over ``mask`` and the pixels where both normals are finite.

    Parameters
    ----------
    normals : (..., 3) float, unit, camera frame -- the estimate (``SolveResult.normals``).
    gt_normals : (..., 3) float, unit, the same frame as ``normals`` -- the truth (``GroundTruth.normals``).
    mask : (...) bool or None -- pixels to average over (None: all).

    Returns
    -------
    float, degrees; NaN when no pixel is left.
    """
    est, gt, m = _check(normals, gt_normals, mask, "aae", 3)
    if not m.any():
        return float("nan")
    return float(angle_deg(est[m], gt[m]).mean())


def mabse(normals: np.ndarray, gt_normals: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean absolute error of normal components: 1/(3|M|) sum ||n_hat - n||_1 over ``mask`` and finite pixels.

    Parameters
    ----------
    normals : (..., 3) float, unit, camera frame -- the estimate.
    gt_normals : (..., 3) float, unit, the same frame as ``normals`` -- the truth.
    mask : (...) bool or None -- pixels to average over (None: all).

    Returns
    -------
    float, unitless (a component difference, 0..2); NaN when no pixel is left.
    """
    est, gt, m = _check(normals, gt_normals, mask, "mabse", 3)
    if not m.any():
        return float("nan")
    return float(np.abs(est[m] - gt[m]).sum() / (3 * m.sum()))


def depth_rmse(depth: np.ndarray, gt_depth: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Root mean square depth error over ``mask`` and the pixels where both depths are finite.

    Parameters
    ----------
    depth : (...) float, mm -- the estimate's z in the camera frame (not range along the ray).
    gt_depth : (...) float, mm -- the truth's z in the camera frame (``GroundTruth.depth``; NaN off the gel).
    mask : (...) bool or None -- pixels to average over (None: all).

    Returns
    -------
    float, mm; NaN when no pixel is left.
    """
    est, gt, m = _check(depth, gt_depth, mask, "depth_rmse", None)
    if not m.any():
        return float("nan")
    return float(np.sqrt(np.mean((est[m] - gt[m]) ** 2)))


def evaluate(result: Reconstruction, ground_truth: GroundTruth, mask: np.ndarray | None = None) -> dict:
    """AAE, MabsE, depth RMSE (and pixel counts) of a SolveResult-like object against a GroundTruth.

    The pixels scored are those valid in the truth and reconstructed (and in ``mask`` when given); the
    ``contact`` figures keep only the truth's contact region of them.

    Parameters
    ----------
    result : SolveResult-like -- ``normals`` (H, W, 3) float, unit, camera frame; ``depth`` (H, W) float, mm,
        camera-frame z; ``reconstructed`` (H, W) bool.
    ground_truth : :class:`~nlipscalib.core.surface_files.GroundTruth` of the same (H, W) image.
    mask : (H, W) bool or None -- further restricts the pixels scored.

    Returns
    -------
    dict: {"all": ..., "contact": ...}, each {"pixels": int, "aae_deg": degrees, "mabse": unitless,
    "depth_rmse_mm": mm} (NaN figures where no pixel is scored).

    Raises
    ------
    CaptureError -- ``ground_truth`` None: a real capture's ``press.ground_truth`` (only twin presses carry one).
    ShapeError -- the result and the truth of other image sizes (or ``mask``).
    """
    if ground_truth is None:  # it failed on "'NoneType' object has no attribute 'valid'"
        raise CaptureError(
            "evaluate: no ground truth (None): a real capture carries none (press.ground_truth is None); only twin "
            "presses (nlips render, nlips dataset) are scored"
        )
    if not all(hasattr(result, field) for field in ("normals", "depth", "reconstructed")):
        raise ShapeError(
            "evaluate: result must be a Reconstruction (a solve's result, load_reconstruction, "
            f"learn.infer.to_reconstruction), got {type(result).__name__}"
        )
    if not all(hasattr(ground_truth, field) for field in ("valid", "contact")):  # a GroundTruth, or like one
        raise ShapeError(
            "evaluate: ground_truth must be a GroundTruth (press.ground_truth of a twin press), got "
            f"{type(ground_truth).__name__}"
        )
    shape = ground_truth.valid.shape
    for name, array in (("result", result.reconstructed), ("mask", mask)):
        if array is not None and np.shape(array) != shape:
            raise ShapeError(f"evaluate: {name} of a {np.shape(array)} image, the ground truth's is {shape} (H, W)")
    base = ground_truth.valid & result.reconstructed
    if mask is not None:
        base = base & mask
    out = {}
    for name, m in (("all", base), ("contact", base & ground_truth.contact)):
        out[name] = {
            "pixels": int(m.sum()),
            "aae_deg": aae(result.normals, ground_truth.normals, m),
            "mabse": mabse(result.normals, ground_truth.normals, m),
            "depth_rmse_mm": depth_rmse(result.depth, ground_truth.depth, m),
        }
    return out
