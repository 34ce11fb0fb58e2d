"""Cheap image maps (OpenCV): normal maps and colour-mapped scalar maps with a small colour bar.

A matplotlib figure costs about 0.4 s to draw and 0.6 s to import; writing the same map as a plain PNG
through OpenCV (``cv2.applyColorMap`` + ``cv2.imencode``) costs milliseconds, so every solve can keep
its figures. The maps keep the image's pixel grid (one map pixel = one camera pixel) so they can be
laid over the capture; the colour bar is a strip added to the right.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.atomic import write_bytes
from ..errors import ShapeError, require
from .figures import normals_to_rgb

COLORMAPS = {
    "viridis": "COLORMAP_VIRIDIS",
    "magma": "COLORMAP_MAGMA",
    "inferno": "COLORMAP_INFERNO",
    "jet": "COLORMAP_JET",
    "turbo": "COLORMAP_TURBO",
    "gray": None,
}
"""Colour maps by their matplotlib names (the same ones the contact sheets use)."""
NO_VALUE_BGR = (217, 217, 217)
"""Pixels without a value (NaN, outside the mask): light grey, like the contact sheets."""
BAR_WIDTH = 64
"""Width of the colour bar strip, pixels (gradient, tick labels and unit)."""


def _cv2():
    return require("cv2", "opencv-python-headless", "Writing figure maps")


def normal_map_png(path: str | Path, normals: np.ndarray, mask: np.ndarray | None = None) -> Path:
    """Write a normal map (camera-facing = blue, see :func:`normals_to_rgb`) as an 8-bit PNG.

    Parameters
    ----------
    path : output .png
    normals : (H, W, 3) float, unit, camera frame
    mask : (H, W) bool, optional -- pixels outside are black
    """
    if normals.ndim != 3 or normals.shape[2] != 3:
        raise ShapeError(f"normal_map_png needs (H, W, 3) normals, got {normals.shape}")
    rgb = normals_to_rgb(normals, mask)
    return _write_png(path, np.round(rgb[..., ::-1] * 255).astype(np.uint8))


def scalar_map_png(
    path: str | Path,
    values: np.ndarray,
    cmap: str = "viridis",
    label: str = "",
    vmin: float | None = None,
    vmax: float | None = None,
) -> Path:
    """Write a scalar map in a colour map with a colour bar (range and unit) on the right, as an 8-bit PNG.

    Parameters
    ----------
    path : output .png
    values : (H, W) float, any unit (named by ``label``); NaN = no value (grey)
    cmap : one of :data:`COLORMAPS`
    label : unit shown under the colour bar, e.g. "mm" or "deg"
    vmin, vmax : colour range; default the 1st and 99th percentiles of the finite values
    """
    if values.ndim != 2:
        raise ShapeError(f"scalar_map_png needs (H, W) values, got {values.shape}")
    if cmap not in COLORMAPS:
        raise ShapeError(f"unknown colour map {cmap!r}; choose one of {sorted(COLORMAPS)}")
    vmin, vmax = _range(values, vmin, vmax)
    bgr = colour_scalars(values, vmin, vmax, cmap)
    return _write_png(path, np.concatenate([bgr, _colour_bar(values.shape[0], cmap, vmin, vmax, label)], axis=1))


def colour_scalars(
    values: np.ndarray, vmin: float, vmax: float, cmap: str = "viridis", no_value=NO_VALUE_BGR
) -> np.ndarray:
    """A scalar map in a colour map: ``vmin`` to ``vmax`` spread over its 256 colours, clipped at both ends.

    Parameters
    ----------
    values : (H, W) float, any unit; NaN = no value
    vmin, vmax : float, the colour range, in ``values``' unit (vmax > vmin)
    cmap : one of :data:`COLORMAPS`
    no_value : BGR of the pixels without a value (default :data:`NO_VALUE_BGR`)

    Returns
    -------
    (H, W, 3) uint8, BGR (OpenCV's order)
    """
    finite = np.isfinite(values)
    level = np.clip((np.nan_to_num(values) - vmin) / (vmax - vmin), 0.0, 1.0)
    bgr = _colour(np.round(level * 255).astype(np.uint8), cmap)
    bgr[~finite] = no_value
    return bgr


def _range(values: np.ndarray, vmin, vmax) -> tuple[float, float]:
    finite = values[np.isfinite(values)]
    if vmin is None:
        vmin = float(np.percentile(finite, 1)) if finite.size else 0.0
    if vmax is None:
        vmax = float(np.percentile(finite, 99)) if finite.size else 1.0
    if not vmax > vmin:
        vmax = vmin + (abs(vmin) * 1e-3 or 1.0)  # a constant map still gets a readable bar
    return float(vmin), float(vmax)


def _colour(levels: np.ndarray, cmap: str) -> np.ndarray:
    """(H, W) uint8 levels -> (H, W, 3) uint8 BGR."""
    cv2 = _cv2()
    name = COLORMAPS[cmap]
    if name is None:
        return np.repeat(levels[..., None], 3, axis=2)
    return cv2.applyColorMap(levels, getattr(cv2, name))


def _colour_bar(height: int, cmap: str, vmin: float, vmax: float, label: str) -> np.ndarray:
    """(height, BAR_WIDTH, 3) uint8 BGR: a vertical gradient (vmax at the top) with its range and unit."""
    cv2 = _cv2()
    bar = np.full((height, BAR_WIDTH, 3), 255, np.uint8)
    text_h = 12
    labelled = height >= 4 * text_h  # too short for text: the gradient alone
    top, bottom = (text_h + 2, height - text_h - 4) if labelled else (0, height)
    ramp = np.linspace(255, 0, bottom - top).round().astype(np.uint8)
    bar[top:bottom, 6:20] = _colour(np.repeat(ramp[:, None], 14, axis=1), cmap)
    if not labelled:
        return bar
    scale = max(0.3, min(0.4, height / 600))  # small images keep legible, tiny labels
    font = cv2.FONT_HERSHEY_SIMPLEX
    for text, y in ((_fmt(vmax), top + 8), (_fmt(vmin), bottom)):
        cv2.putText(bar, text, (22, y), font, scale, (0, 0, 0), 1, cv2.LINE_AA)
    if label:
        cv2.putText(bar, label, (4, height - 3), font, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return bar


def _fmt(v: float) -> str:
    return f"{v:.3g}"


def _write_png(path: str | Path, bgr: np.ndarray) -> Path:
    cv2 = _cv2()
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(bgr), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:  # pragma: no cover - OpenCV failure
        raise ShapeError(f"{path}: OpenCV could not encode the map")
    return write_bytes(path, buf.tobytes())
