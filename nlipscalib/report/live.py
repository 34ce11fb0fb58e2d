"""Pictures of a live stream: the window ``nlips live`` shows, and the PNG normal maps ``--save`` / ``--out`` keep.

device/live.py streams arrays through sinks; these sinks draw them (the CLI passes them in). The depth colours
are :mod:`.maps`' scalar colour mapping (viridis), the normal colours :func:`.figures.normals_to_rgb`'s.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.atomic import write_bytes
from ..core.errors import require
from .figures import normals_to_rgb
from .maps import colour_scalars

if TYPE_CHECKING:  # named in hints only: at run time report/ imports no computing package
    from ..device.live import LiveResult

WINDOW = "nlips live"
"""Title of the OpenCV window."""
OFF_GEL_RGB = (0, 0, 0)
"""Pixels without a depth (off the gel): black, so the dome's outline shows against the window."""
FLAT_RANGE_MM = 1e-9
"""Colour range of a depth map without a reference whose values are all equal, mm: any positive span (each
pixel is then at the range's bottom)."""


def depth_to_rgb(depth: np.ndarray, reference: np.ndarray | None = None, span_mm: float = 2.0) -> np.ndarray:
    """Depth map for viewing: indentation below the reference (or depth itself) on a colour scale.

    Parameters
    ----------
    depth : (H, W) float, mm, camera-frame z; NaN off the gel
    reference : (H, W) float, mm, the undeformed depth (None: the map's own range)
    span_mm : indentation shown at full colour, mm

    Returns
    -------
    (H, W, 3) uint8, RGB; black off the gel
    """
    if reference is not None:
        # a press pushes the gel toward the camera inside the dome: the indentation is reference - depth
        values, vmin, vmax = reference - depth, 0.0, span_mm
    else:
        valid = np.isfinite(depth)
        lo, hi = (float(np.nanmin(depth)), float(np.nanmax(depth))) if valid.any() else (0.0, 1.0)
        values, vmin, vmax = depth, lo, max(hi, lo + FLAT_RANGE_MM)
    return colour_scalars(values, vmin, vmax, "viridis", no_value=OFF_GEL_RGB)[..., ::-1].copy()


def normals_to_rgb8(normals: np.ndarray) -> np.ndarray:
    """(H, W, 3) float normals (unit, camera frame) -> (H, W, 3) uint8 RGB in normal-map colours (truncated)."""
    return (normals_to_rgb(normals) * 255).astype(np.uint8)


def display_available() -> bool:
    """True when an OpenCV window can be opened (a display, and an OpenCV built with a GUI)."""
    return window_problem() is None


NO_GUI = "this OpenCV has no GUI (opencv-python-headless)"
"""Why no window opens where a display is present but OpenCV was built without one: what the stream says, not
"no display" (the user sees a display, and would look for one)."""


def window_problem() -> str | None:
    """Why an OpenCV window cannot be opened (no display; an OpenCV without a GUI), or None when it can."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or os.name == "nt"):
        return "no display"
    cv2 = require("cv2", "opencv-python-headless", "Showing live maps")
    try:
        cv2.namedWindow(WINDOW, cv2.WINDOW_NORMAL)
    except cv2.error:
        return NO_GUI
    return None


class WindowSink:
    """Normals and depth side by side in an OpenCV window; q or Esc ends the stream.

    Parameters
    ----------
    stop : the exception that ends the stream (``device.live.StopLive``; passed in: report/ imports no computing
        package)
    reference_depth : (H, W) float, mm, the undeformed depth (None: each depth map in its own range)
    """

    def __init__(self, stop: type[BaseException], reference_depth: np.ndarray | None = None):
        self.cv2 = require("cv2", "opencv-python-headless", "Showing live maps")
        self.stop, self.reference_depth = stop, reference_depth

    def __call__(self, index: int, frame: np.ndarray, result: LiveResult) -> None:
        normals = normals_to_rgb8(result.normals)
        view = np.concatenate([normals, depth_to_rgb(result.depth, self.reference_depth)], axis=1)
        self.cv2.imshow(WINDOW, view[..., ::-1])
        if self.cv2.waitKey(1) & 0xFF in (ord("q"), 27):
            raise self.stop


class NormalMapPng:
    """A frame's normal map as ``STEM_normals.png`` (normal-map colours, 8 bits): the ``pictures`` of
    ``device.live.SaveSink``."""

    def __init__(self):
        self.cv2 = require("cv2", "opencv-python-headless", "Saving live maps")

    def __call__(self, stem: Path, result: LiveResult) -> None:
        ok, png = self.cv2.imencode(".png", np.ascontiguousarray(normals_to_rgb8(result.normals)[..., ::-1]))
        if ok:
            write_bytes(stem.with_name(stem.name + "_normals.png"), png.tobytes())
