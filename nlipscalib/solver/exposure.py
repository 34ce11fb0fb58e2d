"""What a capture's exposure leaves to fit: the saturated samples, and LED images without light.

The solver and the LED calibration drop saturated samples (at or above the white level) and LEDs that give no
light; this module says how much of a capture that was, so a user is told why a capture cannot be used (every
sample dropped) or how much of it was (:data:`nlipscalib.core.tolerances.SATURATED_SHARE_WARN`).
"""

from __future__ import annotations

import numpy as np

from ..core import tolerances
from ..core.capture import Press
from ..core.dark_pedestal import camera_dn, even_dark_offset
from ..core.repeated_frames import ExpectedLight, model_light
from ..core.sensor_response import CAMERA_SETTINGS_GUIDE, DECLARE_TONE_CURVE, TONE_CURVE_LIFTS_DARK, redo_tone_curve

REMEDY_SATURATED = "lower the exposure (`nlips capture --exposure-ms`) or the LEDs' drive, and capture again"
"""What to do about saturated LED images."""
REMEDY_BLACK = "LEDs off, lens cap on, the camera not streaming?"
"""What black LED images suggest."""


def gel_of(press: Press) -> np.ndarray:
    """(H, W) bool -- the gel's pixels: where the undeformed surface (reference.npz) is known, else every pixel."""
    if press.reference is not None:
        return np.isfinite(press.reference.depth)
    return np.ones(press.camera.shape, bool)


def expected_light_of(press: Press) -> ExpectedLight | None:
    """The image model's summed LED light on the press's undeformed gel (:func:`.repeated_frames.model_light`, the
    capture's LEDs), what the rows dark in every LED image are judged against; None without reference.npz."""
    if press.reference is None:
        return None
    return model_light(press.reference.depth, press.reference.normals, press.camera, press.leds)


def saturated_share(press: Press, gel: np.ndarray | None = None) -> float:
    """Share of the gel's samples (LED x pixel x channel) that are saturated: at or above the white level in the
    LED image or in the dark frame (what the solver leaves out, ``solver.press._Runner``); 0 without a gel."""
    gel = gel_of(press) if gel is None else gel
    if not gel.any():
        return 0.0
    # every solve asks: no gather of the gel's samples (0.16-0.24 s at 640x480), and only the images that reach
    # the white level are compared with it (~1 ms when none does; one specular glint made it ~35 ms)
    white = press.response.white_level
    clipped = [image for image in press.led_images if image.max() >= white]
    dark = press.saturated(press.dark) & gel[:, :, None] if press.dark.max() >= white else None
    if not clipped and dark is None:
        return 0.0
    count = 0 if dark is None else len(press.led_images) * np.count_nonzero(dark)  # the dark frame's, in each
    for image in clipped:  # ... and each image's own, where the dark frame is not saturated already
        sat = press.saturated(image) & gel[:, :, None]
        count += np.count_nonzero(sat if dark is None else sat & ~dark)
    return float(count / (len(press.led_images) * press.led_images.shape[-1] * gel.sum()))


def percent(share: float) -> str:
    """'53 %', '<1 %' for a share above 0 that rounds to 0, '100 %' only when it is all."""
    if 0 < share < 0.005:
        return "<1 %"
    if share < 1 and round(100 * share) == 100:
        return ">99 %"
    return f"{100 * share:.0f} %"


def led_files(press: Press) -> str:
    """'its LED images (led_01.png .. led_12.png)', or without the names when meta.json lists other LEDs."""
    names = (press.meta.get("images") or {}).get("leds")
    if isinstance(names, list) and len(names) == len(press.leds) and all(isinstance(n, str) for n in names):
        return f"its LED images ({names[0]} .. {names[-1]})" if len(names) > 1 else f"its LED image ({names[0]})"
    return "its LED images"


def dark_file(press: Press) -> str:
    """The name of the capture's dark frame, as its meta.json lists it ("dark.png" when it lists none)."""
    name = (press.meta.get("images") or {}).get("dark")
    return name if isinstance(name, str) else "dark.png"


def saturation_note(press: Press, share: float, dropped_from: str) -> str | None:
    """The warning for a capture with ``share`` (:func:`saturated_share`) of its gel's samples saturated, at
    least :data:`~nlipscalib.core.tolerances.SATURATED_SHARE_WARN`; None below it."""
    if not share >= tolerances.SATURATED_SHARE_WARN:
        return None
    return (
        f"{press.folder}: {percent(share)} of the gel's samples in {led_files(press)} are saturated (at or above "
        f"the white level {press.response.white_level:g}) and left out of {dropped_from} (warned from "
        f"{percent(tolerances.SATURATED_SHARE_WARN)}): {REMEDY_SATURATED}"
    )


def no_light_reason(press: Press, gel: np.ndarray, live: np.ndarray) -> str:
    """Why a capture leaves no sample to fit on, when its exposure tells: ": its LED images are black (...)" or
    ": N % of the gel's samples ... are saturated (...)"; "" when it is neither.

    ``gel`` (H, W) bool: the pixels fitted on; ``live`` (L,) bool: the LEDs whose images hold light above the dark
    frame (``solver.image_stats.led_levels``)."""
    if not gel.any():
        return ": the undeformed surface (reference.npz) covers no pixel of the image"
    share = saturated_share(press, gel)
    if share >= tolerances.SATURATED_SHARE_WARN:
        dark = float(press.saturated(press.dark[gel]).mean())
        also = f", and so is {percent(dark)} of the dark frame ({dark_file(press)})" if dark > 0 else ""
        return (
            f": {percent(share)} of the gel's samples in {led_files(press)} are saturated (at or above the white "
            f"level {press.response.white_level:g}){also}: {REMEDY_SATURATED}"
        )
    if not np.any(live):
        return (
            f": {led_files(press)} are black (no light above the dark frame {dark_file(press)} on the gel: "
            f"{REMEDY_BLACK})"
        )
    return ""


def nothing_to_fit(press: Press, gel: np.ndarray | None = None) -> str:
    """Why no sample of a capture can be fitted on (:func:`no_light_reason`, or a plainer word when the exposure
    does not explain it): no LED image gives light above the dark frame, or every lit one is saturated on the gel;
    "" when some sample is usable."""
    from .image_stats import led_levels, lit_leds

    gel = gel_of(press) if gel is None else gel
    if not gel.any():
        return no_light_reason(press, gel, np.zeros(len(press.leds), bool))
    live = lit_leds(led_levels(press.linear_led_images, gel))
    if _unsaturated_sample(press, gel, live):
        return ""
    return no_light_reason(press, gel, live) or ": no LED image holds an unsaturated sample lit above the dark frame"


def _unsaturated_sample(press: Press, gel: np.ndarray, live: np.ndarray) -> bool:
    """Whether a sample of the gel is below the white level in a ``live`` LED image and in the dark frame.

    Image by image, the whole image compared with the white level only when its brightest value reaches it:
    every calibration asks (:func:`nothing_to_fit`), and a gather of all the lit images' gel samples cost
    ~120 ms per 640x480 capture."""
    dark_ok = ~press.saturated(press.dark[gel])  # (N, 3)
    if not dark_ok.any():
        return False
    for index in np.flatnonzero(live):
        image = press.led_images[index]
        if image.max() < press.response.white_level or (dark_ok & ~press.saturated(image[gel])).any():
            return True
    return False


def dark_frame_fault(press: Press, gel: np.ndarray | None = None) -> tuple[str, bool] | None:
    """What is wrong with a capture's dark frame, and whether it is past using; None when it is a dark frame.

    Its median on the gel, linear (``(dark - black_level) / (white_level - black_level)``), is compared with
    :data:`~nlipscalib.core.tolerances.DARK_FRAME_OFFSET` either side of zero: above, it holds light (refused:
    every image would be measured from another image); below, the black level of meta.json is not the sensor's
    (a warning: the images are measured from the dark frame, each carrying that offset).

    Parameters
    ----------
    press : Press
    gel : (H, W) bool or None -- the pixels that see the gel (default :func:`gel_of`).

    Returns
    -------
    (message, refuse) or None -- the message names the folder and the dark frame's file.
    """
    gel = gel_of(press) if gel is None else gel
    if not gel.any():
        return None
    black, white = press.response.black_level, press.response.white_level
    median = float(np.median(press.dark[gel]))
    level = (median - black) / (white - black)
    if abs(level) <= tolerances.DARK_FRAME_OFFSET:
        return None
    name = f"{press.folder}: {dark_file(press)}"
    if level > 0 and (curve := _tone_curve_cause(press)):
        above = f"{percent(level)} of full scale above the black level {black:g}"
        return f"{name}: its median on the gel, {median:g}, is {above}{curve}", True
    if level > 0 and even_dark_offset(press.dark[gel], median - black):
        return (
            f"{name}: not a dark frame of the black level {black:g}: its median on the gel, {median:g}, is "
            f"{percent(level)} of full scale above it and even across the gel, as a camera's own black level "
            f"(pedestal) is: capture again with it declared (`nlips capture --black-level "
            f"{_black_level_hint(press, gel)}); if that level is right, light reached it (an LED lit, or room "
            "light?): capture it with every LED off",
            True,
        )
    if level > 0:
        return (
            f"{name}: not a dark frame: its median on the gel, {median:g}, is {percent(level)} of full scale above "
            f"the black level {black:g} (an LED lit, or room light?); capture it with every LED off",
            True,
        )
    return (
        f"{name}: its median on the gel, {median:g}, is {100 * -level:.1f} % of full scale below the black level "
        f"{black:g} "
        f"(meta.json sensor.black_level): that level is not this sensor's, or the dark frame is not; every image "
        f"is measured from the dark frame, so each carries that offset",
        False,
    )


def _black_level_hint(press: Press, gel: np.ndarray) -> str:
    """The ``--black-level`` a dark frame evenly above the black level asks for, as ``nlips capture`` takes it: the
    median of the ``gel`` samples in the camera's own values (:func:`~nlipscalib.core.dark_pedestal.camera_dn`), a
    declared tone curve applied again (:func:`~nlipscalib.core.sensor_response.redo_tone_curve`; the press is loaded
    with it undone): the end of the option and what its value is in.

    Why: a press declaring the sRGB curve, its dark frame 22 of 255 as the camera gave it, was told
    `--black-level 2.047`, its linear value, where the capture of those frames had said 22 (s37 capcheck)."""
    bits = press.response.bit_depth
    response = press.response
    encoded = float(np.median(redo_tone_curve(press.dark[gel], response.tone_curve())))
    values = f"in the camera's {bits}-bit values"
    if response.camera_response != "linear":
        values += f" as it encodes them, its {response.camera_response} curve not undone"
    return f"{camera_dn(encoded, bits):.4g}`, {values}"


def _tone_curve_cause(press: Press) -> str:
    """The likely cause of a dark frame above the black level when the LED images are not linear in the light
    (:func:`.led_checks.recorded_response_slope` below ``tolerances.LINEAR_RESPONSE_SLOPE``): a tone curve, "" when
    they are linear (or cannot be told).

    Why: an 8-bit sRGB webcam with ``--black-level 0`` was refused as "an LED lit, or room light?" (s27 QA walk),
    with every LED off. The sRGB curve is steepest at black (12.92 times the linear slope), so it lifts the
    sensor's dark offset and noise, 0.07 % of full scale on the twin, to 2 of 255 steps, 0.8 %."""
    from .led_checks import recorded_response_slope

    slope = recorded_response_slope(press, range(len(press.leds)))
    if slope is None or slope >= tolerances.LINEAR_RESPONSE_SLOPE:
        return ""
    return (
        f", and the LED images are not linear in the light (each pixel's value grows as the LED model's light to "
        f"the power {slope:.2f}; a linear capture: about 1): gamma-encoded (sRGB) frames? {TONE_CURVE_LIFTS_DARK}. "
        f"Capture raw, linear frames with the camera's gamma off "
        f"({CAMERA_SETTINGS_GUIDE}), {DECLARE_TONE_CURVE}"
    )
