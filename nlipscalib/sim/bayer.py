"""A Bayer camera in the twin: colour crosstalk of the sensor's filters, the mosaic and the camera's demosaicing.

The twin renders three colour values per pixel; a webcam's sensor records one per pixel, through a 2x2 colour filter
pattern (RGGB and its shifts), and its image signal processor (or OpenCV, for a raw mode) interpolates the other
two from the neighbours. That mixes neighbouring pixels' colours where the light changes within 2 px (zipper and
false colour at edges) and correlates the noise of neighbouring pixels. The filters also pass some light of the
other colours (crosstalk): a red LED's light reaches the green pixels, which a narrow-band tri-colour frame shows
and a white LED image does not tell.

Order, as in a camera: linear light -> :func:`apply_crosstalk` -> sensor noise and quantisation (``sim.noise``, per
pixel and channel; keeping each pixel's own channel of that is the noisy mosaic) -> :func:`bayer_camera`. OpenCV's
demosaicing (``cv2.cvtColor``, ``COLOR_Bayer*2RGB`` and ``*_EA``) does the interpolation: a well-kept, fast C++
implementation of what camera drivers ship, on 16-bit frames.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import require

BAYER_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
"""The 2x2 colour filter patterns, read row by row from the frame's top-left pixel (RGGB: red at (u, v) = (0, 0),
green at (1, 0) and (0, 1), blue at (1, 1))."""

DEMOSAIC_METHODS = ("edge_aware", "bilinear")
"""OpenCV's demosaicing at 16 bits: ``edge_aware`` (``COLOR_Bayer*2RGB_EA``: each missing green interpolated along
the edge, not across it, the other colours from their difference to green) and ``bilinear`` (``COLOR_Bayer*2RGB``:
the mean of the nearest pixels of that colour, linear in the raw values). Why ``edge_aware`` is the twin's default:
a webcam's image signal processor interpolates along edges (gradient-directed demosaicing, with false-colour
suppression) rather than bilinearly; OpenCV's VNG, closer still, takes 8-bit frames only and the twin's are 16-bit."""

# OpenCV names a Bayer code after the colours of the second row's second and third pixels, one pixel down and right
# of ours: the RGGB frame (red at its top-left) is its "BG" (checked on flat fields by tests/sim/test_bayer.py)
_OPENCV_NAME = {"RGGB": "BG", "BGGR": "RG", "GRBG": "GB", "GBRG": "GR"}

_CHANNEL = {"R": 0, "G": 1, "B": 2}

TYPICAL_CROSSTALK = ((1.0, 0.08, 0.02), (0.10, 1.0, 0.15), (0.02, 0.12, 1.0))
"""Colour crosstalk of a typical webcam CMOS sensor under narrow-band LEDs, ``[camera channel][light colour]``
(rows R, G, B pixels; columns red ~625 nm, green ~525 nm, blue ~465 nm light), each colour's own filter 1: the
quantum efficiency curves published for common webcam sensors (Sony IMX219 / IMX291, OmniVision OV5647 class) pass
5-10 % of the green LED's light through the red filter, 10-15 % of the red and blue LEDs' through the green filter
and 10-15 % of the green through the blue; a few % between red and blue. Round figures read off such curves, not a
measurement of one camera (``nlips render --crosstalk typical``)."""

IDENTITY_CROSSTALK = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
"""No crosstalk: each filter passes its own colour only (the twin's default)."""


def bayer_channels(shape: tuple[int, int], pattern: str) -> np.ndarray:
    """(H, W) uint8: the colour channel (0 R, 1 G, 2 B) each pixel of a ``shape`` (H, W) frame records under the
    2x2 filter ``pattern`` (one of :data:`BAYER_PATTERNS`)."""
    _check(pattern in BAYER_PATTERNS, f"Bayer pattern {pattern!r}: must be one of {', '.join(BAYER_PATTERNS)}")
    cell = np.array([[_CHANNEL[pattern[0]], _CHANNEL[pattern[1]]], [_CHANNEL[pattern[2]], _CHANNEL[pattern[3]]]])
    height, width = shape
    return np.tile(cell, ((height + 1) // 2, (width + 1) // 2))[:height, :width].astype(np.uint8)


def mosaic(images: np.ndarray, pattern: str) -> np.ndarray:
    """The raw frames a Bayer sensor records of colour images: each pixel's own channel.

    Parameters
    ----------
    images : (..., H, W, 3) -- colour images (any dtype; the sensor's noise already in them)
    pattern : one of :data:`BAYER_PATTERNS`

    Returns
    -------
    (..., H, W), ``images``' dtype
    """
    images = np.asarray(images)
    _check(images.ndim >= 3 and images.shape[-1] == 3, f"mosaic: images must be (..., H, W, 3), got {images.shape}")
    channels = bayer_channels(images.shape[-3:-1], pattern)
    index = np.broadcast_to(channels[..., None], (*images.shape[:-1], 1))
    return np.take_along_axis(images, index.astype(np.intp), axis=-1)[..., 0]


def demosaic(raw: np.ndarray, pattern: str, method: str = "edge_aware") -> np.ndarray:
    """Colour images interpolated from raw Bayer frames by OpenCV, as a camera's image signal processor does.

    Parameters
    ----------
    raw : (..., H, W) uint8 or uint16 -- raw frames (:func:`mosaic`), H and W at least 2
    pattern : one of :data:`BAYER_PATTERNS`
    method : one of :data:`DEMOSAIC_METHODS`

    Returns
    -------
    (..., H, W, 3) RGB, ``raw``'s dtype; a flat colour field comes back as it was (edges included)
    """
    cv2 = require("cv2", "opencv-python-headless", "The Bayer camera's demosaicing")
    raw = np.asarray(raw)
    _check(raw.ndim >= 2 and min(raw.shape[-2:]) >= 2, f"demosaic: raw must be (..., H, W), got {raw.shape}")
    _check(raw.dtype in (np.uint8, np.uint16), f"demosaic: raw must be uint8 or uint16, got {raw.dtype}")
    _check(method in DEMOSAIC_METHODS, f"demosaic method {method!r}: must be one of {', '.join(DEMOSAIC_METHODS)}")
    _check(pattern in BAYER_PATTERNS, f"Bayer pattern {pattern!r}: must be one of {', '.join(BAYER_PATTERNS)}")
    code = getattr(cv2, f"COLOR_Bayer{_OPENCV_NAME[pattern]}2RGB" + ("_EA" if method == "edge_aware" else ""))
    flat = raw.reshape(-1, *raw.shape[-2:])
    out = np.empty((*flat.shape, 3), raw.dtype)
    for k, frame in enumerate(flat):
        cv2.cvtColor(np.ascontiguousarray(frame), code, dst=out[k])
    return out.reshape(*raw.shape, 3)


def bayer_camera(images: np.ndarray, pattern: str, method: str = "edge_aware") -> np.ndarray:
    """(..., H, W, 3) ``images`` (uint16 stored frames, noise and quantisation in each pixel's three values) as a
    Bayer camera delivers them: :func:`mosaic` then :func:`demosaic`. Why after the noise: each pixel's own channel
    of frames noised per pixel and channel is the sensor's noisy raw frame (the others' noise is dropped)."""
    return demosaic(mosaic(images, pattern), pattern, method)


def apply_crosstalk(linear: np.ndarray, matrix: tuple[tuple[float, ...], ...] | np.ndarray) -> np.ndarray:
    """What the camera's three filters pass of linear light in three colours.

    Parameters
    ----------
    linear : (..., 3) float -- linear light per colour (red, green, blue)
    matrix : (3, 3) float -- ``matrix[c][s]``: the share of colour ``s``'s light that channel ``c`` records
        (:data:`TYPICAL_CROSSTALK`, :data:`IDENTITY_CROSSTALK`)

    Returns
    -------
    (..., 3) float32 -- channel ``c`` = sum over ``s`` of ``matrix[c][s] * linear[..., s]``
    """
    mix = np.asarray(matrix, dtype=np.float32)
    _check(mix.shape == (3, 3), f"crosstalk matrix must be 3x3, got shape {mix.shape}")
    linear = np.asarray(linear, dtype=np.float32)
    _check(linear.shape[-1:] == (3,), f"apply_crosstalk: linear must be (..., 3), got {linear.shape}")
    if np.array_equal(mix, np.eye(3, dtype=np.float32)):
        return linear
    return linear @ mix.T


def _check(ok: bool, line: str) -> None:
    """A caller's wrong argument (the scene's own fields are checked as it loads): ValueError with ``line``."""
    if not ok:
        raise ValueError(line)
