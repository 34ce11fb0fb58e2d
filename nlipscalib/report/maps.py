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
from ..core.errors import ShapeError, require
from ..core.imageio import png_params
from .figures import NO_VALUE_GREY, normals_to_rgb

COLORMAPS = {
    "viridis": "COLORMAP_VIRIDIS",
    "magma": "COLORMAP_MAGMA",
    "inferno": "COLORMAP_INFERNO",
    "jet": "COLORMAP_JET",
    "turbo": "COLORMAP_TURBO",
    "gray": None,
}
"""Colour maps by their matplotlib names (the same ones the contact sheets use)."""
NO_VALUE_BGR = (round(255 * NO_VALUE_GREY),) * 3
"""Pixels without a value (NaN, outside the mask): :data:`.figures.NO_VALUE_GREY`, like the contact sheets."""
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
    mask : (H, W) bool, optional -- pixels outside are grey (:data:`NO_VALUE_BGR`)
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

    The map keeps the image's pixel grid from its top-left corner; a map shorter than its colour bar needs
    (:func:`bar_min_height`) gets white rows below it, so its range and unit stay readable.

    Parameters
    ----------
    path : output .png
    values : (H, W) float, any unit (named by ``label``); NaN = no value (grey)
    cmap : one of :data:`COLORMAPS`
    label : unit shown under the colour bar, e.g. "mm" or "deg" (wrapped at spaces to the bar's width)
    vmin, vmax : colour range; default the 1st and 99th percentiles of the finite values. Values above ``vmax``
        show in its colour, and the bar's top number says so ("10+") when ``vmax`` was given (a fixed scale; the
        default range leaves the top 1 % above it by definition); likewise values below a given ``vmin`` ("<=0":
        an indentation map's pixels behind the undeformed surface)
    """
    if values.ndim != 2:
        raise ShapeError(f"scalar_map_png needs (H, W) values, got {values.shape}")
    if cmap not in COLORMAPS:
        raise ShapeError(f"unknown colour map {cmap!r}; choose one of {sorted(COLORMAPS)}")
    fixed_bottom, fixed_top = vmin is not None, vmax is not None
    vmin, vmax = colour_range(values, vmin, vmax)
    bgr = colour_scalars(values, vmin, vmax, cmap)
    finite = values[np.isfinite(values)]
    over = fixed_top and bool(np.any(finite > vmax))
    under = fixed_bottom and bool(np.any(finite < vmin))
    height = max(values.shape[0], bar_min_height(label))
    bgr = np.concatenate([bgr, np.full((height - values.shape[0],) + bgr.shape[1:], 255, np.uint8)], axis=0)
    strip = colour_bar(height, cmap, vmin, vmax, label, over, under=under)
    return _write_png(path, np.concatenate([bgr, strip], axis=1))


def colour_scalars(
    values: np.ndarray,
    vmin: float,
    vmax: float,
    cmap: str = "viridis",
    no_value: tuple[int, int, int] = NO_VALUE_BGR,
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


def colour_range(values: np.ndarray, vmin: float | None = None, vmax: float | None = None) -> tuple[float, float]:
    """The colour range of a scalar map: ``vmin``/``vmax`` where given, else the 1st/99th percentile of the finite
    values (one outlier pixel does not take the whole scale); a constant map still gets a non-empty range.

    Parameters
    ----------
    values : (H, W) float, NaN = no value
    """
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


LINE_PX = 12
"""Height of one line of colour-bar text, pixels (a Hershey font at scale 0.3-0.4 is 8-11 px tall)."""
FONT_SCALES = (0.4, 0.35, 0.3)
"""Hershey font scales a colour-bar text may use, largest first: the largest that fits the strip's width is used
(0.3 is the smallest that stays legible; "-1.23e-5" needs 43 px at 0.3)."""
RAMP_COLS = (4, 16)
"""Columns of the gradient within the strip; the numbers start 2 px right of it."""


def bar_min_height(label: str = "") -> int:
    """Pixels a labelled colour bar needs: a gradient two lines tall (vmax beside its top, vmin beside its bottom)
    and ``label``'s lines under it, with margins."""
    return (2 + len(_unit_lines(label))) * LINE_PX + 8


def colour_bar(
    height: int, cmap: str, vmin: float, vmax: float, label: str, over: bool = False, under: bool = False
) -> np.ndarray:
    """(height, BAR_WIDTH, 3) uint8 BGR: a vertical gradient (vmax at the top) with its range and unit.

    Shorter than :func:`bar_min_height`: the gradient alone (:func:`scalar_map_png` pads maps so that this does
    not happen). ``over``: values above ``vmax`` exist and show in its colour; its number reads "10+". ``under``:
    values below ``vmin`` exist and show in its colour; its number reads "<=0".
    """
    bar = np.full((height, BAR_WIDTH, 3), 255, np.uint8)
    lines = _unit_lines(label)
    labelled = height >= bar_min_height(label)
    top, bottom = (2, height - LINE_PX * len(lines) - 4) if labelled else (0, height)
    ramp = np.linspace(255, 0, bottom - top).round().astype(np.uint8)
    left, right = RAMP_COLS
    bar[top:bottom, left:right] = _colour(np.repeat(ramp[:, None], right - left, axis=1), cmap)
    if not labelled:
        return bar
    largest = max(FONT_SCALES[-1], min(FONT_SCALES[0], height / 600))  # small maps: small, still legible text
    _put(bar, _fmt(vmax) + ("+" if over else ""), right + 2, top + LINE_PX - 2, largest)
    _put(bar, ("<=" if under else "") + _fmt(vmin), right + 2, bottom - 1, largest)
    for i, text in enumerate(lines):
        _put(bar, text, 2, height - 3 - LINE_PX * (len(lines) - 1 - i), largest)
    return bar


def _put(bar: np.ndarray, text: str, x: int, y: int, largest: float) -> None:
    """Write ``text`` at (x, baseline y) in the largest of ``FONT_SCALES`` (at most ``largest``) that ends inside
    the strip."""
    cv2 = _cv2()
    font = cv2.FONT_HERSHEY_SIMPLEX
    scales = [s for s in FONT_SCALES if s <= largest] or [FONT_SCALES[-1]]
    fits = [s for s in scales if x + cv2.getTextSize(text, font, s, 1)[0][0] < bar.shape[1]]
    cv2.putText(bar, text, (x, y), font, (fits or scales[-1:])[0], (0, 0, 0), 1, cv2.LINE_AA)


def _unit_lines(label: str) -> list[str]:
    """``label`` split at spaces into lines that fit the strip at the smallest font scale ([] for no label)."""
    cv2 = _cv2()
    lines: list[str] = []
    for word in label.split():
        joined = f"{lines[-1]} {word}" if lines else word
        width = cv2.getTextSize(joined, cv2.FONT_HERSHEY_SIMPLEX, FONT_SCALES[-1], 1)[0][0]
        if lines and 2 + width < BAR_WIDTH:
            lines[-1] = joined
        else:
            lines.append(word)
    return lines


def _fmt(v: float) -> str:
    """A colour-bar number in at most three significant digits, exponent without padding ("1.23e-5", not
    "1.23e-05"): the numbers have 45 px of the strip."""
    text = f"{v:.3g}"
    mantissa, _, exponent = text.partition("e")
    return f"{mantissa}e{int(exponent)}" if exponent else text


def _write_png(path: str | Path, bgr: np.ndarray) -> Path:
    cv2 = _cv2()
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(bgr), png_params())
    if not ok:  # pragma: no cover - OpenCV failure
        raise ShapeError(f"{path}: OpenCV could not encode the map")
    return write_bytes(path, buf.tobytes())
