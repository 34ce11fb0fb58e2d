"""Pictures of a live stream: the window ``nlips live`` shows, and the PNG normal maps ``--save`` / ``--out`` keep.

device/live.py streams arrays through sinks; these sinks draw them (the CLI passes them in). The depth colours
are :mod:`.maps`' scalar colour mapping (viridis) with its colour bar, the normal colours
:func:`.figures.normals_to_rgb`'s.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.atomic import write_bytes
from ..core.errors import require
from .figures import normals_to_rgb
from .maps import colour_bar, colour_scalars

if TYPE_CHECKING:  # named in hints only: at run time report/ imports no computing package
    from ..device.live import LiveResult

WINDOW = "nlips live"
"""Title of the OpenCV window."""
OFF_GEL_RGB = (0, 0, 0)
"""Pixels without a depth (off the gel): black, so the dome's outline shows against the window."""
FLAT_RANGE_MM = 1e-9
"""Colour range of a depth map without a reference whose values are all equal, mm: any positive span (each
pixel is then at the range's bottom)."""


def depth_scale(
    depth: np.ndarray, reference: np.ndarray | None = None, span_mm: float = 2.0
) -> tuple[np.ndarray, float, float, str]:
    """What the live view shows of a depth map: the indentation below the reference (or depth itself), its colour
    range and the colour bar's unit label.

    Parameters
    ----------
    depth : (H, W) float, mm, camera-frame z; NaN off the gel
    reference : (H, W) float, mm, the undeformed depth (None: the map's own range)
    span_mm : indentation shown at full colour, mm

    Returns
    -------
    values : (H, W) float, mm, NaN off the gel
    vmin, vmax : the colour range, mm (0 to ``span_mm`` with a reference)
    label : "indentation, mm" or "camera z, mm"
    """
    if reference is not None:
        # a press pushes the gel toward the camera inside the dome: the indentation is reference - depth
        return reference - depth, 0.0, span_mm, "indentation, mm"
    valid = np.isfinite(depth)
    lo, hi = (float(np.nanmin(depth)), float(np.nanmax(depth))) if valid.any() else (0.0, 1.0)
    return depth, lo, max(hi, lo + FLAT_RANGE_MM), "camera z, mm"


def depth_to_rgb(depth: np.ndarray, reference: np.ndarray | None = None, span_mm: float = 2.0) -> np.ndarray:
    """Depth map for viewing: indentation below the reference (or depth itself) on a colour scale
    (:func:`depth_scale`).

    Returns
    -------
    (H, W, 3) uint8, RGB; black off the gel
    """
    values, vmin, vmax, _ = depth_scale(depth, reference, span_mm)
    return colour_scalars(values, vmin, vmax, "viridis", no_value=OFF_GEL_RGB)[..., ::-1].copy()


def depth_bar_rgb(
    depth: np.ndarray, reference: np.ndarray | None = None, span_mm: float = 2.0
) -> tuple[np.ndarray, np.ndarray]:
    """The live view's depth map and its colour bar strip (the maps' :func:`.maps.colour_bar`: range and unit;
    "2+" when a press is deeper than ``span_mm``, "<=0" when the gel lies behind its undeformed surface).

    Returns
    -------
    depth_rgb : (H, W, 3) uint8, RGB; black off the gel (:func:`depth_to_rgb`)
    bar_rgb : (H, :data:`.maps.BAR_WIDTH`, 3) uint8, RGB
    """
    values, vmin, vmax, label = depth_scale(depth, reference, span_mm)
    rgb = colour_scalars(values, vmin, vmax, "viridis", no_value=OFF_GEL_RGB)[..., ::-1]
    fixed = reference is not None  # a fixed scale: values beyond it are marked (the own range holds them all)
    finite = values[np.isfinite(values)] if fixed else values[:0]
    over, under = bool(np.any(finite > vmax)), bool(np.any(finite < vmin))
    bar = colour_bar(values.shape[0], "viridis", vmin, vmax, label, over, under)[..., ::-1]
    return rgb, bar


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
    # Windows and macOS always have their own display server; only X11 and Wayland name theirs in the environment
    desktop = os.name == "nt" or sys.platform == "darwin"
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or desktop):
        return "no display"
    cv2 = require("cv2", "opencv-python-headless", "Showing live maps")
    try:
        cv2.namedWindow(WINDOW, cv2.WINDOW_NORMAL)
    except cv2.error:
        return NO_GUI
    return None


class WindowSink:
    """Normals and depth side by side in an OpenCV window, the depth's colour bar (range, unit) at its right; q or
    Esc ends the stream.

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
        view = np.concatenate([normals, *depth_bar_rgb(result.depth, self.reference_depth)], axis=1)
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
