"""Camera intrinsics and lens distortion from checkerboard or ChArUco images (OpenCV), as a core Camera.

OpenCV does the work: ``cv2.findChessboardCornersSB`` (sector-based detector, robust to the strong
distortion of wide lenses) finds a checkerboard's inner corners, refined with ``cv2.cornerSubPix``;
``cv2.aruco.CharucoDetector`` finds the corners of a ChArUco board, which need not be wholly in view
(useful at the edge of a fisheye's field); and ``cv2.fisheye.calibrate``
(Kannala-Brandt, 4 coefficients) or ``cv2.calibrateCamera`` (Brown-Conrady, 5 coefficients) fits the
model. Both share the core Camera's conventions (pixel centres at integers, OpenCV coefficient order),
so the result drops straight into the capture metadata's ``camera`` block. The reprojection error is
recomputed with the core Camera's own projection, so it measures the model the workbench will use.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from ..core.camera import Camera
from ..core.errors import CaptureError, ConfigError, ShapeError, require
from ..core.imageio import read_image
from ..core.tolerances import CAMERA_CAL_MIN_TILT_SPREAD_DEG

if TYPE_CHECKING:  # OpenCV is imported where it is used (``_cv2``): named for the hints only
    import cv2

MIN_VIEWS = 3
"""Views with a detected board needed for a calibration (use 10-20 covering the whole field in practice)."""


def _cv2():
    return require("cv2", "opencv-python-headless", "Camera calibration")


@dataclasses.dataclass(frozen=True)
class Calibration:
    """A fitted camera and how well it explains the detected corners."""

    camera: Camera
    """Intrinsics and lens model (pixel centres at integers)."""
    rms_px: float
    """RMS reprojection error over all corners, pixels."""
    per_view_px: tuple[float, ...]
    """RMS reprojection error of each used view, pixels."""
    used: tuple[str, ...]
    """Views the board was found in (file names, or indices)."""
    rejected: tuple[str, ...]
    """Views where the board was not found."""

    def to_dict(self) -> dict:
        """The JSON written by ``nlips calibrate-camera``: the capture metadata's ``camera`` block plus errors."""
        return {
            "camera": self.camera.to_dict(),
            "reprojection_rms_px": self.rms_px,
            "per_view_rms_px": dict(zip(self.used, self.per_view_px)),
            "rejected_views": list(self.rejected),
        }


def board_points(pattern: tuple[int, int], square_mm: float) -> np.ndarray:
    """Inner corners of a checkerboard in its own plane.

    Parameters
    ----------
    pattern : (columns, rows) of inner corners
    square_mm : side of one square, mm

    Returns
    -------
    (columns * rows, 3) float64, mm, board frame (z = 0), row by row as OpenCV orders them
    """
    cols, rows = pattern
    j, i = np.mgrid[0:rows, 0:cols]
    return np.stack([i.ravel() * square_mm, j.ravel() * square_mm, np.zeros(i.size)], 1).astype(np.float64)


def find_corners(image: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    """Sub-pixel inner corners of the checkerboard in an image, or None when it is not (wholly) seen.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) uint8 or uint16 (RGB)
    pattern : (columns, rows) of inner corners

    Returns
    -------
    (columns * rows, 2) float64, pixels (u, v), or None
    """
    cv2 = _cv2()
    grey = _grey8(image)
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCornersSB(grey, tuple(pattern), flags=flags)
    if not found:
        return None
    # the sector detector finds every corner; cornerSubPix then locates each one to a few hundredths of
    # a pixel (on synthetic views: 0.02-0.04 px against 0.15-0.25 px for the detector alone), in a window
    # kept inside the corner's own squares
    corners = corners.reshape(-1, 2).astype(np.float32)
    grid = corners.reshape(pattern[1], pattern[0], 2)
    spacing = min(
        np.linalg.norm(np.diff(grid, axis=0), axis=2).min(), np.linalg.norm(np.diff(grid, axis=1), axis=2).min()
    )
    half = int(np.clip(0.4 * spacing, 2, 8))
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-4)
    refined = cv2.cornerSubPix(grey, corners.reshape(-1, 1, 2).copy(), (half, half), (-1, -1), criteria)
    return refined.reshape(-1, 2).astype(np.float64)


@dataclasses.dataclass(frozen=True)
class Target:
    """The calibration target the images show."""

    pattern: tuple[int, int]
    """Checkerboard: inner corners (columns, rows). ChArUco: squares (columns, rows)."""
    square_mm: float
    """Side of one square, mm."""
    marker_mm: float | None = None
    """ChArUco only: side of the ArUco markers, mm (None: a plain checkerboard)."""
    dictionary: str = "DICT_4X4_50"
    """ChArUco only: OpenCV's ArUco dictionary name."""

    def __post_init__(self):
        if not self.square_mm > 0 or (self.marker_mm is not None and not 0 < self.marker_mm < self.square_mm):
            raise ConfigError(
                f"target needs square > 0 and 0 < marker < square (mm), got {self.square_mm}, {self.marker_mm}"
            )

    @property
    def name(self) -> str:
        kind = "ChArUco board" if self.marker_mm else "checkerboard"
        return f"the {self.pattern[0]}x{self.pattern[1]} {kind}"

    def detect(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Board points and their pixels in one image, or None when not enough of the board is seen.

        Returns
        -------
        (N, 3) float64 mm board frame, (N, 2) float64 pixels
        """
        if self.marker_mm is None:
            corners = find_corners(image, self.pattern)
            return None if corners is None else (board_points(self.pattern, self.square_mm), corners)
        return _detect_charuco(_grey8(image), self)


def _grey8(image: np.ndarray) -> np.ndarray:
    grey = np.asarray(image)
    if grey.ndim == 3:
        grey = grey[..., :3].mean(axis=2)
    if grey.ndim != 2:
        raise ShapeError(f"calibration images must be (H, W[, 3]), got {np.shape(image)}")
    if grey.dtype != np.uint8:
        top = float(grey.max()) or 1.0
        grey = np.clip(grey.astype(np.float64) * (255.0 / top), 0, 255)
    return np.ascontiguousarray(np.rint(grey).astype(np.uint8))


CHARUCO_MIN_CORNERS = 6
"""ChArUco views with fewer interpolated corners are skipped (too little to pin a pose)."""


def charuco_board(target: Target) -> cv2.aruco.CharucoBoard:
    """The OpenCV CharucoBoard of a target (also to print one: ``board.generateImage``)."""
    cv2 = _cv2()
    name = target.dictionary.upper()
    if not hasattr(cv2.aruco, name):
        raise ConfigError(f"unknown ArUco dictionary {target.dictionary!r} (e.g. DICT_4X4_50, DICT_5X5_100)")
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
    return cv2.aruco.CharucoBoard(tuple(target.pattern), target.square_mm, target.marker_mm, dictionary)


def _detect_charuco(grey: np.ndarray, target: Target):
    board = charuco_board(target)
    corners, ids, _, _ = _cv2().aruco.CharucoDetector(board).detectBoard(grey)
    if ids is None or len(ids) < CHARUCO_MIN_CORNERS:
        return None
    obj = np.asarray(board.getChessboardCorners(), np.float64)[np.ravel(ids)]
    return obj, corners.reshape(-1, 2).astype(np.float64)


def calibrate(
    views: list[tuple[np.ndarray, np.ndarray] | None],
    image_size: tuple[int, int],
    model: str = "fisheye",
    names: list[str] | None = None,
    target_name: str = "the board",
    where: str | None = None,
) -> Calibration:
    """Fit intrinsics and distortion to detected board points.

    Parameters
    ----------
    views : per image, (board points (N, 3) mm, pixels (N, 2)) from :meth:`Target.detect`, or None
    image_size : (width, height), pixels
    model : "fisheye" or "brown"
    names : view names for the report (default: indices)
    target_name : what the images show, for the error message
    where : the images' file or folder, named first in the error message (None: not named)
    """
    cv2 = _cv2()
    if model not in ("fisheye", "brown"):
        raise ConfigError(f"camera model must be fisheye or brown, got {model!r}")
    names = names or [str(k) for k in range(len(views))]
    used = [k for k, v in enumerate(views) if v is not None]
    rejected = tuple(names[k] for k, v in enumerate(views) if v is None)
    if len(used) < MIN_VIEWS:
        # found in every image given: the pattern is right and more views are what is missing
        why = (
            "take more pictures of it, in different poses over the whole image"
            if len(used) == len(views)
            else "check --pattern: inner corners of a checkerboard, squares of a ChArUco board, columns x rows"
        )
        raise CaptureError(
            f"{f'{where}: ' if where else ''}{target_name} was found in {len(used)} of {len(views)} images; at least "
            f"{MIN_VIEWS} are needed ({why})"
        )
    # (1, N, 3) / (1, N, 2) float32: the layout both OpenCV 4 and 5 accept in fisheye.calibrate
    objs = [np.asarray(views[k][0], np.float32).reshape(1, -1, 3) for k in used]
    imgs = [np.asarray(views[k][1], np.float32).reshape(1, -1, 2) for k in used]
    w, h = image_size
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    try:
        if model == "fisheye":
            flags = _fisheye_flag(cv2, "CALIB_RECOMPUTE_EXTRINSIC") | _fisheye_flag(cv2, "CALIB_FIX_SKEW")
            _, K, D, rvecs, tvecs = cv2.fisheye.calibrate(
                objs, imgs, (w, h), np.eye(3), np.zeros((4, 1)), flags=flags, criteria=criteria
            )
        else:
            objs2, imgs2 = [o.reshape(-1, 3) for o in objs], [i.reshape(-1, 2) for i in imgs]
            _, K, D, rvecs, tvecs = cv2.calibrateCamera(objs2, imgs2, (w, h), None, None, criteria=criteria)
        # before the camera is built: such a fit's focal length can be anything, negative too
        why = _unconstrained(K, rvecs, (w, h))
    except cv2.error as exc:  # OpenCV 5.1 asserts inside the fit on such views where 5.0 returned a degenerate one
        why = f"OpenCV's {model} fit failed on them: {str(exc).strip().splitlines()[-1][:160]}"
    if why:
        raise CaptureError(
            f"{target_name} in these {len(used)} images does not pin the camera down ({why}): the focal length "
            "cannot be told from the board's distance when the board faces the same way in every image. Take the "
            "views again with the board tilted 20-40 deg in different directions, spread over the whole field"
        )
    coeffs = tuple(float(c) for c in np.ravel(D)[: 4 if model == "fisheye" else 5])
    camera = Camera(w, h, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), model, coeffs)
    per_view = []
    for k, rvec, tvec in zip(used, rvecs, tvecs):
        R = cv2.Rodrigues(np.asarray(rvec, np.float64))[0]
        pts = np.asarray(views[k][0], np.float64) @ R.T + np.asarray(tvec, np.float64).reshape(1, 3)
        err = camera.project(pts) - np.asarray(views[k][1], np.float64)
        per_view.append(float(np.sqrt((err**2).sum(axis=1).mean())))
    rms = float(np.sqrt(np.mean(np.square(per_view))))
    return Calibration(camera, rms, tuple(per_view), tuple(names[k] for k in used), rejected)


def _unconstrained(K: np.ndarray, rvecs: Sequence[np.ndarray], size: tuple[int, int]) -> str | None:
    """Why a fit is degenerate (boards all facing one way, a focal length or centre no camera has), or None."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    spread = tilt_spread_deg(rvecs)
    if spread < CAMERA_CAL_MIN_TILT_SPREAD_DEG:
        return f"the board normals lie within {spread:.1f} deg of each other"
    if not (fx > 0 and fy > 0 and 0 <= cx < size[0] and 0 <= cy < size[1]):
        return f"the fit diverged: fx {fx:.4g} fy {fy:.4g} px, centre ({cx:.4g}, {cy:.4g})"
    return None


def tilt_spread_deg(rvecs: Sequence[np.ndarray]) -> float:
    """Largest angle between the board normals of any two views, deg.

    Parameters
    ----------
    rvecs : sequence of (3,) or (3, 1) Rodrigues vectors, board frame -> camera frame
    """
    cv2 = _cv2()
    normals = np.stack([cv2.Rodrigues(np.asarray(r, np.float64).reshape(3, 1))[0][:, 2] for r in rvecs])
    cosines = np.clip(normals @ normals.T, -1.0, 1.0)
    return float(np.degrees(np.arccos(cosines.min())))


def _fisheye_flag(cv2: ModuleType, name: str) -> int:
    # OpenCV 4 keeps the fisheye flags in cv2.fisheye (with their own values); OpenCV 5 unified them in cv2
    return int(getattr(cv2.fisheye, name, None) or getattr(cv2, name))


def calibrate_images(paths: list[str | Path], target: Target, model: str = "fisheye") -> Calibration:
    """Detect the target in image files and calibrate (all images must share one size)."""
    views, size = [], None
    for path in paths:
        image = read_image(path)
        if image is None:
            raise CaptureError(f"{path}: not a readable image")
        this = (image.shape[1], image.shape[0])
        if size is not None and this != size:
            raise CaptureError(f"{path}: size {this[0]}x{this[1]} differs from the first image's {size[0]}x{size[1]}")
        size = this
        views.append(target.detect(image))
    if size is None:
        raise CaptureError("no calibration images given")
    folders = {str(Path(p).parent) for p in paths}  # the one folder they came from leads the line where too few
    where = folders.pop() if len(folders) == 1 else None  # show the board (several folders: each image is named)
    return calibrate(views, size, model, [Path(p).name for p in paths], target.name, where)
