"""LED images that repeat the image captured before them: a camera whose frames lag the LED switch.

Why: a USB camera with a deep frame queue (or a driver that ignores ``CAP_PROP_BUFFERSIZE``) can hand out, after
the LEDs switch from LED k-1 to LED k, a frame exposed before the switch. The capture then holds LED k-1's light
under LED k's name, and nothing downstream said so (s27 QA walk, webcam-grade camera on the one-bounce twin at
320x240): ``nlips calibrate-leds`` fitted LED 5 at LED 4's place and called the fit "reliable" (residual 1.05x the
noise), and ``nlips solve --roi auto`` gave a contact AAE of 0.62 / 0.76 deg on the sphere / cube press instead
of 0.47 / 0.46. Two different LEDs never light the gel alike, so an LED image within noise of its predecessor is
that predecessor's light.
"""

from __future__ import annotations

import numpy as np

from .tolerances import CAPTURE_CHECK_BLUR, EXPOSURE_LIGHT_FRACTION, REPEATED_FRAME_DIFFERENCE

MIN_LIT_PIXELS = 100
"""Fewest lit gel pixels two images need for a verdict (a smaller lit patch says nothing either way)."""


def repeated_leds(linear: np.ndarray, gel: np.ndarray) -> list[tuple[int, float]]:
    """The LED images that repeat the image captured just before them, in capture order.

    Parameters
    ----------
    linear : (L, H, W, 3) float -- the LED images in capture order, linear (dark frame subtracted, full scale 1:
        :func:`nlipscalib.core.sensor_response.linearise`).
    gel : (H, W) bool -- the pixels that see the gel.

    Returns
    -------
    list of (index, difference) -- ``index`` (0-based, >= 1) of each LED image whose median relative difference
    from image ``index - 1`` over the pixels either lights (above
    :data:`~nlipscalib.core.tolerances.EXPOSURE_LIGHT_FRACTION`), both averaged over blocks of
    :data:`~nlipscalib.core.tolerances.CAPTURE_CHECK_BLUR` pixels a side (:func:`_block_means`), is below
    :data:`~nlipscalib.core.tolerances.REPEATED_FRAME_DIFFERENCE`; empty when none is.
    """
    found = []
    inside = _block_means(np.asarray(gel, np.float32)[..., None]) > 1 - 1e-6  # blocks wholly on the gel (rounding)
    previous = _block_means(linear[0])[inside] if len(linear) else None
    for index in range(1, len(linear)):
        current = _block_means(linear[index])[inside]
        brighter = np.maximum(current, previous)
        lit = brighter > EXPOSURE_LIGHT_FRACTION
        if lit.sum() * CAPTURE_CHECK_BLUR**2 >= MIN_LIT_PIXELS:
            difference = float(np.median(np.abs(current[lit] - previous[lit]) / brighter[lit]))
            if difference < REPEATED_FRAME_DIFFERENCE:
                found.append((index, difference))
        previous = current
    return found


def _block_means(image: np.ndarray) -> np.ndarray:
    """(H // b, W // b) float32: the channels' mean of one (H, W, C) image over b x b blocks
    (b = :data:`~nlipscalib.core.tolerances.CAPTURE_CHECK_BLUR`; the last H % b rows and W % b columns left out).
    Block means, not a sliding box blur: they average the noise alike (b * b pixels each) at a twenty-fifth of the
    samples, and every solve runs this check on 12 full frames (a box blur with scipy.ndimage took 0.1 s and its
    import 0.09 s of a 640x480 solve's ~2 s, s27 lead)."""
    import cv2  # imported by the solve already (core.camera)

    b = CAPTURE_CHECK_BLUR
    h, w = image.shape[0] // b, image.shape[1] // b
    # INTER_AREA at an integer factor is the b x b block mean (~1 ms at 640x480; NumPy's reduction over the
    # reshaped block axes took 1.5 ms an image)
    blocks = cv2.resize(np.asarray(image[: h * b, : w * b], np.float32), (w, h), interpolation=cv2.INTER_AREA)
    return blocks.reshape(h, w, -1).mean(axis=2, dtype=np.float32)


def repeated_line(folder: object, names: list[str], repeated: list[tuple[int, float]]) -> str:
    """One line naming the repeated LED images (``names`` in capture order) and the fix."""
    said = ", ".join(
        f"{names[i]} repeats {names[i - 1]} ({100 * difference:.1f} % apart)" for i, difference in repeated
    )
    return (
        f"{folder}: {said}: the camera handed out a frame exposed before the LED switched (frames lag the LEDs); "
        "capture again with a larger --flush (frames dropped after each LED change) or CAP_PROP_BUFFERSIZE 1"
    )
