"""The LED calibration's captures with an LED image's lagged or dark band: that band left out of that LED's fit.

Why: a capture of the undeformed dome whose LED 5 frame was read out across the LED switch (a rolling shutter: its
top rows hold LED 4's light) or with rows read while LED 5 was off was refused whole by ``nlips calibrate-leds``,
while ``nlips solve`` leaves only the band (and :data:`~nlipscalib.core.tolerances.DARK_BAND_MARGIN` lines more) out
for that LED (benchmarks/RESULTS.md, s31-darkall). The band's samples are marked unusable for that LED
(:func:`nlipscalib.core.capture.with_unusable_samples`, as saturated ones are), so the LED's fit, the indirect term's
fit and the contact check all leave them out; the rest of the LED's image is fitted.

An LED image that repeats the one before it whole (a stale frame) is left out of that LED's fit alike, the LED kept at
its starting values where no capture holds its light (:func:`without_repeated_images`).

Lagged bands are found from the images alone, before the fit (:func:`nlipscalib.core.repeated_frames.lagged_bands`);
dark bands against the fitted LEDs, after the first fit (:func:`.calibration_contact._dark_rows_of`'s reason: an LED
far from its design ends its light where the design's would not), and a band over more than half an image against the
converged LEDs (:func:`half_dark_bands`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ..core import tolerances
from ..core.capture import Press, with_unusable_samples
from ..core.errors import CaptureError
from ..core.lag_blind import say_lag_blind
from ..core.leds import Leds
from ..core.repeated_frames import (
    DarkBand,
    LaggedBand,
    dark_band_mask,
    dark_line,
    frame_checks,
    lagged_line,
    model_light,
    repeated_line,
)

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


REPEATED_FITTED_ELSEWHERE = "; left out of that LED's fit (it holds the light of the LED before it), fitted on {}"
"""What the LED calibration does about a capture's LED image that repeats the one before it (:func:`.repeated_line`'s
tail) where another capture holds that LED's own light: the other captures' names."""
REPEATED_HELD = (
    "; {leds} not fitted (no capture holds its own light): kept at its starting values (the capture's meta.json "
    "LEDs), the LED file's not_fitted; capture the undeformed dome again to calibrate it"
)
"""What the LED calibration does about an LED whose image repeats the one before it in every capture: it is held at
its start (:func:`.led_fit.held_fit`), as a solve leaves such an LED out (:data:`.led_checks.REPEATED_REASON`)."""
REPEATED_REFUSED = (
    "; the LED calibration needs each LED's own light, and at least {least} LEDs fitted to keep the others at their "
    "starting values: capture the undeformed dome again"
)
"""The tail of the refusal when too few LEDs would be fitted without the repeated ones."""


NOTHING_TO_FIT = "{folder}: no usable pixel to calibrate the LEDs on{why}"
"""The LED calibration's refusal of a capture black or saturated throughout (``why``: :func:`.exposure.nothing_to_fit`'s
words)."""


class Repeats(NamedTuple):
    """The captures' LED images that repeat the image before them (:func:`without_repeated_images`)."""

    presses: list[Press]
    """The captures, each repeated image marked unusable whole for its LED."""
    notes: list[str]
    """One warning per capture with a repeated image."""
    held: tuple[int, ...]
    """The LEDs (0-based) repeated in every capture: no light of theirs to fit, held at their start."""


def without_repeated_images(presses: Sequence[Press]) -> Repeats:
    """The captures with each LED image that repeats the one before it (:func:`.frame_checks`' first list: a camera
    that handed out a stale frame; the later of the two is the stale one, as the solve decides,
    :func:`.led_checks.led_check`) marked unusable whole for that LED, one warning per such capture, and the LEDs
    stale in every capture: those keep their starting values (:func:`.led_fit.held_fit`). CaptureError (the line and
    what to do) when fewer than ``tolerances.MIN_LEDS_PER_PIXEL`` LEDs would be fitted.

    Why: such a capture was refused whole ("the LED calibration needs each LED's own light") while ``nlips solve``
    and its ``--reference`` capture leave that LED out (s31-halfdark); fitted, the LED went to the place of the LED
    before it and was called reliable (s27 QA walk)."""
    from .exposure import nothing_to_fit

    found = [_frame_faults(p)[0] for p in presses]
    count = len(presses[0].leds)
    held = set(range(count))
    for p, repeated in zip(presses, found):
        held &= {i for i, _ in repeated} if p.reference is not None else set()
    out, notes = [], []
    for p, repeated in zip(presses, found):
        if not repeated:
            out.append(p)
            continue
        line = repeated_line(p.folder, _names(p), repeated)
        if count - len(held) < tolerances.MIN_LEDS_PER_PIXEL:
            if why := nothing_to_fit(p):  # saturated throughout: every image alike, said as such (not stale frames)
                raise CaptureError(NOTHING_TO_FIT.format(folder=p.folder, why=why))
            raise CaptureError(f"{line}{REPEATED_REFUSED.format(least=tolerances.MIN_LEDS_PER_PIXEL)}")
        mask = np.zeros((count, *p.camera.shape), bool)
        mask[[i for i, _ in repeated]] = True
        out.append(with_unusable_samples(p, mask))
        if own := {i for i, _ in repeated} - held:
            others = ", ".join(str(q.folder) for q, r in zip(presses, found) if not own & {i for i, _ in r})
            line += REPEATED_FITTED_ELSEWHERE.format(others)
        if mine := sorted(held & {i for i, _ in repeated}):
            line += REPEATED_HELD.format(leds=", ".join(f"LED {i + 1}" for i in mine))
        notes.append(line)
    return Repeats(out, notes, tuple(sorted(held)))


def without_lagged_bands(presses: Sequence[Press]) -> tuple[list[Press], list[str]]:
    """The captures with each LED image's lagged band (:func:`.frame_checks`: rows or columns read before its LED
    switched) marked unusable for that LED (:func:`.dark_band_mask`: the band, its margin, on to the frame's edge),
    and one warning line per capture with such a band; CaptureError when a band leaves too little of its LED
    (:func:`check_left`). Repeated images: :func:`without_repeated_images`; rows dark in every image are refused by
    the calibration's own check."""
    out, notes = [], []
    for p in presses:
        bands = _frame_faults(p)[1]
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

    found = tuple(tuple(dark_rows(p, leds, _own_light(p))) if p.reference is not None else () for p in presses)
    if not any(found):
        return list(presses), found
    out = []
    for p, bands in zip(presses, found):
        out.append(masked(p, list(bands), dark_line(p.folder, _names(p), list(bands))) if bands else p)
    return out, found


def dark_notes(presses: Sequence[Press], found: Sequence[Sequence[DarkBand]]) -> list[str]:
    """One warning line per capture with dark bands left out (:func:`without_dark_bands`' ``found``)."""
    return [dark_line(p.folder, _names(p), list(b), DARK_FIT_DONE) for p, b in zip(presses, found) if b]


def half_dark_bands(
    presses: Sequence[Press], leds: Leds, known: Sequence[Sequence[DarkBand]]
) -> tuple[tuple[DarkBand, ...], ...]:
    """Per capture, its LED images' dark bands over more than half an image against the calibrated ``leds``
    (:func:`.led_checks.dark_rows` with ``mostly_dark``) that the median's look does not find, of the LEDs without a
    band ``known`` (per capture, those left out already; may be empty); all empty: none.

    Why: over half dark, a band puts the LED's median light at the dark frame's noise and goes unseen by the look
    against the first fit (:func:`without_dark_bands`); a fit that converges anyway (the robust loss leaves the dark
    rows) took it without a word (s31-halfdark: a noise-free capture's LED 5 dark in rows 0-64 of 120). Asked of the
    converged LEDs, not the first fit's: against those an LED far from its design ends its own light at its
    terminator over as much (s31-ledfar's twin: LEDs 4 and 5 "dark" over 56 % of their images)."""
    from .led_checks import dark_rows

    out = []
    for p, bands in zip(presses, list(known) or [()] * len(presses)):
        if p.reference is None:
            out.append(())
            continue
        live = [i for i in _own_light(p) if i not in {band.index for band in bands}]
        plain = {band.index for band in dark_rows(p, leds, live)}
        half = [band for band in dark_rows(p, leds, live, mostly_dark=True) if band.index not in plain]
        out.append(tuple(band for band in half if at_dark_level(p, band)))
    return tuple(out)


def at_dark_level(press: Press, band: DarkBand) -> bool:
    """Whether ``band``'s gel pixels hold the dark frame's level in its LED's image: their median light (linear, the
    channels' mean) at most :data:`~nlipscalib.core.tolerances.HALF_DARK_NOISE` times the image's noise
    (:func:`.image_stats.image_noise`, at least one ADC step: a noise-free capture)."""
    from .calibration_quality import adc_step
    from .image_stats import image_noise

    gel = np.isfinite(press.reference.depth)
    inside = np.zeros_like(gel)
    start, stop = band.rows
    if band.axis == "rows":
        inside[start:stop] = True
    else:
        inside[:, start:stop] = True
    image = press.linear_led_images[band.index]
    noise = max(image_noise(image[None], gel), adc_step(press))
    return bool(np.median(image[inside & gel].mean(-1)) <= tolerances.HALF_DARK_NOISE * noise)


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

    bands = dark_rows(press, leds, _own_light(press), mostly_dark=True) if press.reference is not None else []
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


def _frame_faults(press: Press) -> tuple[list[tuple[int, float]], list[LaggedBand]]:
    """The capture's LED images that repeat the one before them, whole and partly (:func:`.frame_checks`' first two
    lists; none without a surface). The bands judged with each LED's modelled light (the design's LEDs): LEDs
    designed in close pairs light the gel alike far from the pair, which is no lag (s35-pairband); the pairs a lag
    between which it cannot see said once per command (:func:`.say_lag_blind`)."""
    if press.reference is None:
        return [], []
    expected = model_light(press.reference.depth, press.reference.normals, press.camera, press.leds)
    gel = np.isfinite(press.reference.depth)
    found = frame_checks(press.linear_led_images, gel, expected)[:2]
    say_lag_blind(press.folder, expected, gel)
    return found


def _own_light(press: Press) -> list[int]:
    """The LEDs (0-based) whose image holds some of their own light: all but those marked unusable throughout (a
    repeated image, :func:`without_repeated_images`: its light is another LED's, no band of it to look for)."""
    whole = press.saturated_led_images.all(axis=(1, 2, 3))
    return [i for i in range(len(press.leds)) if not whole[i]]


def _names(press: Press) -> list[str]:
    """The LED images' names (:func:`.led_checks.image_names`)."""
    from .led_checks import image_names

    return image_names(press)
