"""The LED calibration's captures with an LED image's lagged or dark band: that band left out of that LED's fit.

Why: a capture of the undeformed dome whose LED 5 frame was read out across the LED switch (a rolling shutter: its
top rows hold LED 4's light) or with rows read while LED 5 was off was refused whole by ``nlips calibrate-leds``,
while ``nlips solve`` leaves only the band (and :data:`~nlipscalib.core.tolerances.DARK_BAND_MARGIN` lines more) out
for that LED (benchmarks/RESULTS.md, s31-darkall). The band's samples are marked unusable for that LED
(:func:`nlipscalib.core.capture.with_unusable_samples`, as saturated ones are), so the LED's fit, the indirect term's
fit and the contact check all leave them out; the rest of the LED's image is fitted.

Lagged bands are found from the images alone, before the fit (:func:`nlipscalib.core.repeated_frames.lagged_bands`);
dark bands against the fitted LEDs, after the first fit (:func:`.calibration_contact._dark_rows_of`'s reason: an LED
far from its design ends its light where the design's would not).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core import tolerances
from ..core.capture import Press, with_unusable_samples
from ..core.errors import CaptureError
from ..core.leds import Leds
from ..core.repeated_frames import DarkBand, LaggedBand, dark_band_mask, dark_line, frame_checks, lagged_line

LAGGED_FIT_DONE = (
    f"; left out of that LED's fit (and of the indirect term's) with {tolerances.DARK_BAND_MARGIN} rows (columns) "
    "more and to the frame's edge (they hold the light of the LED before it), the rest of its image fitted"
)
"""What the LED calibration does about an LED image's rows (columns) read before its LED switched
(:func:`.lagged_line`'s tail), as the solve does (:data:`.led_checks.LAGGED_DONE`)."""
DARK_FIT_DONE = (
    f"; left out of that LED's fit (and of the indirect term's) with {tolerances.DARK_BAND_MARGIN} rows (columns) "
    "either side (read while it was off, they hold none of its light), the rest of its image fitted"
)
"""What the LED calibration does about an LED image's dark rows (columns) (:func:`.dark_line`'s ``done``)."""


def without_lagged_bands(presses: Sequence[Press]) -> tuple[list[Press], list[str]]:
    """The captures with each LED image's lagged band (:func:`.frame_checks`: rows or columns read before its LED
    switched) marked unusable for that LED (:func:`.dark_band_mask`: the band, its margin, on to the frame's edge),
    and one warning line per capture with such a band; CaptureError when a band leaves too little of its LED
    (:func:`check_left`). Repeated images and rows dark in every image are refused by the calibration's own check."""
    out, notes = [], []
    for p in presses:
        bands = _lagged(p)
        if bands:
            names = _names(p)
            line = lagged_line(p.folder, names, bands)
            p = masked(p, bands, line)
            notes.append(f"{line}{LAGGED_FIT_DONE}")
        out.append(p)
    return out, notes


def without_dark_bands(presses: Sequence[Press], leds: Leds) -> tuple[list[Press], tuple[tuple[DarkBand, ...], ...]]:
    """The captures with each LED image's dark band against the fitted ``leds`` (:func:`.led_checks.dark_rows`)
    marked unusable for that LED, and the bands found per capture (all empty: the captures as given). CaptureError
    when a band leaves too little of its LED (:func:`check_left`)."""
    from .led_checks import dark_rows

    found = tuple(tuple(dark_rows(p, leds, range(len(leds)))) if p.reference is not None else () for p in presses)
    if not any(found):
        return list(presses), found
    out = []
    for p, bands in zip(presses, found):
        out.append(masked(p, list(bands), dark_line(p.folder, _names(p), list(bands))) if bands else p)
    return out, found


def dark_notes(presses: Sequence[Press], found: Sequence[Sequence[DarkBand]]) -> list[str]:
    """One warning line per capture with dark bands left out (:func:`without_dark_bands`' ``found``)."""
    return [dark_line(p.folder, _names(p), list(b), DARK_FIT_DONE) for p, b in zip(presses, found) if b]


HALF_DARK_DONE = (
    "; the LED calibration cannot fit that LED on the rest of its image (its fit ran off): capture the undeformed "
    "dome again"
)
"""What the LED calibration does about a dark band over more than half an LED's image (:func:`half_dark_line`)."""


def half_dark_line(press: Press, leds: Leds) -> str | None:
    """The refusal naming ``press``'s LED images' dark bands, over more than half an image or less, against the
    starting ``leds`` (:func:`.led_checks.dark_rows` with ``mostly_dark``); None when it has none. Asked only after an
    LED's fit ran off (:class:`.led_fit.LedFitRanOff`): over half dark, a band put the LED's median light at the dark
    frame's noise and went unseen against the first fit (s31-halfdark), while an LED far from the model ends its own
    light as far, so the look is not made on a fit that converged."""
    from .led_checks import dark_rows

    bands = dark_rows(press, leds, range(len(press.leds)), mostly_dark=True) if press.reference is not None else []
    return dark_line(press.folder, _names(press), bands, HALF_DARK_DONE) if bands else None


def masked(press: Press, bands: Sequence[DarkBand | LaggedBand], line: str) -> Press:
    """``press`` with ``bands`` marked unusable for their LEDs, after :func:`check_left` (``line``: the warning that
    names them, the refusal's start)."""
    mask = dark_band_mask(list(bands), list(range(len(press.leds))), press.camera.shape)
    check_left(press, mask, line)
    return with_unusable_samples(press, mask)


def check_left(press: Press, mask: np.ndarray, line: str) -> None:
    """CaptureError (``line`` and why) when a band leaves an LED fewer than
    :data:`~nlipscalib.core.tolerances.CALIBRATION_MIN_LED_KEPT` of the gel's pixels: too little of its light to fit
    it on (``mask``: (L, H, W) bool, :func:`.dark_band_mask`'s)."""
    gel = np.isfinite(press.reference.depth) if press.reference is not None else np.ones(mask.shape[1:], bool)
    total = max(int(gel.sum()), 1)
    kept = 1 - (mask & gel).reshape(len(mask), -1).sum(axis=1) / total
    short = np.flatnonzero(kept < tolerances.CALIBRATION_MIN_LED_KEPT)
    if short.size:
        k = int(short[0])
        raise CaptureError(
            f"{line}; that leaves LED {k + 1} {100 * kept[k]:.0f} % of the gel, under the "
            f"{100 * tolerances.CALIBRATION_MIN_LED_KEPT:.0f} % the LED calibration needs to fit it: capture the "
            "undeformed dome again"
        )


def _lagged(press: Press) -> list[LaggedBand]:
    """The capture's partly lagged LED images (:func:`.frame_checks`' second list; none without a surface)."""
    if press.reference is None:
        return []
    return frame_checks(press.linear_led_images, np.isfinite(press.reference.depth))[1]


def _names(press: Press) -> list[str]:
    """The LED images' names (:func:`.led_checks.image_names`)."""
    from .led_checks import image_names

    return image_names(press)
