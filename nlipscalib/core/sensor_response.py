"""How a capture's stored 16-bit values relate to light: the sensor response (:class:`SensorResponse`: bit depth,
black and white levels), the white level of a bit depth, and the one conversion of stored values to linear
intensity (:func:`linearise`)."""

from __future__ import annotations

import dataclasses

import numpy as np

from .errors import CaptureError, ShapeError

CAMERA_SETTINGS_GUIDE = 'docs/formats.md, "Cameras", in the nlipscalib source distribution or repository'
"""Where messages about a camera's settings (gamma, exposure, white balance, compression) send a lab: a file a
wheel's user does not have, so the message says where it is (tests/test_packaging.py)."""


def white_level_of(bit_depth: int) -> int:
    """The stored white level of a ``bit_depth``-bit sensor: its largest value shifted up to 16 bits, as stored
    values are (``DN << (16 - bit_depth)``, docs/formats.md; ``device.camera.to_stored``): 0xFF00 at 8 bits."""
    return ((1 << bit_depth) - 1) << (16 - bit_depth)


LEAST_BIT_DEPTH = 8
"""Fewest bits a sensor's values have (:attr:`SensorResponse.bit_depth`): an 8-bit camera, video or image file."""


CLIPPED_VALUE = white_level_of(LEAST_BIT_DEPTH)
"""Stored values from here up count as clipped in a frame from any source (``nlips infer``'s images and streams),
even below the sensor's white level: the white level of the fewest bits a frame has, an 8-bit frame's 255 shifted
up to 16 bits (0xFF00)."""


def linearise(
    image: np.ndarray, dark: np.ndarray, black_level: float, white_level: float, out: np.ndarray | None = None
) -> np.ndarray:
    """Dark-subtracted linear intensity, scaled so the sensor's full range is 1: the one conversion of stored
    values to light (:meth:`.capture.Press.linear`, NLiPsNet's frames, the capture's exposure check).

    Parameters
    ----------
    image : (..., H, W, 3) stored values (uint16), or a scalar (one stored level, e.g. the clipping value)
    dark : (H, W, 3) the dark frame's stored values (uint16, or float32 already); any shape that ``image``
        ends with (e.g. (N, 3), the gel's pixels)
    black_level, white_level : the sensor's levels (:class:`SensorResponse`), 16-bit units
    out : (..., H, W, 3) float32 or None -- written and returned when given (an array image only)

    Returns
    -------
    (..., H, W, 3) float32, 0 = dark frame, 1 = full scale: ``(image - dark) / (white_level - black_level)``
    """
    image, dark = np.asarray(image), np.asarray(dark)
    if image.ndim and image.shape[image.ndim - dark.ndim :] != dark.shape:  # (H, W, 3) - (1, W, 3) broadcast silently
        raise ShapeError(f"image {image.shape} must end with the dark frame's shape {dark.shape}")
    scale = np.float32(white_level - black_level)
    # one float32 array, cast while subtracting and divided in place: the same numbers as casting both first, without
    # two more arrays of the result's size (12 LED images at 640x480: 44 MB each, most of their cost page faults)
    diff = np.subtract(image, dark, dtype=np.float32, out=out)
    return np.divide(diff, scale, out=diff) if diff.ndim else diff / scale


@dataclasses.dataclass(frozen=True)
class SensorResponse:
    """How stored 16-bit values relate to light."""

    bit_depth: int = 12
    """Bits of the sensor ADC; stored values are DN << (16 - bit_depth)."""
    black_level: float = 256.0
    """Stored value of zero light (16-bit units), before read noise."""
    white_level: float = 65520.0
    """Largest stored value; pixels at or above it are saturated (16-bit units)."""
    exposure_ms: float = 10.0
    """Exposure time, ms (informational; images are not normalised by it); > 0."""
    gain: float = 1.0
    """Analogue gain (informational); >= 0."""

    def __post_init__(self):
        from .config import is_finite_number, is_whole_number

        # types first: a string compared below would fail as "'<=' not supported ...", naming no key
        if not is_whole_number(self.bit_depth):
            raise CaptureError(f"sensor.bit_depth must be a whole number of bits, got {self.bit_depth!r}")
        for key in ("black_level", "white_level", "exposure_ms", "gain"):
            if not is_finite_number(getattr(self, key)):
                raise CaptureError(f"sensor.{key} must be a finite number, got {getattr(self, key)!r}")
        if not self.exposure_ms > 0 or self.gain < 0:
            raise CaptureError(
                f"sensor.exposure_ms must be > 0 and sensor.gain >= 0, got {self.exposure_ms}, {self.gain}"
            )
        if not LEAST_BIT_DEPTH <= self.bit_depth <= 16:
            raise CaptureError(f"sensor.bit_depth must be {LEAST_BIT_DEPTH}..16, got {self.bit_depth}")
        if not 0 <= self.black_level < self.white_level <= 65535:
            raise CaptureError(
                f"sensor levels must satisfy 0 <= black_level < white_level <= 65535, "
                f"got {self.black_level}, {self.white_level}"
            )

    def saturated(self, image: np.ndarray) -> np.ndarray:
        """Which stored values are at or above the white level (clipped).

        Parameters
        ----------
        image : (..., H, W, 3) uint16 (or float) -- stored 16-bit values, not linearised.

        Returns
        -------
        (..., H, W, 3) bool, per channel.
        """
        return image >= self.white_level
