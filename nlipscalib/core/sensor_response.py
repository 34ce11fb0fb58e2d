"""How a capture's stored 16-bit values relate to light: the sensor response (:class:`SensorResponse`: bit depth,
black and white levels), the white level of a bit depth, and the one conversion of stored values to linear
intensity (:func:`linearise`), and the undoing of a camera's tone curve (:func:`undo_tone_curve`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from .errors import CaptureError, ShapeError
from .response_curve import check_curve, is_measured, measured_table

CAMERA_SETTINGS_GUIDE = 'docs/formats.md, "Cameras", in the nlipscalib source distribution or repository'
"""Where messages about a camera's settings (gamma, exposure, white balance, compression) send a lab: a file a
wheel's user does not have, so the message says where it is (tests/test_packaging.py)."""


def white_level_of(bit_depth: int) -> int:
    """The stored white level of a ``bit_depth``-bit sensor: its largest value shifted up to 16 bits, as stored
    values are (``DN << (16 - bit_depth)``, docs/formats.md; ``device.camera.to_stored``): 0xFF00 at 8 bits."""
    return ((1 << bit_depth) - 1) << (16 - bit_depth)


CAMERA_RESPONSES = ("linear", "srgb")
"""The named values of meta.json's ``sensor.camera_response`` (:attr:`SensorResponse.camera_response`): "linear",
stored values proportional to light (raw frames, the camera's gamma off); "srgb", frames encoded with the sRGB
transfer curve (IEC 61966-2-1), as a webcam that cannot turn its tone curve off delivers them. Beside them, a
measured curve (``nlips calibrate-camera-response``): "measured:<hash>", its table in ``sensor.response_curve``
(:mod:`.response_curve`)."""


def known_response(camera_response: object) -> bool:
    """Whether ``camera_response`` is one meta.json may declare: one of :data:`CAMERA_RESPONSES`, or a measured
    curve's name (``"measured:<hash>"``, :func:`.response_curve.is_measured`)."""
    return camera_response in CAMERA_RESPONSES or is_measured(camera_response)


def srgb_to_linear(encoded: np.ndarray) -> np.ndarray:
    """The exact inverse sRGB transfer function of IEC 61966-2-1: ``V / 12.92`` up to 0.04045, else
    ``((V + 0.055) / 1.055) ** 2.4``; below 0 the straight part goes on (``V / 12.92``: noise under black stays
    noise, as the scRGB extension of the standard has it).

    Parameters
    ----------
    encoded : (...) float -- encoded values V, 0 = black, 1 = full scale

    Returns
    -------
    (...) float64, linear light, 0 = black, 1 = full scale
    """
    v = np.asarray(encoded, np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((np.maximum(v, 0.04045) + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function of IEC 61966-2-1, :func:`srgb_to_linear`'s inverse: ``12.92 L`` up to 0.0031308,
    else ``1.055 L ** (1 / 2.4) - 0.055`` (the emulated sRGB camera's encoding, ``emulator.EMULATED_TONE_CURVES``).

    Parameters
    ----------
    linear : (...) float32, linear light in [0, 1]

    Returns
    -------
    (...) float32, encoded values V in [0, 1]
    """
    x = np.asarray(linear, np.float32)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, np.float32(1 / 2.4)) - 0.055).astype(np.float32)


def tone_curve_table(
    camera_response: str, black_level: float, white_level: float, curve: Sequence[float] | None = None
) -> np.ndarray | None:
    """The stored value each stored value of a ``camera_response`` camera stands for in light, as a table of the
    65536 uint16 values; None for "linear" (nothing to undo). A measured response ("measured:<hash>") is its
    ``curve`` (``sensor.response_curve``, :func:`.response_curve.measured_table`): (65536, 3), a column per
    channel, for a per-channel curve.

    The curve runs from the black level (encoded 0) to the white level (encoded 1), so both levels keep their
    values and :func:`linearise`'s scale, the dark-frame check and the saturation test read the linear values as
    they read a linear camera's; values above the white level are clipped anyway and kept as they are. Rounded
    to whole 16-bit steps (1/65535 of full scale: 1/257 of an 8-bit step)."""
    if camera_response == "linear":
        return None
    if is_measured(camera_response):
        if curve is None:
            raise CaptureError(f"camera response {camera_response} given without its response_curve")
        return measured_table(curve, black_level, white_level)
    stored = np.arange(65536, dtype=np.float64)
    span = white_level - black_level
    linear = black_level + span * srgb_to_linear((stored - black_level) / span)
    linear = np.where(stored >= white_level, stored, linear)
    return np.clip(np.rint(linear), 0, 65535).astype(np.uint16)


def undo_tone_curve(images: np.ndarray, table: np.ndarray | None) -> np.ndarray:
    """``images`` with the camera's tone curve undone (:func:`tone_curve_table`), in place; ``images`` itself
    when ``table`` is None (a linear camera: nothing touched).

    Parameters
    ----------
    images : (..., H, W, 3) uint16, stored values as the camera encoded them
    table : (65536,) uint16 from :func:`tone_curve_table`, (65536, 3) for a per-channel measured curve (a column
        per channel, R, G, B), or None

    Returns
    -------
    (..., H, W, 3) uint16, stored values linear in the light (the same array)
    """
    if table is None:
        return images
    if table.ndim == 1:
        np.take(table, images, out=images)
        return images
    for c in range(3):  # each channel through its own curve
        images[..., c] = table[images[..., c], c]
    return images


def redo_tone_curve(values: np.ndarray, table: np.ndarray | None) -> np.ndarray:
    """Stored values linear in the light back to the values the camera encoded them as, :func:`undo_tone_curve`'s
    inverse: for each, the middle of the stored values that ``table`` (:func:`tone_curve_table`, monotonic) undoes
    to it (where the curve is flatter than the 16-bit steps, several: the sRGB toe's 13); ``values`` themselves when
    ``table`` is None (a linear camera).

    Parameters
    ----------
    values : (..., 3) uint16 or float, stored values linear in the light (a column per channel, R, G, B)
    table : (65536,) or (65536, 3) uint16 from :func:`tone_curve_table`, or None

    Returns
    -------
    (..., 3) float64, stored values as the camera encoded them (``values`` for None)

    Why: a dark frame's level is told to a lab as the ``--black-level`` that ``nlips capture`` takes, the camera's
    own value; a press declaring an sRGB curve was told its linear one (2.047 of 255 for the 22 the camera gave,
    s37 capcheck)."""
    if table is None:
        return values

    def middle(column: np.ndarray, wanted: np.ndarray) -> np.ndarray:
        return (np.searchsorted(column, wanted, "left") + np.searchsorted(column, wanted, "right") - 1) / 2

    if table.ndim == 1:
        return middle(table, values)
    return np.stack([middle(table[:, c], values[..., c]) for c in range(3)], axis=-1)


def eight_bit_table(table: np.ndarray | None) -> np.ndarray:
    """The stored value of each 8-bit sample, with the camera's tone curve undone: (256,) uint16, ``table`` (from
    :func:`tone_curve_table`) at ``DN << 8`` (an 8-bit frame's stored values, ``device.camera.to_stored``), or
    ``DN << 8`` itself for None (a linear camera); (1, 256, 3) for a per-channel table (``cv2.LUT``'s table of a
    lookup per channel).

    Why: an 8-bit frame has 256 values, so the shift up to 16 bits and the curve are one lookup on the uint8 frame
    (``cv2.LUT``), bit for bit :func:`undo_tone_curve` of the shifted frame: 0.3 ms a 640x480 frame against 2-4
    (benchmarks/RESULTS.md, s29-lut8).
    """
    stored = np.arange(256, dtype=np.uint16) << np.uint16(8)
    if table is None:
        return stored
    if table.ndim == 2:
        return np.ascontiguousarray(table[stored][None], dtype=np.uint16)
    return np.ascontiguousarray(table[stored], dtype=np.uint16)


DECLARE_TONE_CURVE = (
    "or, when the camera cannot turn its gamma off, declare its sRGB curve and the tool undoes it: `nlips capture "
    '--camera-response srgb` (a capture already taken: meta.json "sensor": {"camera_response": "srgb"}); another '
    "curve (gamma 2.2, a vendor's): measure it once with `nlips calibrate-camera-response` and capture with "
    "`--camera-response FILE`"
)
"""The second cure the tone-curve messages name (the linearity warning, the dark-frame refusal): a webcam that
cannot switch gamma off is declared, not refused (docs/formats.md, "Cameras")."""
TONE_CURVE_LIFTS_DARK = (
    "A tone curve is steepest at black (sRGB: 12.92 times the linear slope), so it lifts the sensor's small dark "
    "offset and noise above the black level"
)
"""Why a camera's undeclared tone curve shows as a dark frame above the black level: said where the dark-frame
refusals of the solve (``solver.exposure.dark_frame_fault``) and of the capture
(``device.exposure.check_exposure``, at the reference) name the tone curve as the cause."""


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
    camera_response: str = "linear"
    """How the camera encodes light in its values (:data:`CAMERA_RESPONSES`): "linear" (raw frames), or "srgb" (the
    sRGB tone curve, undone once when the press is loaded, before the dark frame is subtracted). meta.json's
    ``sensor.camera_response``, absent in captures before it existed (and in linear ones: they are written as
    before, format_version 1). A measured curve: "measured:<hash>" (:mod:`.response_curve`)."""
    response_curve: tuple | None = None
    """The measured curve a "measured:<hash>" response names (meta.json ``sensor.response_curve``: 256 or 65536
    linear fractions of full scale, one per encoded fraction from black to white, or three such tuples, R, G, B,
    for a camera whose channels respond differently); None for "linear" and "srgb" (and then absent from
    meta.json)."""

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
        if not known_response(self.camera_response):
            raise CaptureError(
                f"sensor.camera_response must be one of {', '.join(map(repr, CAMERA_RESPONSES))} or a measured "
                "curve's name, measured:<hash> (docs/formats.md, meta.json, in the nlipscalib source distribution), "
                f"got {self.camera_response!r}"
            )
        self._check_curve()
        if not LEAST_BIT_DEPTH <= self.bit_depth <= 16:
            raise CaptureError(f"sensor.bit_depth must be {LEAST_BIT_DEPTH}..16, got {self.bit_depth}")
        if not 0 <= self.black_level < self.white_level <= 65535:
            raise CaptureError(
                f"sensor levels must satisfy 0 <= black_level < white_level <= 65535, "
                f"got {self.black_level}, {self.white_level}"
            )

    def _check_curve(self) -> None:
        """A measured response carries the curve it names, as a tuple (meta.json gives a list); no other does."""
        if not is_measured(self.camera_response):
            if self.response_curve is not None:
                raise CaptureError(
                    f"sensor.response_curve is given, but sensor.camera_response is {self.camera_response!r}, "
                    "not a measured curve (measured:<hash>)"
                )
            return
        if self.response_curve is None:
            raise CaptureError(f"sensor.camera_response is {self.camera_response} but sensor.response_curve is missing")
        try:
            curve = check_curve(self.response_curve, self.camera_response)
        except ValueError as exc:
            raise CaptureError(f"sensor.{exc}") from None
        object.__setattr__(self, "response_curve", curve)  # frozen: a list from meta.json kept as a tuple

    def tone_curve(self) -> np.ndarray | None:
        """The table that undoes this camera's tone curve (:func:`tone_curve_table`), None for a linear one."""
        return tone_curve_table(self.camera_response, self.black_level, self.white_level, self.response_curve)

    def saturated(self, image: np.ndarray) -> np.ndarray:
        """Which stored values are at or above the white level (clipped).

        Parameters
        ----------
        image : (..., H, W, 3) uint16 (or float) -- stored 16-bit values, not linearised (a tone curve undone or
            not: both keep the white level).

        Returns
        -------
        (..., H, W, 3) bool, per channel.
        """
        return image >= self.white_level
