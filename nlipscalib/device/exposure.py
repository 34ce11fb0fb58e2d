"""Exposure check of a captured press: LED frames that show no light, frames with much of the gel saturated.

A capture session locks its exposure and LED levels when the reference is taken (a resumed session must keep
them), so an exposure problem is best caught at once: :func:`check_exposure` runs on every press and the
reference as they are captured (:func:`nlipscalib.device.session.capture_press`). It warns, one line per
problem naming the files, when LED frames are black (no light above the dark frame: LEDs off, lens cap) or
a large share of the gel is saturated (a shorter ``--exposure-ms`` or a lower LED level needed) or an LED frame
repeats the frame before it (the camera's frames lag the LED switch: a larger ``--flush`` needed), and refuses
a reference whose LED frames are all black or saturated, which nothing downstream can use. Thresholds:
:mod:`nlipscalib.core.tolerances` (``EXPOSURE_*``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..core.compression import blockiness_line, compressed
from ..core.dark_pedestal import camera_dn, even_dark_offset
from ..core.errors import CaptureError, require
from ..core.lag_blind import say_lag_blind
from ..core.repeated_frames import ExpectedLight, dark_everywhere_line, frame_checks, lagged_line, repeated_line
from ..core.sensor_response import (
    CAMERA_SETTINGS_GUIDE,
    DECLARE_TONE_CURVE,
    TONE_CURVE_LIFTS_DARK,
    SensorResponse,
    linearise,
    undo_tone_curve,
)
from ..core.tolerances import (
    CAPTURE_CHECK_BLUR,
    DARK_FRAME_OFFSET,
    DECLARED_CURVE_SLOPE,
    EXPOSURE_LIGHT_FRACTION,
    EXPOSURE_LIT_SHARE,
    EXPOSURE_SATURATED_SHARE,
    EXPOSURE_UNUSABLE_SHARE,
    LINEAR_RESPONSE_SLOPE,
)

NAMED = 3
"""Most files a warning names (then "and N more")."""

ResponseSlope = Callable[[np.ndarray, np.ndarray], "float | None"]
"""How the LED frames grow with the light: ``slope(led_frames, dark)``, the (L, H, W, 3) uint16 LED frames and the
(H, W, 3) uint16 dark frame (stored values, a declared tone curve undone), to the median log-log slope of each
pixel's dark-subtracted values against the sensor model's light (1: linear; ~0.5: gamma-encoded), None when it cannot
be told. The solve's check (``solver.led_checks.recorded_response_slope``), which the CLI wires in
(``cli.capture_checks``): device/ never imports solver/."""


def check_exposure(
    frames: dict[str, np.ndarray],
    response: SensorResponse,
    folder: str | Path,
    gel: np.ndarray | None = None,
    reference: bool = False,
    expected: ExpectedLight | None = None,
    response_slope: ResponseSlope | None = None,
) -> list[str]:
    """The exposure warnings of one captured press (none when it is well exposed).

    Parameters
    ----------
    frames : dict name -> (H, W, 3) uint16 stored image
        What :func:`nlipscalib.device.session.capture_frames` returns: ``tricolor``, ``dark``, ``led_01`` ...
        (as the camera encoded them: a declared tone curve, ``response.camera_response``, is undone on copies)
    response : SensorResponse
        Black and white level of the stored values, and the camera's tone curve.
    folder : path
        The press folder, for the messages (its files are named as :func:`nlipscalib.core.write_press` names them).
    gel : (H, W) bool, optional
        The pixels that see the gel (``np.isfinite(reference.depth)``); the whole frame when None.
    reference : bool
        The session's reference: wholly black or wholly saturated is a CaptureError, not a warning.
    expected : ExpectedLight, optional
        The image model's light on the undeformed gel (:func:`nlipscalib.core.repeated_frames.model_light`): rows
        that look dark in every LED frame are judged again against it (a wide view's dome base is lit less).
    response_slope : ResponseSlope, optional
        The tone-curve check of a ``reference`` (asked once, ~0.3 s at 640x480): LED frames not linear in the light
        are warned about first (:func:`_tone_curve_lines`), and with a dark frame evenly above the black level
        refused naming the tone curve, not the black level (:func:`_refuse_pedestal`); None: not judged.

    Returns
    -------
    list of str
        At most seven lines: a ``reference``'s tone curve (:func:`_tone_curve_lines`), the black LED frames, the
        over-exposed frames, the repeated LED frames, the partly lagged ones, rows dark in every LED frame, the
        JPEG-compressed LED frames.

    Raises
    ------
    CaptureError
        ``reference`` and nothing usable: every LED frame black or saturated.
    """
    require("cv2", "opencv-python-headless", "The exposure check")
    folder = Path(folder)
    stored_dark = frames["dark"]  # as the camera gave it: the --black-level a pedestal asks for
    if (curve := response.tone_curve()) is not None:  # a declared sRGB camera: checked in light, as it is solved
        frames = {name: undo_tone_curve(frame.copy(), curve) for name, frame in frames.items()}
    names = sorted(name for name in frames if name.startswith("led_"))
    outlined = _has_gel(gel, frames["dark"].shape[:2])
    gel, where = _gel(gel, frames["dark"].shape[:2])
    clipped = {f"{name}.png": _saturated_share(frames[name], response, gel) for name in names}
    clipped["tricolor.png"] = _saturated_share(frames["tricolor"], response, gel)
    dark = frames["dark"].astype(np.float32)  # once for all the LED frames
    black = [
        name
        for name in names
        if clipped[f"{name}.png"] < EXPOSURE_UNUSABLE_SHARE and not _lit(frames[name], dark, response, gel)
    ]
    lines = []
    if reference:
        _refuse_unusable(folder, names, black, clipped, where)
        slope = None
        if response_slope is not None:  # the LED frames in the light, as the dark frame
            slope = response_slope(np.stack([frames[name] for name in names]), frames["dark"])
        _refuse_pedestal(folder, frames["dark"], stored_dark, response, gel, where, slope)
        lines += _tone_curve_lines(folder, response, slope)  # first: every other reading is of the wrong light
    lines += [_black_line(folder, names, black)] if black else []
    over = _over_line(folder, clipped, where)
    lines += [over] if over else []
    lines += _repeated_lines(frames, names, response, folder, gel, outlined, expected)
    return lines + _compressed_lines(frames, names, folder, gel)


def _repeated_lines(
    frames: dict[str, np.ndarray],
    names: list[str],
    response: SensorResponse,
    folder: Path,
    gel: np.ndarray,
    outlined: bool = True,
    expected: ExpectedLight | None = None,
) -> list[str]:
    """The warnings naming LED frames that repeat the frame before them, whole or in some rows (the camera's frames
    lag the LED switch, or were read out across it: :mod:`nlipscalib.core.repeated_frames`), and rows dark in every
    LED frame (read while no LED was lit; only where ``outlined``, a gel mask given: the frame's rows beyond the
    dome's image are dark in every frame), while the press can still be captured again."""
    linear = np.stack(
        [linearise(frames[name], frames["dark"], response.black_level, response.white_level) for name in names]
    )
    repeated, bands, dark = frame_checks(linear, gel, expected)
    say_lag_blind(folder, expected, gel)  # LEDs in close pairs: where a lag between them goes unseen, once
    files = [f"{name}.png" for name in names]
    return (
        ([repeated_line(folder, files, repeated)] if repeated else [])
        + ([lagged_line(folder, files, bands)] if bands else [])
        + ([dark_everywhere_line(folder, dark)] if dark and outlined else [])
    )


def _compressed_lines(frames: dict[str, np.ndarray], names: list[str], folder: Path, gel: np.ndarray) -> list[str]:
    """The warning when the LED frames went through JPEG (a camera streaming MJPEG:
    :mod:`nlipscalib.core.compression`), while the press can still be captured again."""
    if not names or (value := compressed(np.stack([frames[name] for name in names]), gel)) is None:
        return []
    return [blockiness_line(folder, "the LED frames", value)]


def _gel(gel: np.ndarray | None, shape: tuple[int, int]) -> tuple[np.ndarray, str]:
    """The pixels checked, and what the messages call them: the gel's when ``gel`` marks some of a frame of
    ``shape`` (:func:`_has_gel`), else every pixel."""
    if _has_gel(gel, shape):
        return gel, "of the gel"
    return np.ones(shape, bool), "of the pixels"


def _has_gel(gel: np.ndarray | None, shape: tuple[int, int]) -> bool:
    """Whether ``gel`` marks some pixels of a frame of ``shape``."""
    return gel is not None and gel.shape == shape and bool(gel.any())


def _saturated_share(image: np.ndarray, response: SensorResponse, gel: np.ndarray) -> float:
    """Share of the ``gel`` pixels with a channel at the white level in one stored frame."""
    return float(response.saturated(image).any(axis=2)[gel].mean())


def _lit(image: np.ndarray, dark: np.ndarray, response: SensorResponse, gel: np.ndarray) -> bool:
    """Whether an LED frame shows light above the dark frame: at least :data:`EXPOSURE_LIT_SHARE` of the ``gel``
    pixels above :data:`EXPOSURE_LIGHT_FRACTION` of full scale, the channels' mean after a :data:`CAPTURE_CHECK_BLUR`
    box blur.

    Not the solver's test of a lit LED image (:data:`nlipscalib.core.tolerances.LIT_LEVEL`, its 99th percentile
    on the gel at 0.1 % of full scale), on purpose: this one runs while the session can still be fixed, on raw
    frames of a camera that may have 8 bits, where 0.1 % is a quarter of one step and a lens cap's noise would
    pass it; the blur averages that noise away and the level is 20 times higher. The solver asks of a capture that
    can no longer be retaken whether an image holds any light to fit, and keeps a dim LED that this check warns
    about (LIT_LEVEL says more)."""
    cv2 = require("cv2", "opencv-python-headless", "The exposure check")
    light = linearise(image, dark, response.black_level, response.white_level).mean(axis=2)
    blurred = cv2.blur(light, (CAPTURE_CHECK_BLUR, CAPTURE_CHECK_BLUR))
    return float((blurred[gel] > EXPOSURE_LIGHT_FRACTION).mean()) >= EXPOSURE_LIT_SHARE


def _over_line(folder: Path, clipped: dict[str, float], where: str) -> str | None:
    """The warning naming the over-exposed frames (more than :data:`EXPOSURE_SATURATED_SHARE` saturated), the
    worst first; None when there is none."""
    over = sorted((share, name) for name, share in clipped.items() if share > EXPOSURE_SATURATED_SHARE)[::-1]
    if not over:
        return None
    share, name = over[0]
    others = ", ".join(f"{other} {100 * part:.0f} %" for part, other in over[1:NAMED])
    if len(over) > NAMED:
        others += f" and {len(over) - NAMED} more frames"
    also = f" ({others} also over {100 * EXPOSURE_SATURATED_SHARE:.0f} %)" if others else ""
    hint = " (--tricolor-level for tricolor.png)" if any(other == "tricolor.png" for _, other in over) else ""
    return (
        f"{folder / name}: {100 * share:.0f} % {where} saturated{also}: saturated pixels are left out of every "
        f"fit; lower --exposure-ms or the LED level{hint}"
    )


def _black_line(folder: Path, names: list[str], black: list[str]) -> str:
    """The warning naming the LED frames without light (``black``, of ``names``): all of them, or which."""
    if len(black) == len(names):
        return (
            f"{folder}: no LED frame shows light above the dark frame ({names[0]}.png .. {names[-1]}.png against "
            "dark.png): LEDs off or not driven (the right --port?), lens cap on, or the camera not looking at the gel"
        )
    listed = ", ".join(f"{name}.png" for name in black[:NAMED]) + (
        f" and {len(black) - NAMED} more" if len(black) > NAMED else ""
    )
    return (
        f"{folder}/{listed}: no light above the dark frame (dark.png): is that LED lit and wired "
        "(`nlips leds PORT test`)?"
    )


def _refuse_unusable(folder: Path, names: list[str], black: list[str], clipped: dict, where: str) -> None:
    """CaptureError when the reference holds nothing usable: every LED frame black or saturated (the LED
    calibration and NLiPs, whose solves label NLiPsNet's training, read only the LED frames; a saturated
    tri-colour frame alone is warned about)."""
    saturated = [name for name in names if clipped[f"{name}.png"] >= EXPOSURE_UNUSABLE_SHARE]
    tail = (
        "; nothing downstream can use it, so it was not written: fix it and capture again (the session's settings "
        "are fixed only once the reference is written)"
    )
    if len(black) == len(names):
        raise CaptureError(
            f"{folder}: the reference is black: no LED frame shows light above the dark frame: LEDs off or not "
            f"driven (the right --port?), lens cap on, or the camera not looking at the gel{tail}"
        )
    if len(saturated) + len(black) == len(names):
        raise CaptureError(
            f"{folder}: the reference is saturated: every LED frame has at least "
            f"{100 * EXPOSURE_UNUSABLE_SHARE:.0f} % {where} at the white level (or no light): lower --exposure-ms or "
            f"the LED level{tail}"
        )


def _refuse_pedestal(
    folder: Path,
    dark: np.ndarray,
    stored_dark: np.ndarray,
    response: SensorResponse,
    gel: np.ndarray,
    where: str,
    slope: float | None = None,
) -> None:
    """CaptureError when the reference's dark frame sits evenly above the declared black level by more than
    :data:`~nlipscalib.core.tolerances.DARK_FRAME_OFFSET` of full scale: the camera's own black level (pedestal),
    not declared (:func:`nlipscalib.core.dark_pedestal.even_dark_offset`, the solve's judgement).

    Why: such a session was captured whole without a word, and ``nlips solve`` then refused every press, naming
    ``--black-level N`` only after the lab's session (s36 device walk). The reference fixes the session's settings,
    so it is refused before any press, as a black one is. ``dark`` is in the light (a declared tone curve undone),
    as the solve judges it; ``stored_dark`` as the camera encoded it, the values ``--black-level`` takes.

    A tone curve is told first: with the LED frames (in the light, as ``dark``) growing with the light to the power
    ``slope`` (:data:`ResponseSlope`; None: not told) below :data:`~nlipscalib.core.tolerances.LINEAR_RESPONSE_SLOPE`
    (the solve's limit), the refusal names the camera's tone curve (:func:`_tone_curve_refusal`). Why: a gamma-2.2
    webcam whose dark frame held 0.3 % of full scale of light evenly was told `--black-level 20` (of 255: the curve
    lifted it 26 times, to 7.8 %); captured so, `nlips solve` called its LED images "not linear in the light" (power
    0.53) and refused the press as another sensor's (s37 capcheck, the /tmp/keep reference and sphere1 through a
    gamma-2.2 encoding). A camera's own black level, subtracted, leaves linear frames (power 1.00): only the slope
    tells the two apart."""
    samples = dark[gel]
    median = float(np.median(samples))
    black, white = response.black_level, response.white_level
    level = (median - black) / (white - black)
    if level <= DARK_FRAME_OFFSET or not even_dark_offset(samples, median - black):
        return
    bits = response.bit_depth
    pedestal = camera_dn(float(np.median(stored_dark[gel])), bits)
    if slope is not None and slope < LINEAR_RESPONSE_SLOPE:
        lifted = (
            f"dark.png sits evenly above the black level {camera_dn(black, bits):g} (--black-level), its median "
            f"{where} {pedestal:.4g} in the camera's {bits}-bit values ({100 * level:.1f} % of full scale)"
        )
        raise CaptureError(_tone_curve_refusal(folder, response, slope, lifted))
    raise CaptureError(
        f"{folder}/dark.png: not a dark frame of the black level {camera_dn(black, bits):g} (--black-level): the "
        f"median {where}, {pedestal:.4g} in the camera's {bits}-bit values, is "
        f"{100 * level:.1f} % of full scale above it and even, as a camera's own black level (pedestal) is, and "
        f"`nlips solve` would refuse every press: capture again with it declared (`--black-level "
        f"{pedestal:.4g}`); if that level is right, light reached it (an LED lit, or room light?): "
        "capture with every LED off. The reference was not written (the session's settings are fixed only once "
        "it is)"
    )


def _tone_curve_refusal(folder: Path, response: SensorResponse, slope: float, lifted: str) -> str:
    """The reference's refusal when its LED frames grow with the light to the power ``slope`` (below
    :data:`~nlipscalib.core.tolerances.LINEAR_RESPONSE_SLOPE`) and its dark frame is ``lifted`` above the black
    level: the camera's tone curve, undeclared or declared wrongly (``response.camera_response``), named first."""
    head, cure = _tone_curve_fault(folder, response, slope)
    return (
        f"{head}; and {lifted}. {TONE_CURVE_LIFTS_DARK}: a --black-level would not make the frames linear (`nlips "
        f"solve` would call them not linear, its normals wrong by degrees). {cure}. The reference was not written (the "
        "session's settings are fixed only once it is)"
    )


def _tone_curve_lines(folder: Path, response: SensorResponse, slope: float | None) -> list[str]:
    """The warning of a written reference whose LED frames grow with the light to the power ``slope``: below
    :data:`~nlipscalib.core.tolerances.LINEAR_RESPONSE_SLOPE` the camera's tone curve (undeclared, or declared and
    another), above :data:`~nlipscalib.core.tolerances.DECLARED_CURVE_SLOPE` with a curve declared linear frames
    (undoing a curve they never had); [] otherwise or for None (not told).

    Why: a gamma-encoding camera (its dark frame at the black level) was captured whole without a word, every press
    solved later with "not linear in the light" and its normals degrees off; the session's tone curve
    (``--camera-response``) is fixed by its reference, so the session has to be captured again, in a new folder.
    A warning, not a refusal: the slope is judged against the design's model of the sensor, which a real sensor
    departs from (the solve warns alike)."""
    again = (
        "; the session's normals would be wrong by degrees: stop (Ctrl-C) and capture it again into a new folder "
        "(this one's settings are fixed by its reference)"
    )
    if slope is not None and slope < LINEAR_RESPONSE_SLOPE:
        head, cure = _tone_curve_fault(folder, response, slope)
        return [f"{head}{again}. {cure}"]
    declared = response.camera_response
    if slope is not None and declared != "linear" and slope > DECLARED_CURVE_SLOPE:
        return [
            f"{folder}: --camera-response declares the camera's {declared} tone curve, but with it undone each "
            f"pixel's value grows as the LED model's light to the power {slope:.2f} (median; a linear capture: about "
            f"1): the frames were linear already?{again}, without --camera-response (or with the camera's measured "
            "curve, `nlips calibrate-camera-response` with the camera set as it captures)"
        ]
    return []


def _tone_curve_fault(folder: Path, response: SensorResponse, slope: float) -> tuple[str, str]:
    """What the tone-curve messages say of LED frames growing with the light to the power ``slope``: the fault
    (``folder``: ...) and its cure, for an undeclared curve or a declared one (``response.camera_response``) that is
    not the camera's."""
    declared = response.camera_response
    grows = (
        f"each pixel's value grows as the LED model's light to the power {slope:.2f} (median; a linear capture: "
        "about 1)"
    )
    if declared == "linear":
        head = f"{folder}: the LED frames are not linear in the light: {grows}, as in gamma-encoded (sRGB) frames"
        cure = f"Capture raw, linear frames with the camera's gamma off ({CAMERA_SETTINGS_GUIDE}), {DECLARE_TONE_CURVE}"
    else:
        head = (
            f"{folder}: the LED frames are not linear in the light with the declared tone curve undone "
            f"(--camera-response: {declared}): {grows}: the camera's curve is another"
        )
        cure = (
            "Measure the camera's own curve once (`nlips calibrate-camera-response`, with the camera set as it "
            f"captures) and capture with `--camera-response FILE`, or capture raw, linear frames with the camera's "
            f"gamma off ({CAMERA_SETTINGS_GUIDE})"
        )
    return head, cure
