"""Does each LED image show its own LED's light? Warnings for a weak LED and for LED images in the wrong order.

Why: a capture whose LED images do not match the LED model was solved without a word about why (s26 QA walk on the
one-bounce twin's cube press): two LED images swapped (a wiring error) gave a contact AAE of 5-6 deg and a depth 6.6
mm off, with only "the solve drifted 6.2 mm from the undeformed surface"; an LED at 30 % of its power gave 0.64 deg
on the whole gel (0.42 clean) and "--roi auto found no contact". Both are plain in the images: each LED image is
compared with every LED's modelled shading of the undeformed dome, after a per-pixel albedo fitted over the LEDs.
LEDs designed 0.8 mm apart light the gel alike (0.99): their exchange is told by how their two images differ
(:func:`_close_pair_exchanges`; it cost the twin's pairs08 sphere 0.66 -> 0.83 deg on the contact, unsaid); the
tri-colour frame is checked against the LED images summed by colour group (:mod:`nlipscalib.core.tricolor_check`:
an exchange across groups, or a frame of another press; s37-swapcheck).
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ..core import tolerances
from ..core.camera import depth_to_points
from ..core.capture import Press
from ..core.compression import blockiness_line, compressed
from ..core.errors import CaptureError
from ..core.lag_blind import say_lag_blind
from ..core.leds import TRICOLOR_NAMES, Led, led_shading, tricolor_groups
from ..core.repeated_frames import (
    DarkBand,
    LaggedBand,
    dark_band_mask,
    dark_bands_and_candidates,
    dark_everywhere_line,
    dark_line,
    dark_lines,
    frame_checks,
    lagged_line,
    lit_level,
    repeated_line,
)
from ..core.sensor_response import CAMERA_SETTINGS_GUIDE, DECLARE_TONE_CURVE
from ..core.tricolor_check import tricolor_note
from . import reuse
from .indirect import fit_indirect

WEAK_LED_GAIN = 0.6
"""An LED whose image holds less than this fraction of the light the model gives it, relative to the median LED's
fraction, is warned about as weak (or as brighter than modelled above 1 / this). The twin's LEDs: 1.05-1.10 of the
model, within 5 % of their median; its 30 % LED: 0.29 of the median."""
MATCH_CORRELATION = 0.5
"""An LED image whose correlation over the gel with its own LED's modelled light is below this, and which
correlates better with another LED's, is warned about as in the wrong place. The twin's images: 0.98-0.99 with their
own LED; two swapped LED images: -0.55 and -0.51 with their own, 0.98 with each other's."""
REORDER_CORRELATION = 0.9
"""LED images out of order are solved in the order they show (:func:`detected_order`) only when each misplaced image
correlates with the LED it shows by at least this much: the twin's two swapped images 0.98 with each other's LED
(their own 0.98-0.99). Below it, or when the images do not map one-to-one onto the LEDs they leave (a clean pair
or cycle), the order is kept and only warned about."""
CHECK_PIXELS = 2000
"""Gel pixels the check samples, at least (every k-th in raster order): its statistics are medians and
correlations over the gel, steady at this count (the verdicts above are the same at 10^4 pixels)."""
OUTSIDE_PIXELS = CHECK_PIXELS
""":func:`exposure_ratio` samples the gel outside the solve's box when at least this many gel pixels lie there (else
the whole gel), :data:`CHECK_PIXELS` of them as on the whole gel: the one-bounce twin's 16-spp noise is ~5 % a pixel,
and the 289 whole-gel samples outside the flat pad's 15 deg cube press's box read one LED's blue at 0.987, a
correction; its ~35000 gel pixels there sampled 2000 strong read 0.995-1.005."""


def led_mismatch_notes(press: Press, leds: Sequence[Led], live: Sequence[int]) -> list[str]:
    """The warnings of :func:`led_check` (one line each, naming the press and the LED images)."""
    return led_check(press, leds, live)[0]


def led_check(
    press: Press, leds: Sequence[Led], live: Sequence[int]
) -> tuple[list[str], list[int], list[int], list[int] | None]:
    """Warnings (one line each, naming the press and the LED images) when LED images do not show their LEDs, repeat
    the image before them (frames that lag the LED switch, :mod:`nlipscalib.core.repeated_frames`), hold rows read
    while no LED was lit (one image's, against the LED model: :func:`_dark_rows`; every image's), went through
    JPEG (:func:`compression_notes`), and the LEDs whose
    light is off the model's (weak, or brighter than the others) or repeated: a solve leaves those out.

    Why leave them out: with a 30 % LED 7 in the twin's cube press, its misfit everywhere raised the contact
    finder's floor (the misfit's median) above the dent's misfit ("--roi auto found no contact"), and the whole gel
    solved with it gave 0.64 deg (clean 0.42). Left out (as a dead LED is): 0.434 deg with ``--roi auto``; its
    intensity rescaled by the measured 0.29 instead: 0.441 (benchmarks/RESULTS.md, s26-degen2).

    Parameters
    ----------
    press : Press -- with ``reference`` (none: no check, []).
    leds : sequence of Led -- the LED model of the solve, in the order of ``press.led_images``.
    live : sequence of int -- LEDs whose images hold light (0-based); dead ones are said elsewhere.

    Returns
    -------
    notes : list of str -- empty when every live LED image matches its LED.
    left_out : list of int -- LEDs (0-based) to leave out: their light is off the model's by more than
        :data:`WEAK_LED_GAIN`, or their image repeats the one before (whole); empty when leaving them out would
        leave fewer than ``tolerances.MIN_LEDS_PER_PIXEL`` LEDs (then only warned about). An image with a band of
        rows (columns) at the dark frame's level, or holding the previous image's light (read across the switch), is
        not left out: only those rows (:func:`led_check_measured`).
    misplaced : list of int -- LEDs (0-based) whose images show another LED's light (swapped, or out of order).
    order : list of int, or None -- for each LED (0-based), the image (0-based, the capture's order) that shows its
        light, when the misplaced images are a clean pair or cycle (:func:`detected_order`); None otherwise.
    """
    return led_check_measured(press, leds, live)[:4]


@dataclasses.dataclass(frozen=True)
class MeasuredGains:
    """Each LED's light against the LED model over the median LED's (:func:`model_relative_gains`) as
    :func:`led_check_measured` measured it on its samples, for :func:`model_gain_check` of the same LEDs.

    Why: a solve without an undeformed capture judged the LEDs' ageing on samples of the gel and LED shading that
    the weak-LED check had just computed alike (~2-10 ms a solve, benchmarks/RESULTS.md, s29-qaleft)."""

    live: tuple[int, ...]
    """The LEDs (0-based) measured, in order."""
    relative: np.ndarray
    """(len(live),) float64 -- their light over the median LED's."""


class ExchangedImages(NamedTuple):
    """LED images captured in each other's place: neighbours', whose light is alike (:func:`led_check_measured`
    against the LED model, :func:`reference_exchanges` against the undeformed capture)."""

    leds: tuple[int, ...]
    """The exchange's LEDs (0-based), in the assignment's order: the image of ``leds[k]`` shows the light of
    ``leds[k + 1]`` (the last's, the first's)."""
    line: str
    """What was found, naming the capture and the files, without what is done about it (the solve's)."""
    against: str = "model"
    """What told it: "model" (the LED model's light) or "reference" (the undeformed capture's images); "leds": the
    LED model given (``--leds FILE``), its LEDs where the design places each other (:func:`given_leds_exchange`)."""
    head: str = ""
    """The line up to its cause: the capture, the files and the correlations ("" when the line is one piece)."""


class LedFindings(NamedTuple):
    """What :func:`led_check_measured` found of a capture's LED images (a tuple: unpacks in this order)."""

    notes: list[str]
    """The warnings, each naming the capture and the files."""
    left_out: list[int]
    """The LEDs (0-based) to leave out of the solve."""
    misplaced: list[int]
    """The LEDs whose images show another LED's light."""
    order: list[int] | None
    """The LED order the images show (None: theirs, or not clear)."""
    measured: MeasuredGains | None
    """The LEDs' light against the LED model as measured (None when none was sampled)."""
    bands: list[DarkBand | LaggedBand]
    """The LED images' dark, then lagged bands, whose samples a solve leaves out for that LED."""
    exchanged: list[ExchangedImages]
    """The images exchanged with a neighbour's."""


NOTHING_FOUND = LedFindings([], [], [], None, None, [], [])
"""No verdict: no undeformed dome to model, or too few LEDs to judge."""


def led_check_measured(press: Press, leds: Sequence[Led], live: Sequence[int]) -> LedFindings:
    """:func:`led_check`, the relative gains it measured on the LEDs it judged (:class:`MeasuredGains`; None
    when it sampled none), the LED images' bands whose samples a solve leaves out for that LED
    (:func:`.dark_band_mask`; the LED itself is kept): dark bands (:func:`_dark_rows`: rows or columns read while
    the LED was off), then lagged bands (:func:`.lagged_bands`: read before the LED switched, the previous LED's
    light), and the images exchanged with a neighbour's (:func:`_model_exchanges`: their light too alike for the
    misplaced images' check; not among those)."""
    live = [int(i) for i in live]
    if press.reference is None or len(live) < 3:
        return NOTHING_FOUND
    names = image_names(press)
    count = len(live)
    said, repeated, lagged, everywhere = _repeated_line(press, names)
    jpeg_notes = compression_notes(press) + (
        [f"{dark_everywhere_line(press.folder, everywhere)}; {DARK_ALL.format(everywhere.axis)}"] if everywhere else []
    )
    lagged_notes = [f"{lagged_line(press.folder, names, lagged)}{LAGGED_DONE}"] if lagged else []
    # another LED's light, whole or in a band: no verdict on its own LED
    live = [i for i in live if i not in repeated and i not in {band.index for band in lagged}]
    image, model, pixels = _sampled(press, leds, live) if len(live) >= 3 else (None, None, None)
    if image is None:
        left_out = _leave_out(repeated, count)
        notes = _said_repeated(said, left_out) + lagged_notes + jpeg_notes
        return LedFindings(notes, left_out, [], None, None, list(lagged), [])
    # linearity: said by the solve once its indirect term is fitted (linearity_notes)
    notes = jpeg_notes + shifted_notes(press, leds, live)
    dark = _dark_rows(press, leds, image, model, pixels, live, everywhere)
    dark += _half_dark_rows(press, leds, image, model, pixels, live, everywhere, dark)
    judged = [k for k, i in enumerate(live) if i not in {band.index for band in dark}]
    off = []
    relative = _relative_gains(image, model, judged)
    with np.errstate(invalid="ignore", divide="ignore"):  # a flat image (saturated throughout): NaN, no verdict
        corr = np.corrcoef(image.mean(-1), model.mean(-1))[: len(live), len(live) :]
    swapped, misplaced, shows = set(), [], {}
    for k in judged:  # an image with dark rows: its light is off the model there, no verdict on its LED
        i = live[k]
        best = int(np.argmax(corr[k]))
        if corr[k, k] < MATCH_CORRELATION and best != k:
            j = live[best]
            misplaced.append(i)
            shows[i] = (j, float(corr[k, best]))
            if int(np.argmax(corr[best])) == k and (j, i) not in swapped:
                swapped.add((i, j))
                notes.append(
                    f"{press.folder}: the images of LED {i + 1} ({names[i]}) and LED {j + 1} ({names[j]}) look "
                    f"swapped: each shows the other LED's light (correlation {corr[k, k]:.2f} with its own LED's "
                    f"model, {corr[k, best]:.2f} with the other's): check the wiring, or the order of images.leds "
                    f"in meta.json"
                )
            elif (j, i) not in swapped:
                notes.append(
                    f"{press.folder}: the image of LED {i + 1} ({names[i]}) does not show that LED's light "
                    f"(correlation {corr[k, k]:.2f} with its model, {corr[k, best]:.2f} with LED {j + 1}'s): check "
                    f"the wiring, the order of images.leds in meta.json, or the LED positions"
                )
        elif relative[k] < WEAK_LED_GAIN or relative[k] > 1 / WEAK_LED_GAIN:
            off.append((i, relative[k]))
    left_out = _leave_out([i for i, _ in off] + repeated, count)
    dark = [band for band in dark if band.index not in left_out]
    dark_notes = (
        [dark_line(press.folder, names, dark, DARK_DONE + _unjudged(press, names, dark, pixels))] if dark else []
    )
    notes = _said_repeated(said, left_out) + lagged_notes + dark_notes + notes
    for i, share in off:
        what = "weak LED?" if share < 1 else "brighter than the others"
        done = "left out of the solve and of --roi auto" if left_out else "used (too few LEDs to leave it out)"
        notes.append(
            f"{press.folder}: LED {i + 1} ({names[i]}) gives {share:.2f} times the light the LED model expects of "
            f"it, relative to the other LEDs ({what}), {done}: calibrate the LEDs on the undeformed dome (nlips "
            f"calibrate-leds) and solve with --leds FILE to use it"
        )
    measured = MeasuredGains(tuple(live), relative)
    off_band, banded = _correlations_off_bands(press, image, model, pixels, live, dark, corr)
    judged_here = sorted([live[k] for k in judged] + banded, key=live.index)
    exchanged = _model_exchanges(press, names, off_band, judged_here, live, misplaced, banded)
    held = {*misplaced, *(i for found in exchanged for i in found.leds)}
    exchanged += _close_pair_exchanges(press, names, image, model, live, [i for i in judged_here if i not in held])
    said = {*held, *(i for found in exchanged for i in found.leds)}
    if (crossed := tricolor_note(press, pixels, names, said)) is not None:
        notes.append(crossed)
    order = detected_order(shows, len(press.leds))
    return LedFindings(notes, left_out, misplaced, order, measured, [*dark, *lagged], exchanged)


def _correlations_off_bands(
    press: Press,
    image: np.ndarray,
    model: np.ndarray,
    pixels: np.ndarray,
    live: list[int],
    dark: list[DarkBand],
    corr: np.ndarray,
) -> tuple[np.ndarray, list[int]]:
    """``corr`` ((len(live), len(live)): each live image's correlation with each live LED's modelled light, over the
    samples ``pixels`` of ``image`` and ``model``) with the rows of the images holding a dark band (``dark``)
    measured anew on their samples outside it (:func:`_off_band`), and those images' LEDs (0-based) that keep
    :data:`~nlipscalib.core.tolerances.EXCHANGE_OFF_BAND_SHARE` of their samples there: judged for an exchange.

    Why: an image with a dark band had no verdict (its light is off the model in the band), so an exchange of its
    LED with a neighbour's was solved without a word where the press was solved without --reference (the synthetic
    sphere with led_03.png and led_04.png exchanged and led_03.png's top 20 of 72 rows dark; s35-leftovers)."""
    corr, banded = corr.copy(), []
    for band in dark:
        keep = _off_band(press, band, pixels)
        if keep.mean() < tolerances.EXCHANGE_OFF_BAND_SHARE:
            continue
        k = live.index(band.index)
        with np.errstate(invalid="ignore", divide="ignore"):  # a flat image: NaN, no verdict (as in corr)
            corr[k] = np.corrcoef(image[k, keep].mean(-1), model[:, keep].mean(-1))[0, 1:]
        banded.append(band.index)
    return corr, banded


def _off_band(press: Press, band: DarkBand, pixels: np.ndarray) -> np.ndarray:
    """(len(pixels),) bool: the samples (flat pixel indices) outside ``band`` and its margin (:func:`.dark_band_mask`,
    the samples a solve leaves out for that LED)."""
    shape = press.camera.shape
    return ~dark_band_mask([band], [band.index], shape)[0].reshape(-1)[pixels]


def _unjudged(press: Press, names: list[str], dark: list[DarkBand], pixels: np.ndarray) -> str:
    """What the dark-band warning adds of the images whose samples outside their band are too few to judge an
    exchange on (:func:`_correlations_off_bands`): "" when there are none."""
    few = [names[b.index] for b in dark if _off_band(press, b, pixels).mean() < tolerances.EXCHANGE_OFF_BAND_SHARE]
    if not few:
        return ""
    files = few[0] if len(few) == 1 else ", ".join(few[:-1]) + f" and {few[-1]}"
    return (
        f"; too little of {files} lies outside {'its band' if len(few) == 1 else 'their bands'} to tell an exchange "
        "with a neighbour's image there (solving with --reference, the undeformed dome's capture, tells it)"
    )


def _model_exchanges(
    press: Press,
    names: list[str],
    corr: np.ndarray,
    judged: list[int],
    live: list[int],
    misplaced: list[int],
    banded: list[int] = (),
) -> list[ExchangedImages]:
    """The LED images of the LEDs ``judged`` (0-based) exchanged with each other's
    (:func:`nlipscalib.core.led_exchange.exchanged_in_shading` of ``corr``, (len(live), len(live)): each live
    image's correlation with each live LED's modelled light), but for exchanges of ``misplaced`` LEDs only (far
    apart: reordered or warned about as such). A cycle of three neighbours holds one image two LEDs from its own,
    misplaced, and the misplaced images' check gives no order for it (not a closed cycle of misplaced images): only
    its warning said it (the twin's sphere and cube presses, led_03-05 in a cycle); now it is refused as a cycle.

    Why: neighbours light the dome alike (their images correlate 0.8 with each other's LED's light, above the 0.5 of
    :data:`MATCH_CORRELATION`), so a press with led_03.png and led_04.png exchanged was solved without a word; the
    twin's 320x240 sphere, --roi auto: its box widened to the whole gel, 1.09 deg there where the clean press's whole
    gel solves to 0.80 (benchmarks/RESULTS.md, s34-solveswap)."""
    from ..core.led_exchange import exchanged_in_shading

    at = [live.index(i) for i in judged]
    among = corr[np.ix_(at, at)]
    found = []
    for cycle in exchanged_in_shading(among):
        leds = [judged[k] for k in cycle]
        if set(leds) <= set(misplaced):  # far apart, each warned about (and reordered, where clean) as such
            continue
        said = []
        for n, k in enumerate(cycle):
            m = cycle[(n + 1) % len(cycle)]
            own, other = judged[k] + 1, judged[m] + 1
            off = " (outside its dark band)" if judged[k] in banded else ""
            said.append(
                f"{names[judged[k]]} {among[k, k]:.2f} with LED {own}'s, {among[k, m]:.2f} with LED {other}'s{off}"
            )
        whose = "the other's" if len(leds) == 2 else "the next one's"
        head = (
            f"{press.folder}: {_listed(names, leds)} look exchanged (each correlates with {whose} modelled "
            f"light of the undeformed dome better than with its own LED's: {'; '.join(said)})"
        )
        cause = (
            ": their images were captured in each other's place (the LED wiring, the controller's LED order or the "
            "images' order)"
        )
        found.append(ExchangedImages(tuple(leds), head + cause, head=head))
    return found


def _close_pair_exchanges(
    press: Press, names: list[str], image: np.ndarray, model: np.ndarray, live: list[int], judged: list[int]
) -> list[ExchangedImages]:
    """The images of LEDs designed so close together that their modelled lights correlate by
    :data:`~nlipscalib.core.tolerances.CLOSE_PAIR_LIGHT_CORRELATION` or more, exchanged with each other: their
    normalised difference ((a - b) / (a + b) per sample, the albedo cancelled) correlates with the LED model's at or
    below :data:`~nlipscalib.core.tolerances.CLOSE_PAIR_EXCHANGE_CORRELATION`. ``image``, ``model``: (len(live), N, 3)
    samples of the live LEDs' images and modelled light (:func:`_sampled`); ``judged``: the LEDs (0-based) to judge.

    Why: LEDs 0.8 mm apart light the gel alike (their lights correlate 0.99), so an exchange of their images left
    each image fitting its own LED as well as the other's (:func:`_model_exchanges` tells only the farther): the
    twin's `pairs08` presses with led_01.png and led_02.png exchanged were solved with ``--reference --roi auto``
    without a word on it (a false "the image is shifted by (+0.7, +2.0) px ... the camera moved?"), 0.66 -> 0.83 deg
    on the sphere's contact, 0.44 -> 0.66 on the cube's. Their difference tells: +0.89 to +0.95 with the model's on
    clean captures, -0.93 to -0.95 exchanged (benchmarks/RESULTS.md, s37-swapcheck)."""
    seen, light = image.mean(-1), model.mean(-1)  # (len(live), N)
    at = {i: live.index(i) for i in judged}
    found = []
    with np.errstate(invalid="ignore", divide="ignore"):  # a flat image: NaN, no verdict
        alike = np.corrcoef(light)
        for i, j in itertools.combinations(judged, 2):
            a, b = at[i], at[j]
            if not alike[a, b] >= tolerances.CLOSE_PAIR_LIGHT_CORRELATION:
                continue
            total = seen[a] + seen[b]
            usable = total > 0
            if usable.sum() < 10:
                continue
            ratio = (seen[a] - seen[b])[usable] / total[usable]
            expected = ((light[a] - light[b]) / (light[a] + light[b]))[usable]
            agree = float(np.corrcoef(ratio, expected)[0, 1])
            if not agree <= tolerances.CLOSE_PAIR_EXCHANGE_CORRELATION:
                continue
            head = (
                f"{press.folder}: {names[i]} and {names[j]} look exchanged (LEDs {i + 1} and {j + 1}, whose modelled "
                f"lights of the undeformed dome correlate {alike[a, b]:.3f}: how the two images differ correlates "
                f"{agree:+.2f} with how the LED model's lights differ, where each image in its place gives +0.9)"
            )
            cause = (
                ": their images were captured in each other's place (the LED wiring, the controller's LED order or "
                "the images' order)"
            )
            found.append(ExchangedImages((i, j), head + cause, head=head))
    return found


def given_leds_exchange(
    found: ExchangedImages, design: Sequence[Led], given: Sequence[Led], name: str
) -> ExchangedImages:
    """``found`` (images exchanged against the LED model given, ``--leds FILE``) said to be the LED model's when
    ``given`` holds those LEDs each at the place ``design`` (the press's meta.json) gives the next
    (:func:`nlipscalib.core.led_exchange.exchanged_leds`): the press's images then show the design's order, and the
    file is the likelier exchanged (calibrated on images captured in each other's place and kept so, ``nlips
    calibrate-leds --keep-led-order``); ``found`` itself otherwise.

    Why: the line said the press's images were captured in each other's place and that solving them as captured was
    right "only when the LED model misplaces those LEDs", while the model given was the one misplacing them, and the
    file it came from was not named (s34-solveswap, the twin's sphere with such a file)."""
    from ..core.led_exchange import exchanged_leds

    if found.against != "model" or not found.head:
        return found
    places = [np.array([led.position for led in leds], np.float64) for leds in (design, given)]
    if sorted(found.leds) not in [sorted(cycle) for cycle in exchanged_leds(*places)]:
        return found
    where = []
    for n, i in enumerate(found.leds):
        j = found.leds[(n + 1) % len(found.leds)]
        own, other = (float(np.linalg.norm(places[1][i] - places[0][k])) for k in (i, j))
        where.append(f"LED {i + 1} {other:.2f} mm from LED {j + 1}'s place, {own:.2f} mm from its own")
    line = (
        f"{found.head} against the LEDs of {name}, which holds them at each other's places in the press's design "
        f"(meta.json; {'; '.join(where)}) while the press's images show the design's order: {name} is the likelier "
        "exchanged (calibrated on images captured in each other's place and kept so)"
    )
    return ExchangedImages(found.leds, line, "leds", found.head)


def _listed(names: list[str], leds: Sequence[int]) -> str:
    """The files of the LEDs ``leds`` (0-based) for a line: "a and b", or "a, b and c (a cycle)"."""
    files = [names[i] for i in leds]
    return " and ".join(files) if len(files) == 2 else ", ".join(files[:-1]) + f" and {files[-1]} (a cycle)"


def reference_exchanges(
    press: Press,
    reference: Press,
    samples: tuple[np.ndarray, np.ndarray] | None,
    said: Sequence[int] = (),
    fitting: Sequence[int] = (),
) -> list[ExchangedImages]:
    """The press's LED images that hold the light of other LEDs' images of the undeformed capture it is solved with
    (:func:`nlipscalib.core.led_exchange.exchanged_images` on ``samples``, :func:`drift_samples` of the two: the
    ones :func:`exposure_ratio` is then given), but for exchanges holding an LED of ``said`` (0-based: the press's
    own images already named as showing other LEDs' light); [] when none, or when the two cannot be compared
    (``samples`` None). ``fitting``: the LEDs (0-based) whose press images the LED model's check found showing their
    own light: an exchange of only those is said to be likelier the undeformed capture's.

    Why: the press and its undeformed capture in different LED orders (either one's images exchanged) solve against
    light that is not their LEDs': the twin's 320x240 sphere with led_03.png and led_04.png exchanged against a clean
    capture, --roi auto, said only that it left 10227 pixels out along the gel's edge (benchmarks/RESULTS.md,
    s34-solveswap). One LED's images correlate 0.96 or more over the gel of a press and its undeformed capture (the
    twin's coin press, 640x480), neighbours' 0.83 at most: the images alone tell, whatever the LED model."""
    from ..core.led_exchange import exchanged_images

    if samples is None:
        return []
    now, before = (values.mean(-1) for values in samples)
    found = []
    for cycle in exchanged_images(before, now):
        if set(cycle) & set(said):
            continue
        count = len(cycle)
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = np.corrcoef(now[cycle], before[cycle])[:count, count:]
        names, theirs = image_names(press), image_names(reference)
        shown = [cycle[(n + 1) % count] for n in range(count)]
        own = " / ".join(f"{corr[n, n]:.2f}" for n in range(count))
        other = " / ".join(f"{corr[n, (n + 1) % count]:.2f}" for n in range(count))
        odd = (
            f"the press's images show their own LEDs' modelled light: {reference.folder}'s are the likelier exchanged"
            if set(cycle) <= set(fitting)
            else "either one's images exchanged"
        )
        line = (
            f"{press.folder}: {_listed(names, cycle)} hold the light {reference.folder}'s "
            f"{' and '.join(theirs[j] for j in shown)} hold (correlation over the gel {own} with the undeformed "
            f"capture's images of their own LEDs, {other} with those): the press and the undeformed capture it is "
            "solved with hold their LED images in different orders (the LED wiring, the controller's LED order or "
            f"the images' order changed between them; {odd})"
        )
        found.append(ExchangedImages(tuple(cycle), line, "reference"))
    return found


def dark_rows(press: Press, leds: Sequence[Led], live: Sequence[int], mostly_dark: bool = False) -> list[DarkBand]:
    """The LED images (of the 0-based LEDs ``live``) with a band of rows (or columns) at the dark frame's level where
    the LED model ``leds`` lights the undeformed dome (:func:`_dark_rows`), ``index`` the LED's; empty without a
    surface or lit samples. :func:`led_check` finds them from its own samples. ``mostly_dark``: also a band over
    more than half an LED's image (:func:`.repeated_frames.lit_level`; where an LED's fit ran off)."""
    live = [int(i) for i in live]
    if press.reference is None or len(live) < 3:
        return []
    image, model, pixels = _sampled(press, leds, live)
    return [] if image is None else _dark_rows(press, leds, image, model, pixels, live, None, mostly_dark)


def _half_dark_rows(
    press: Press,
    leds: Sequence[Led],
    image: np.ndarray,
    model: np.ndarray,
    pixels: np.ndarray,
    live: list[int],
    everywhere: DarkBand | None,
    found: list[DarkBand],
) -> list[DarkBand]:
    """The bands over more than half an LED's image at the dark frame's level (:func:`_dark_rows` with
    ``mostly_dark``, each band's light at most :data:`~nlipscalib.core.tolerances.HALF_DARK_NOISE` times the image's
    noise: :func:`.calibration_bands.at_dark_level`) of the LEDs without a band ``found`` whose light over the model
    is dark at more than about half their samples (as :func:`.repeated_frames.lit_level` tells); none otherwise, at
    the cost of a median and a quantile.

    Why: over half dark, a band puts the LED's median light at the dark frame's noise, and every ratio to it says
    lit: the twin-like exact press's led_05.png dark over 55-80 % of its rows was called "weak LED? (0.00 times the
    light the LED model expects)" and left out whole, over 55-80 % of its columns "does not show that LED's light
    (correlation -0.22 with its model, 0.72 with LED 2's): check the wiring" and solved with its dark columns
    (s36-lagcost; s35-leftovers' "bands over half the frame are not found as bands"). The noise test keeps an LED
    far from its design, whose light ends at its own terminator over as much but holds the indirect light there,
    from being called dark (s31-ledfar, :data:`~nlipscalib.core.tolerances.HALF_DARK_NOISE`)."""
    from ..core.repeated_frames import LIT_QUANTILE
    from .calibration_bands import at_dark_level

    light = image.sum(-1) / np.maximum(model.sum(-1), 1e-12)
    top = np.quantile(light, LIT_QUANTILE, axis=1)
    banded = {band.index for band in found}
    dim = {
        live[k]
        for k in np.flatnonzero((np.median(light, axis=1) < tolerances.DARK_BAND_LIGHT * top) & (top > 0))
        if live[k] not in banded
    }
    if not dim:
        return []
    half = _dark_rows(press, leds, image, model, pixels, live, everywhere, mostly_dark=True)
    return [band for band in half if band.index in dim and at_dark_level(press, band)]


DENSE_LINE_SAMPLES = 100
"""Samples a pixel row (column) gets, about, where :func:`_dark_rows` looks for a band shorter than
:data:`~nlipscalib.core.tolerances.DARK_BAND_ROWS` bands (every ``width // 100``-th gel pixel of the row,
``height // 100``-th of the column: ~107 a row and ~120 a column at 640x480 and at 320x240)."""


def _dark_rows(
    press: Press,
    leds: Sequence[Led],
    image: np.ndarray,
    model: np.ndarray,
    pixels: np.ndarray,
    live: list[int],
    everywhere: DarkBand | None,
    mostly_dark: bool = False,
) -> list[DarkBand]:
    """The LED images with a band of rows, else of columns (a camera turned 90 degrees), at the dark frame's level:
    :func:`.dark_bands` of the sampled LED images (``image``, ``model``, ``pixels``: :func:`_sampled`'s, of the LEDs
    ``live``), and for the LEDs without one, the shorter bands that :func:`.dark_candidates` points to, told pixel
    row by pixel row (:func:`.dark_lines`) on samples dense along those rows (:data:`DENSE_LINE_SAMPLES`); their
    ``index`` the LED's (0-based), outside the rows dark in every image (``everywhere``: there the albedo fitted to
    the dark frame's noise models noise); ``mostly_dark``: :func:`dark_rows`'.

    Why the LED model: an LED's own light can end as sharply at its terminator (the synthetic ring with LEDs far
    from their design: dark top rows in 2 of 12 images, s28-rolling); the samples lie where every LED lights the
    gel directly, so rows the model lights and the image does not were read while the LED was off."""
    height, width = press.camera.shape
    light = image.sum(-1) / np.maximum(model.sum(-1), 1e-12)
    lines = dict(zip(("rows", "columns"), np.divmod(pixels, width), strict=True))
    lengths = {"rows": height, "columns": width}
    if everywhere is not None:
        along = lines[everywhere.axis]
        keep = (along < everywhere.rows[0]) | (along >= everywhere.rows[1])
        light, lines = light[:, keep], {axis: at[keep] for axis, at in lines.items()}
    found: dict[int, DarkBand] = {}
    candidates = {}
    for axis in ("rows", "columns"):
        bands, candidates[axis] = dark_bands_and_candidates(light, lines[axis], lengths[axis], axis, mostly_dark)
        for band in bands:
            found.setdefault(band.index, band)
    level = np.median(light, axis=1)
    blocky = dict(found)
    for axis in ("rows", "columns"):
        wanted = {k: bands for k, bands in enumerate(candidates[axis]) if bands.size and k not in found}
        if wanted:
            extent = (int(lines[axis].min()), int(lines[axis].max()) + 1)
            found.update(_short_dark_bands(press, leds, live, axis, wanted, level, extent, everywhere))
    if blocky:  # found by bands of rows: told to the row
        found.update(_to_the_line(press, leds, live, blocky, lit_level(light)[:, 0], lines, everywhere))
    return [found[k]._replace(index=live[k]) for k in sorted(found)]


def _to_the_line(
    press: Press,
    leds: Sequence[Led],
    live: list[int],
    found: dict[int, DarkBand],
    level: np.ndarray,
    lines: dict[str, np.ndarray],
    everywhere: DarkBand | None,
) -> dict[int, DarkBand]:
    """The bands ``found`` to a band of :data:`~nlipscalib.core.tolerances.CAPTURE_CHECK_BLUR` rows (columns), told to
    the pixel row by :func:`.dark_lines` on samples dense over them and one band either side (``level``: each LED's
    lit level, :func:`.lit_level`; ``lines``: the samples' rows and columns): widened where the dense look finds the
    band longer, else as found.

    Why: a band's partly dark last band of rows is not dark at the band's quantile, so the band was found up to 4 rows
    short; its :data:`~nlipscalib.core.tolerances.DARK_BAND_MARGIN` of 5 then left 1 row past the dark ones, and the
    LED calibration's contact check, which blurs the images by 1.5 px, carried the dark rows past it: a capture with
    LED 5's rows 0-32 of 72 dark (noise-free synth) or 0-23 / 0-53 of 120 (the twin at 160x120) was refused "as a
    press does" or with a contact, where rows 0-29 / 0-41 were named and fitted without them (benchmarks/RESULTS.md,
    s33-ledswap)."""
    b = tolerances.CAPTURE_CHECK_BLUR
    out = {}
    for axis in ("rows", "columns"):
        mine = {k: band for k, band in found.items() if band.axis == axis}
        if not mine:
            continue
        wanted = {k: np.arange(band.rows[0] // b, -(-band.rows[1] // b)) for k, band in mine.items()}
        extent = (int(lines[axis].min()), int(lines[axis].max()) + 1)
        for k, dense in _short_dark_bands(press, leds, live, axis, wanted, level, extent, everywhere).items():
            start, stop = mine[k].rows
            if dense.rows[0] < stop and dense.rows[1] > start:  # the same band, told to the row
                rows = (min(start, dense.rows[0]), max(stop, dense.rows[1]))
                out[k] = mine[k]._replace(rows=rows, where=_end_of(rows, extent, axis, mine[k].where))
    return out


def _end_of(rows: tuple[int, int], extent: tuple[int, int], axis: str, where: str) -> str:
    """Where a band of ``rows`` lies in the gel's ``extent`` of rows (columns): its end ("top", "left", ...), else
    ``where`` as found."""
    ends = ("top", "bottom") if axis == "rows" else ("left", "right")
    return ends[0] if rows[0] <= extent[0] else ends[1] if rows[1] >= extent[1] else where


def _short_dark_bands(
    press: Press,
    leds: Sequence[Led],
    live: list[int],
    axis: str,
    wanted: dict[int, np.ndarray],
    level: np.ndarray,
    extent: tuple[int, int],
    everywhere: DarkBand | None,
) -> dict[int, DarkBand]:
    """:func:`.dark_lines` of the LEDs ``wanted`` (positions in ``live`` -> their candidate bands of
    :data:`~nlipscalib.core.tolerances.CAPTURE_CHECK_BLUR` rows or columns, :func:`.dark_candidates`), on samples
    dense along those rows (columns) and one band either side; ``level``: each LED's median light over the
    modelled light on the check's own samples (the dense samples' scale)."""
    b = tolerances.CAPTURE_CHECK_BLUR
    length = press.camera.shape[0 if axis == "rows" else 1]
    near = np.zeros(length, bool)
    for bands in wanted.values():
        for band in bands:
            near[max(0, (band - 1) * b) : (band + 2) * b] = True
    if everywhere is not None and everywhere.axis == axis:
        near[everywhere.rows[0] : everywhere.rows[1]] = False
    gel = np.isfinite(press.reference.depth)
    gel = gel if axis == "rows" else gel.T
    chosen = np.flatnonzero(near)
    step = max(1, gel.shape[1] // DENSE_LINE_SAMPLES)
    at, across = np.nonzero(gel[chosen, ::step])
    at, across = chosen[at], across * step
    index = at * press.camera.width + across if axis == "rows" else across * press.camera.width + at
    image, model, pixels = _sampled_at(press, leds, live, np.sort(index))
    if image is None:
        return {}
    light = image.sum(-1) / np.maximum(model.sum(-1), 1e-12) / np.where(level > 0, level, np.nan)[:, None]
    lines = np.divmod(pixels, press.camera.width)[0 if axis == "rows" else 1]
    found = {}
    for k, bands in wanted.items():
        mine = np.zeros(length, bool)
        for band in bands:
            mine[max(0, (band - 1) * b) : (band + 2) * b] = True
        where = mine[lines]
        if dark := dark_lines(light[k, where], lines[where], extent, k, axis):
            found[k] = dark
    return found


def detected_order_of(press: Press, leds: Sequence[Led], live: Sequence[int]) -> list[int] | None:
    """:func:`led_check`'s ``order`` alone: the order the LED images show, or None (theirs, or not clear)."""
    return led_check(press, leds, live)[3]


def detected_order(shows: dict[int, tuple[int, float]], count: int) -> list[int] | None:
    """For each of ``count`` LEDs, the image that shows its light, when the misplaced images are unambiguous.

    Parameters
    ----------
    shows : dict int -> (int, float) -- each misplaced image (0-based) -> the LED whose light it shows best
        (0-based) and its correlation with that LED's modelled light.
    count : int -- LEDs of the capture.

    Returns
    -------
    list of int (``count``), the image of each LED (the identity where nothing is misplaced), or None when
    nothing is misplaced, when two images show one LED, when an image shows an LED whose own image is not
    misplaced (a pair or cycle is closed), or when one correlates with its LED below :data:`REORDER_CORRELATION`.
    """
    if not shows:
        return None
    targets = [j for j, _ in shows.values()]
    closed = sorted(targets) == sorted(shows)
    if not closed or min(c for _, c in shows.values()) < REORDER_CORRELATION:
        return None
    order = list(range(count))
    for image, (led, _) in shows.items():
        order[led] = image
    return order


def reordered(press: Press, order: Sequence[int]) -> Press:
    """``press`` with its LED images in ``order`` (``order[j]``: the image of LED ``j``), meta.json's
    ``images.leds`` names with them (warnings name the files); the LEDs and the other fields ``press``'s own."""
    order = [int(i) for i in order]
    fields = {field.name: press.__dict__[field.name] for field in dataclasses.fields(press)}
    fields["led_images"] = press.led_images[order]
    images = (press.meta.get("images") or {}).get("leds")
    if isinstance(images, list) and len(images) == len(order):
        fields["meta"] = {**press.meta, "images": {**press.meta["images"], "leds": [images[i] for i in order]}}
    return Press(**fields)


def reorder_note(press: Press, order: Sequence[int], flag: str, fit: bool = False) -> str:
    """The warning of a solve (``fit``: an LED calibration) that uses the LED images in the ``order`` they show
    (:func:`detected_order`)."""
    names = image_names(press)
    moved = ", ".join(
        f"{names[i]} (image {i + 1} of images.leds) as LED {j + 1}" for j, i in enumerate(order) if i != j
    )
    done, record, keep = ("fitted", "the LED file's", "fit") if fit else ("solved", "report.json", "solve")
    return (
        f"{press.folder}: the LED images are out of order (each shows another LED's light: a wiring error, or the "
        f"order of images.leds in meta.json): {done} in the order they show, {moved} ({record} led_order); fix "
        f"the wiring or images.leds, or pass {flag} to {keep} them as captured"
    )


def _leave_out(candidates: list[int], count: int) -> list[int]:
    """``candidates`` (0-based LEDs) when at least ``tolerances.MIN_LEDS_PER_PIXEL`` of ``count`` LEDs are left
    without them, else none (too few LEDs to solve: they are only warned about)."""
    return sorted(candidates) if count - len(candidates) >= tolerances.MIN_LEDS_PER_PIXEL else []


def _repeated_line(press: Press, names: list[str]) -> tuple[list[str], list[int], list[LaggedBand], DarkBand | None]:
    """The line naming LED images that repeat the image before them (:func:`.frame_checks`: frames that lag the LED
    switch), none when none does, those LEDs (0-based), in the capture order of ``images.leds``; the LED images
    read out across the switch by a rolling shutter, in part the previous LED's light (:func:`.lagged_bands`); and
    the rows dark in every LED image (None: none). The LED pairs a lag between which the check cannot see (LEDs in
    close pairs) said once per command (:func:`.say_lag_blind`; report.json ``lag_blind_pairs``)."""
    from .exposure import expected_light_of

    gel = np.isfinite(press.reference.depth)
    expected = expected_light_of(press)
    repeated, bands, everywhere = frame_checks(press.linear_led_images, gel, expected)
    say_lag_blind(press.folder, expected, gel)
    lines = [repeated_line(press.folder, names, repeated)] if repeated else []
    return lines, sorted(i for i, _ in repeated), bands, everywhere


DARK_ALL = "no LED can be left out for it: the normals solved in those {} are wrong"
"""The tail of the solve's warning about rows (columns: ``DARK_ALL.format(axis)``) dark in every LED image
(:func:`.dark_everywhere_line`)."""
REPEATED_REASON = "they hold the light of the LED before them"
"""Why :func:`_said_repeated` leaves repeated LED images out."""
LAGGED_DONE = (
    f"; left out of the solve for that LED only, with {tolerances.DARK_BAND_MARGIN} rows (columns) more and to the "
    "frame's edge (they hold the light of the LED before it), the rest of its image used"
)
"""What the solve does about an LED image's rows (columns) read before its LED switched (:func:`.lagged_line`): as
about dark rows (:data:`DARK_DONE`; :func:`.dark_band_mask`).

Why not the LED whole (as s28-rolling and s30-qaleft did): the twin's sphere and cube presses (640x480, --roi auto;
clean 0.503 / 0.442 deg) with LED 5's rows 0-119, 0-359, 420-479 or columns 0-59, 0-210 from LED 4 gave a contact
AAE of 0.509-0.515 / 0.455-0.468 deg with the LED left out, 0.503-0.516 / 0.442-0.453 with only its band left out
(and its gain measured off the band: with it, 0.546 / 0.605 on columns 0-210; benchmarks/RESULTS.md, s31-darkall)."""
DARK_DONE = (
    f"; left out of the solve for that LED only, with {tolerances.DARK_BAND_MARGIN} rows (columns) either side "
    "(read while it was off, they hold none of its light), the rest of its image used"
)
"""What the solve does about an LED image's dark rows (:func:`.dark_line`'s ``done``).

Why not the LED whole (as s29-darkrows did): the twin's sphere and cube presses (640x480, --roi auto; clean 0.509 /
0.439 deg) with a band of LED 5's or LED 9's rows or columns dark (3-200 of them, top, middle, bottom, left, right)
gave a contact AAE of 0.512-0.520 / 0.441-0.452 deg with the LED left out, 0.508-0.514 / 0.436-0.441 with only its
band's rows left out (benchmarks/RESULTS.md, s30-darkcols)."""


def _said_repeated(lines: list[str], left_out: list[int], reason: str = REPEATED_REASON) -> list[str]:
    """The warnings of :func:`_repeated_line`'s ``lines``, saying whether the solve leaves those LEDs out (not when
    too few LEDs would be left: :func:`_leave_out`), and ``reason``."""
    done = "left out of the solve" if left_out else "used (too few LEDs to leave them out)"
    return [f"{line}; {done} ({reason})" for line in lines]


SHIFT_BANDS = 16
"""Bands of rows (columns) :func:`shifted_rows` fits one by one (30 rows at 480, 40 columns at 640: the reported
lines are to a band)."""
SHIFT_BAND_SAMPLES = 50
"""Fewest samples a band needs for a verdict in :func:`shifted_rows` (~a band's at 2 x :data:`CHECK_PIXELS`)."""


class ShiftedBand(NamedTuple):
    """Rows (or columns) at the frame's edge in which every LED image shows the light of the LED before it
    (:func:`shifted_rows`)."""

    lines: tuple[int, int]
    """First and one-past-last pixel row (``axis`` "columns": column), to a band (:data:`SHIFT_BANDS`)."""
    top: bool
    """At the frame's top (columns: its left), else its bottom (right)."""
    axis: str = "rows"
    """"rows", or "columns": a camera mounted turned 90 degrees, its rolling shutter reading the image's columns."""

    @property
    def where(self) -> str:
        """ "top" or "bottom" of the rows; "left" or "right" of the columns."""
        return ("top" if self.top else "bottom") if self.axis == "rows" else ("left" if self.top else "right")


def shifted_notes(press: Press, leds: Sequence[Led], live: Sequence[int]) -> list[str]:
    """The warning when a band of rows at the top or bottom (columns at the left or right: a camera turned 90
    degrees) of every LED image shows the previous LED's light (:func:`shifted_rows`): a systematic timing error, no
    LED can be left out for it."""
    band = shifted_rows(press, leds, live)
    if band is None:
        return []
    first, stop = band.lines
    reads = (
        "a rolling shutter reads the rows one after another"
        if band.axis == "rows"
        else "a camera mounted turned 90 degrees: its rolling shutter reads the image's columns one after another"
    )
    return [
        f"{press.folder}: {band.axis} {first}-{stop - 1} ({band.where}) of the LED images show the light of the LED "
        f"captured before each: the LEDs switched while the camera read the frames out ({reads}), every frame "
        "alike; capture again with --flush 1 or more (frames dropped after each LED change, default 2) and frames "
        f"that are not read out before the LED lit; the normals solved in those {band.axis} are wrong"
    ]


def shifted_rows(press: Press, leds: Sequence[Led], live: Sequence[int]) -> ShiftedBand | None:
    """The rows at the top or the bottom of the frame (else the columns at its left or right: a camera mounted
    turned 90 degrees) in which the LED images show the light of the LED before them in capture order, or None.

    Per band of rows (columns; :data:`SHIFT_BANDS`) and live LED k whose predecessor is live, the LED image is
    fitted (gain and offset: albedo and interreflection) to LED k's modelled light and to LED k-1's on the
    undeformed dome; a band whose median over the LEDs of the two misfits' ratio (previous / own) is below
    :data:`~nlipscalib.core.tolerances.SHIFTED_BAND_RATIO` holds the previous LED's light. Why model, not the
    images: with every frame read across its switch, neighbouring images no longer share any rows' light
    (:func:`nlipscalib.core.repeated_frames.frame_lags` sees nothing).
    """
    pairs = [k for k in live if k >= 1 and k - 1 in set(live)]
    ref = press.reference
    if ref is None or len(pairs) < 3:
        return None
    index = np.flatnonzero(np.isfinite(ref.depth))
    index = index[:: max(1, index.size // (2 * CHECK_PIXELS))]
    rows, cols = np.divmod(index, press.camera.width)
    rays = press.camera.unproject(np.stack([cols, rows], axis=-1).astype(np.float64))
    points = depth_to_points(ref.depth.reshape(-1)[index].astype(float), rays)
    model = led_shading(points, ref.normals.reshape(-1, 3)[index].astype(float), list(leds)).sum(axis=-1)
    image = np.stack([press.linear_led_images[k].reshape(-1, 3)[index].sum(axis=-1) for k in pairs]).astype(float)
    own, previous = model[pairs], model[[k - 1 for k in pairs]]
    found = []
    for axis, at, length in (("rows", rows, press.camera.height), ("columns", cols, press.camera.width)):
        band = at * SHIFT_BANDS // length
        ratio = np.median(_band_misfits(image, previous, band) / _band_misfits(image, own, band), axis=0)
        if shifted := _shifted_edge(ratio, length, axis):
            found.append((float(np.nanmean(ratio[_band_of(shifted, length)])), shifted))
    # where both look shifted (a band of columns leaves some rows mostly inside it, as lagged_bands says), the
    # band whose light is the more plainly the previous LED's: the lower ratio
    return min(found)[1] if found else None


def _band_of(shifted: ShiftedBand, length: int) -> slice:
    """The bands (:data:`SHIFT_BANDS` over ``length`` lines) ``shifted`` spans."""
    return slice(shifted.lines[0] * SHIFT_BANDS // length, -(-shifted.lines[1] * SHIFT_BANDS // length))


def _shifted_edge(ratio: np.ndarray, length: int, axis: str) -> ShiftedBand | None:
    """The run of bands from the frame's first (else last) band whose ``ratio`` ((SHIFT_BANDS,), NaN: no verdict)
    is below :data:`~nlipscalib.core.tolerances.SHIFTED_BAND_RATIO`, not all of the counted ones."""
    shifted = ratio < tolerances.SHIFTED_BAND_RATIO  # NaN: False
    counted = np.flatnonzero(np.isfinite(ratio))
    if not shifted.any() or shifted[counted].all():
        return None
    for top, ordered in ((True, counted), (False, counted[::-1])):
        run = int(np.argmax(~shifted[ordered]))  # the first band of the LEDs' own light
        if run:
            ends = sorted((ordered[0], ordered[run - 1]))
            lines = (int(ends[0]) * length // SHIFT_BANDS, (int(ends[1]) + 1) * length // SHIFT_BANDS)
            return ShiftedBand(lines, top, axis)
    return None


def _band_misfits(image: np.ndarray, model: np.ndarray, band: np.ndarray) -> np.ndarray:
    """(L, SHIFT_BANDS) float: the rms misfit of each row of ``image`` (L, N) fitted as gain x ``model`` (L, N) +
    offset, over its mean, over the samples of each band (``band``: (N,) int, 0 to SHIFT_BANDS - 1); NaN where a band
    holds fewer than :data:`SHIFT_BAND_SAMPLES`. The bands' sums in one pass (``np.add.reduceat`` on the samples
    sorted by band: a matrix product with the bands' indicator took ~1 ms here, OpenBLAS on 2 busy cores)."""
    order = np.argsort(band, kind="stable")
    count = np.bincount(band, minlength=SHIFT_BANDS)
    starts = np.cumsum(count) - count  # an empty band's sum is masked below
    pad = np.zeros((len(model), 1))  # a last start past the samples (empty bands at the end) reads this
    x, y = np.hstack([model[:, order], pad]), np.hstack([image[:, order], pad])
    n = np.maximum(count, 1)

    def mean(values: np.ndarray) -> np.ndarray:
        return np.add.reduceat(values, starts, axis=1) / n

    mean_x, mean_y = mean(x), mean(y)
    sxx, sxy, syy = mean(x * x) - mean_x**2, mean(x * y) - mean_x * mean_y, mean(y * y) - mean_y**2
    gain = sxy / np.maximum(sxx, 1e-24)
    rms = np.sqrt(np.maximum(syy - gain * sxy, 0.0))
    misfit = np.maximum(rms / np.maximum(np.abs(mean_y), 1e-12), 1e-12)
    misfit[:, count < SHIFT_BAND_SAMPLES] = np.nan
    return misfit


def compression_notes(press: Press) -> list[str]:
    """The warning when the LED images went through JPEG (:func:`nlipscalib.core.compression.blockiness` over
    the gel above :data:`~nlipscalib.core.tolerances.JPEG_BLOCKINESS`: a camera streaming MJPEG); [] without an
    undeformed surface to say where the gel is. ~4 ms on a 640x480 press of 12 LEDs (6 of its LED images, a
    seventh of their rows and columns, one channel)."""
    if press.reference is None:
        return []
    value = compressed(press.led_images, np.isfinite(press.reference.depth))
    return [] if value is None else [blockiness_line(press.folder, "the LED images", value)]


def linearity_notes(press: Press, live: Sequence[int], indirect: Sequence[np.ndarray] | None = None) -> list[str]:
    """A warning when the LED images are not linear in the light: the median over the sampled pixels of the
    log-log slope of each pixel's LED images against its modelled light, direct and indirect
    (:func:`recorded_response_slope`), is below :data:`~nlipscalib.core.tolerances.LINEAR_RESPONSE_SLOPE` (an sRGB
    or gamma-encoded camera output).

    The direct light is modelled with the LEDs the capture records (meta.json: the design's), never with calibrated
    ones: an LED calibration on gamma-encoded images absorbs the tone curve (the twin's sRGB reference: LEDs
    moved 2.5 mm, "reliable") and the solve with it gave 3.6 deg instead of 0.46.

    Parameters
    ----------
    press : Press -- with ``reference`` (none: no check, []).
    live : sequence of int -- the LEDs (0-based) to judge.
    indirect : sequence of (H, W, 3) float or None -- the indirect light per unit albedo of each of the press's
        LEDs (``IndirectModel.undeformed_light_per_led``: a solve's fitted term); None: fitted here
        (:func:`own_indirect_light`).

    A capture that declares a tone curve is warned about the other way above
    :data:`~nlipscalib.core.tolerances.DECLARED_CURVE_SLOPE`: linear frames declared sRGB."""
    slope = recorded_response_slope(press, live, indirect)
    declared = press.response.camera_response
    if slope is not None and declared != "linear" and slope > tolerances.DECLARED_CURVE_SLOPE:
        return [
            f"{press.folder}: meta.json declares the camera's {declared} tone curve (sensor.camera_response), "
            f"but with it undone each pixel's value grows as the LED model's light to the power {slope:.2f} "
            f"(median; a linear capture: about 1): the frames were linear already? Remove "
            + (
                '"camera_response" and "response_curve" (or remeasure the curve with the camera set as it captured: '
                "`nlips calibrate-camera-response`)"
                if press.response.response_curve is not None
                else '"camera_response" (or set it to "linear")'
            )
            + "; normals solved from it are wrong by degrees"
        ]
    if slope is None or slope >= tolerances.LINEAR_RESPONSE_SLOPE:
        return []
    return [
        f"{press.folder}: the LED images are not linear in the light: across the LEDs each pixel's value grows as "
        f"the LED model's light (direct and interreflected) to the power {slope:.2f} (median; a linear capture: "
        f"about 1), as in gamma-encoded (sRGB) frames: capture raw, linear frames, with the "
        f"camera's gamma, auto exposure and auto white balance off ({CAMERA_SETTINGS_GUIDE}), {DECLARE_TONE_CURVE}; "
        f"the solve's normals are wrong by degrees"
    ]


def recorded_response_slope(
    press: Press, live: Sequence[int], indirect: Sequence[np.ndarray] | None = None, min_fit: float = 0.0
) -> float | None:
    """:func:`response_slope` of the ``live`` LED images (0-based) against the light of the LEDs the capture
    records (meta.json), never calibrated ones (:func:`linearity_notes` says why), plus the ``indirect`` light
    (:func:`linearity_notes`; None: :func:`own_indirect_light`); None without an undeformed surface, with too
    few lit pixels, or when the power law fits worse than ``min_fit`` (:func:`response_slope`).

    Why the indirect light: against the direct light alone a linear capture's slope is its direct share, not 1:
    the capsule's own interreflection gave 0.28-0.34 on every linear capture (warned as gamma-encoded), the
    default dome 0.75; with the fitted term 1.00-1.02 on both, and their sRGB encodings 0.48-0.49."""
    live = [int(i) for i in live]
    if press.reference is None:
        return None
    if indirect is None:
        indirect = own_indirect_light(press)
    image, model = _samples(press, press.leds, live, indirect)
    return None if image is None else response_slope(image, model, min_fit)


def own_indirect_light(press: Press) -> Sequence[np.ndarray] | None:
    """The indirect light per unit albedo of each LED (``IndirectModel.undeformed_light_per_led``) fitted on the
    press itself with the LEDs it records (:func:`.indirect.fit_indirect`, forced on, one bounce), for a check made
    before or without a solve's fit (the LED calibration, the dark frame's cause); None when nothing can be fitted
    (the check then judges the direct light alone)."""
    try:
        model = fit_indirect(press, press.leds, mode="on", bounces=1)
    except CaptureError:
        return None
    return model.undeformed_light_per_led(press.camera.shape)


def response_slope(image: np.ndarray, model: np.ndarray, min_fit: float = 0.0) -> float | None:
    """Median over pixels of the least-squares slope of log(image) against log(model) across the LEDs: 1 for a
    linear response without interreflection, ``gamma`` for a camera that records ``x ** gamma``.

    Parameters
    ----------
    image, model : (L, N, 3) float -- LED images and their modelled light at N pixels (:func:`_samples`).
    min_fit : float -- the least median R^2 of those fits for the slope to be told: images that follow no power
        law of the model (frames of another scene, flat test frames) give a slope that says nothing of a tone curve
        (``nlips capture``'s reference check asks :data:`~nlipscalib.core.tolerances.RESPONSE_POWER_LAW_FIT`; the
        solve 0, any fit).

    Returns
    -------
    float, or None when fewer than 10 pixels have light from every LED, or the fit is worse than ``min_fit``
    """
    image, model = image.mean(axis=-1), model.mean(axis=-1)
    usable = (image > tolerances.LIT_LEVEL).all(axis=0) & (model > 0).all(axis=0)
    if usable.sum() < 10:
        return None
    x, y = np.log(model[:, usable]), np.log(image[:, usable])
    x, y = x - x.mean(axis=0), y - y.mean(axis=0)
    sxx, sxy = (x * x).sum(axis=0), (x * y).sum(axis=0)
    if min_fit > 0 and np.median(sxy * sxy / np.maximum(sxx * (y * y).sum(axis=0), 1e-24)) < min_fit:
        return None
    return float(np.median(sxy / np.maximum(sxx, 1e-12)))


def _samples(
    press: Press, leds: Sequence[Led], live: list[int], indirect: Sequence[np.ndarray] | None = None
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """:func:`_sampled`'s images and modelled light, without the pixels."""
    return _sampled(press, leds, live, indirect)[:2]


def _sampled(
    press: Press, leds: Sequence[Led], live: list[int], indirect: Sequence[np.ndarray] | None = None
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """The live LED images and their modelled light (albedo fitted per pixel and channel over the live LEDs; with
    ``indirect``, each LED's (H, W, 3) indirect light per unit albedo added to its direct shading) on a subgrid of
    the gel: two (L_live, N, 3) float64 arrays and the samples' (N,) flat pixel indices, or Nones when too few gel
    pixels are lit."""
    index = np.flatnonzero(np.isfinite(press.reference.depth))
    index = index[:: max(1, index.size // CHECK_PIXELS)]  # every k-th gel pixel in raster order
    return _sampled_at(press, leds, live, index, indirect)


def _sampled_at(
    press: Press,
    leds: Sequence[Led],
    live: list[int],
    index: np.ndarray,
    indirect: Sequence[np.ndarray] | None = None,
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """:func:`_sampled` at the gel pixels ``index`` ((n,) int, flat, row-major)."""
    ref = press.reference
    if index.size < 10:
        return None, None, None
    depth = ref.depth.reshape(-1)[index].astype(float)
    # the sampled pixels' rays only: the whole frame's (Camera.rays, 0.1 s at 640x480) is more than a solve on
    # the contact's box ever needs
    rows, cols = np.divmod(index, press.camera.width)
    rays = press.camera.unproject(np.stack([cols, rows], axis=-1).astype(np.float64))
    points = depth_to_points(depth, rays)
    normals = ref.normals.reshape(-1, 3)[index].astype(float)
    direct = led_shading(points, normals, [leds[i] for i in live])  # (L_live, N, 3)
    shading = direct
    if indirect is not None:
        shading = direct + np.stack([np.asarray(indirect[i]).reshape(-1, 3)[index] for i in live])
    image = np.stack([press.linear_led_images[i].reshape(-1, 3)[index] for i in live]).astype(float)
    albedo = (shading * image).sum(0) / np.maximum((shading * shading).sum(0), 1e-24)
    lit = (direct > 0).all(axis=(0, 2)) & (albedo > 0).all(axis=1)
    if lit.sum() < 10:
        return None, None, None
    return image[:, lit], (albedo * shading)[:, lit], index[lit]


def image_names(press: Press) -> list[str]:
    """The LED images' file names as meta.json lists them (LED ``i`` at ``i``), or "image i" when they cannot be
    matched (an LED subset)."""
    names = (press.meta.get("images") or {}).get("leds")
    if not isinstance(names, list) or len(names) != len(press.leds):
        return [f"image {i + 1}" for i in range(len(press.leds))]
    return [str(name) for name in names]


def exposure_drift(press: Press, reference: Press) -> np.ndarray | None:
    """Each LED image's brightness against the undeformed capture's of the same LED, per channel, relative to their
    median: (L, 3) float64 ratios, 1 where the two were taken alike; None without a surface, or with other image
    sizes or LED counts (:func:`exposure_ratio` over its median)."""
    ratio = exposure_ratio(press, reference)
    return None if ratio is None else ratio / np.median(ratio)


def exposure_ratio(
    press: Press,
    reference: Press,
    bands: Sequence[DarkBand | LaggedBand] = (),
    samples: tuple[np.ndarray, np.ndarray] | None = None,
    outside: np.ndarray | None = None,
) -> np.ndarray | None:
    """Each LED image's brightness against the undeformed capture's of the same LED, per channel: (L, 3) float64
    ratios (the median over the gel of the pixels' ratios), 1 where the two were taken alike; None without a
    surface, or with other image sizes or LED counts. ``bands``: the LED images' dark or lagged bands
    (:func:`led_check_measured`'s), their samples left out of that LED's median (:func:`.dark_band_mask`): there
    the image holds no light of its LED (the twin's sphere press with LED 5's columns 0-209 from LED 4 measured
    LED 5 at 0.98, and the solve rescaled its image by it).
    ``samples``: :func:`drift_samples` of the two with the same ``outside``, when taken already (None: taken here).
    ``outside``: (H, W) bool, the pixels away from the contact (the gel outside the solve's box): the gel is sampled
    there when at least :data:`OUTSIDE_PIXELS` of its pixels lie in it, else everywhere. Why: a contact that covers
    most of the gel moves the median by its own shading; the twin's flat pad pressed 1 mm by a 5 mm cube (65 % of the
    gel in contact) read LEDs 1 and 12 at 0.97-0.98 and 1.01 elsewhere, the solve rescaled their images by it and its
    contact AAE went 0.31 -> 0.81 deg (0.30 with the median outside the box; benchmarks/RESULTS.md, s41-flatcube).

    Why: a camera left on auto exposure, gain or white balance scales each LED image (and each channel) by its
    own factor; the LED model then fits nowhere (s27 QA walk, 8-bit twin with +-15 % exposure and +-8 % white
    balance per image: "--roi auto found no contact ... the LED model does not fit this sensor"). A press differs
    from the undeformed capture only in its contact, so the median over the gel of each LED's ratio is that LED's
    exposure change."""
    samples = drift_samples(press, reference, outside) if samples is None else samples
    if samples is None:
        return None
    now, before = samples
    index = _drift_index(press, outside)
    lit = (before > tolerances.EXPOSURE_LIGHT_FRACTION) & (now > tolerances.EXPOSURE_LIGHT_FRACTION)
    if bands:
        banded = sorted({band.index for band in bands})
        mask = dark_band_mask(list(bands), banded, press.camera.shape).reshape(len(banded), -1)[:, index]
        lit[banded] &= ~mask[..., None]
    if (lit.sum(axis=1) < 10).any():
        return None
    ratio = np.array(
        [[np.median(now[k, lit[k, :, c], c] / before[k, lit[k, :, c], c]) for c in range(3)] for k in range(len(now))]
    )
    return ratio


def _drift_index(press: Press, outside: np.ndarray | None = None) -> np.ndarray:
    """(n,) int -- the flat gel pixels :func:`exposure_ratio` compares a press and its undeformed capture on: every
    k-th of the press's surface, about :data:`CHECK_PIXELS`; of its part in ``outside`` ((H, W) bool) when that holds
    at least :data:`OUTSIDE_PIXELS` of them."""
    gel = np.isfinite(press.reference.depth)
    if outside is not None and np.count_nonzero(away := gel & outside) >= OUTSIDE_PIXELS:
        gel = away
    index = np.flatnonzero(gel)
    return index[:: max(1, index.size // CHECK_PIXELS)]


def drift_samples(
    press: Press, reference: Press, outside: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray] | None:
    """The press's and the undeformed capture's linear LED images at :func:`_drift_index`: two (L, n, 3) float64
    arrays, the capture's kept as its other results are (one decoding a session); None without a surface, or with
    other image sizes or LED counts. Taken once a solve, for :func:`reference_exchanges` and :func:`exposure_ratio`:
    the capture's key (its images' digest) took ~50 ms of a 640x480 capture's each time on the loaded 2-core VM.
    ``outside``: the pixels to sample, as :func:`_drift_index`'s."""
    if press.reference is None or reference.camera.shape != press.camera.shape:
        return None
    if len(reference.leds) != len(press.leds):
        return None
    index = _drift_index(press, outside)
    now = press.linear_led_images.reshape(len(press.leds), -1, 3)[:, index].astype(np.float64)

    def sampled() -> np.ndarray:
        return reference.linear_led_images.reshape(len(press.leds), -1, 3)[:, index].astype(np.float64)

    # kept on disk under the undeformed capture's bytes, as its other results: a warm solve never decodes it
    where = hashlib.sha256(index.tobytes()).hexdigest()[:16]
    before = reuse.reused(
        "drift reference", (reference.images_digest(), reference.response, where), sampled, persist=True
    )
    return now, before


def reference_gain(ratio: np.ndarray) -> np.ndarray:
    """(3,) float64 -- the press's brightness over the undeformed capture's, per channel: the median over the LEDs
    of :func:`exposure_ratio`'s (L, 3) ratios (each already a median over the gel, so the contact, a small part of
    it, does not move it; nor does one LED group of a third of the LEDs dimmed on its own: that is
    :func:`led_gains`' and :func:`exposure_drift_note`'s).

    Why: all LEDs aged alike, or an exposure or gain changed, scale every image by one factor, which the albedo
    absorbs, but the indirect term fitted on the undeformed capture holds that capture's brightness (its kappa is
    per unit albedo): on the twin's sphere press with every LED image 10 % dimmer the whole-gel depth RMSE went from
    0.039 to 0.27 mm (benchmarks/RESULTS.md, s28-dimref). The solve scales the term by this gain
    (:meth:`.indirect.IndirectModel.with_gain`)."""
    return np.median(ratio, axis=0)


def led_gains(ratio: np.ndarray, misplaced: Sequence[int] = ()) -> np.ndarray | None:
    """(L, 3) float64 -- each LED's brightness against the undeformed capture's, per channel, over the press's
    overall gain (:func:`reference_gain`), when one strays from 1 by more than
    :data:`~nlipscalib.core.tolerances.LED_GAIN_CORRECTION`; None when every LED is within it (as captured).
    ``misplaced`` (0-based): LEDs whose images show another LED's light, kept at 1 (their ratio is no gain).

    Why: an LED that aged on its own (the red group 10 % dimmer on the twin's sphere and cube presses) scales its
    own images only; the model, with its calibrated Psi and the indirect light fitted on the undeformed capture,
    then misfits every pixel that LED lights: contact AAE 0.50 -> 4.8 deg, depth 0.49 mm off (benchmarks/RESULTS.md,
    s28-dimref). Each ratio is a median over the gel (outside the solve's box when it has one, given or
    ``--roi auto``'s: :func:`exposure_ratio`, ``solver.press``), so the contact does not move it. The solve rescales
    those images (:func:`nlipscalib.core.capture.with_led_gains`)."""
    gains = ratio / reference_gain(ratio)
    gains[[int(i) for i in misplaced]] = 1.0
    if np.abs(np.log(gains)).max() <= np.log1p(tolerances.LED_GAIN_CORRECTION):
        return None
    return gains


def agreed_gains(whole: np.ndarray, away: np.ndarray | None) -> np.ndarray | None:
    """(L, 3) float64 -- :func:`led_gains` ``away`` (measured on the gel outside the contact's box), kept for the LEDs
    that both it and ``whole`` (the same LEDs' :func:`led_gains` over the whole gel) find stray beyond
    :data:`~nlipscalib.core.tolerances.LED_GAIN_CORRECTION` the same way, 1 for the others; None when no LED is
    both (or ``away`` is None: no gain found there).

    Why: an LED that aged on its own scales its images everywhere, so both measures find it; a large contact moves
    them apart, each by its own shading: on the whole gel by its dent (the flat pad's cube: 7 LEDs 0.974-1.011,
    s41-flatcube), outside the box by the light the dent bounces onto the rest of the gel (the twin's 30 mm sphere
    3 mm deep over 41 % of the gel, 640x480: LEDs 1-2 0.988 outside its box, 0.996 over the whole gel; both within
    0.16 % without bounces). Taking every LED's outside ratio (s41-autogain) rescaled
    those two with an aged LED 8: contact AAE 1.08 deg, 0.80 now, 0.79 with LED 8's true gain alone
    (benchmarks/RESULTS.md, s42-autogain2)."""
    if away is None:
        return None
    tol = np.log1p(tolerances.LED_GAIN_CORRECTION)
    lw, la = np.log(whole), np.log(away)
    both = ((lw > tol) & (la > tol)) | ((lw < -tol) & (la < -tol))
    leds = both.any(axis=1)
    if not leds.any():
        return None
    return np.where(leds[:, None], away, 1.0)


def changed_leds(gains: np.ndarray) -> list[int]:
    """The LEDs (0-based) whose :func:`led_gains` stray beyond ``tolerances.LED_GAIN_CORRECTION``."""
    off = np.abs(np.log(gains)).max(axis=1) > np.log1p(tolerances.LED_GAIN_CORRECTION)
    return [int(i) for i in np.flatnonzero(off)]


def reference_gain_note(press: Press, reference: Press, gain: np.ndarray) -> str | None:
    """A warning when :func:`reference_gain` strays from 1 by more than
    :data:`~nlipscalib.core.tolerances.REFERENCE_GAIN_DRIFT`: the LEDs aged or the exposure changed since the
    undeformed capture."""
    if np.abs(np.log(gain)).max() <= np.log1p(tolerances.REFERENCE_GAIN_DRIFT):
        return None
    colours = "/".join(f"{g:.2f}" for g in gain)
    return (
        f"{press.folder}: the LED images are {colours} times (red/green/blue) as bright as the undeformed capture's "
        f"{reference.folder}, every LED alike: LEDs aged (dimmer with use) or the exposure or gain changed since. "
        f"The solve scales the undeformed capture's light by this gain; a fresh capture of the undeformed dome "
        f"(--reference) at today's settings is the remedy"
    )


def exposure_drift_note(
    press: Press, reference: Press, ratio: np.ndarray | None = None, gains: np.ndarray | None = None
) -> str | None:
    """A warning when :func:`exposure_drift` spreads beyond :data:`~nlipscalib.core.tolerances.EXPOSURE_DRIFT`:
    auto exposure, gain or white balance on, or one group of LEDs aged. ``ratio``: :func:`exposure_ratio`'s, when
    already measured; ``gains``: :func:`led_gains`, when the solve rescales the images by them (the note names those
    LEDs)."""
    ratio = exposure_ratio(press, reference) if ratio is None else ratio
    drift = None if ratio is None else ratio / np.median(ratio)
    if drift is None or np.abs(np.log(drift)).max() <= np.log1p(tolerances.EXPOSURE_DRIFT):
        return None
    worst = int(np.unravel_index(np.argmax(np.abs(np.log(drift))), drift.shape)[0])
    names = image_names(press)
    return (
        f"{press.folder}: the LED images are {drift.min():.2f}-{drift.max():.2f} times as bright as the undeformed "
        f"capture's {reference.folder} (per LED and channel, relative to their median; {names[worst]} the most "
        f"changed): auto exposure, gain or white balance on, or some LEDs aged (dimmer with use) since that capture? "
        f"Every image must be taken at one fixed exposure, gain and white balance ({CAMERA_SETTINGS_GUIDE}); for "
        f"aged LEDs a fresh capture of the undeformed dome (--reference) and of the LEDs (nlips calibrate-leds)"
        + (_rescaled(names, gains) if gains is not None else "")
    )


def _rescaled(names: Sequence[str], gains: np.ndarray) -> str:
    """The drift note's tail when the solve rescales LED images by :func:`led_gains`: which, and by how much."""
    which = ", ".join(f"LED {i + 1} ({names[i]}) {np.median(gains[i]):.2f}" for i in changed_leds(gains))
    return (
        f". The solve rescaled these LED images to the undeformed capture's brightness (report.json led_gains): "
        f"{which}; the lasting fix is that fresh capture and calibration"
    )


GROUP_NAMES = TRICOLOR_NAMES
"""The tri-colour groups' names (:data:`nlipscalib.core.leds.TRICOLOR_NAMES`), for warnings."""


def model_led_gains(relative: np.ndarray, groups: np.ndarray) -> np.ndarray | None:
    """Each LED's gain against the LED model when some LED or tri-colour group is off beyond the model's own error,
    for a solve without an undeformed capture: (L,) float64, 1 where within it; None when every LED is.

    A group whose median of ``relative`` over the median group's strays beyond
    :data:`~nlipscalib.core.tolerances.MODEL_GROUP_GAIN` gets that group gain on each of its LEDs (judged together:
    one LED's own gain, up to 3.6 % off from the model's error, caught a 5 % dimmer red group's LED 1 alone and the
    solve went 1.60 deg instead of 0.50); an LED whose ``relative`` over its group's median strays beyond
    :data:`~nlipscalib.core.tolerances.MODEL_LED_GAIN` gets that own gain too (benchmarks/RESULTS.md, s28-noref).

    Parameters
    ----------
    relative : (L,) float -- each LED's light against the LED model, relative to the median LED
        (:func:`model_relative_gains`).
    groups : (L,) int -- each LED's tri-colour group (0 red, 1 green, 2 blue).
    """
    relative, groups = np.asarray(relative, np.float64), np.asarray(groups)
    present = np.unique(groups)
    medians = {int(g): float(np.median(relative[groups == g])) for g in present}
    middle = float(np.median(list(medians.values())))
    gains = np.ones_like(relative)
    for g, median in medians.items():
        if abs(np.log(median / middle)) > np.log1p(tolerances.MODEL_GROUP_GAIN):
            gains[groups == g] = median / middle
    own = relative / np.array([medians[int(g)] for g in groups])
    off = np.abs(np.log(own)) > np.log1p(tolerances.MODEL_LED_GAIN)
    gains[off] *= own[off]
    return None if np.all(gains == 1.0) else gains


def model_relative_gains(press: Press, leds: Sequence[Led], live: Sequence[int]) -> np.ndarray | None:
    """(len(live),) float64 -- each live LED's light (0-based ``live``) against the LED model ``leds`` (albedo fitted
    over the LEDs, the weak-LED check's :func:`led_check`), relative to the median LED; None without an undeformed
    surface or with too few lit pixels. The twin's design LEDs: 0.966-1.022, the same LEDs low on every press."""
    live = [int(i) for i in live]
    if press.reference is None or len(live) < 3:
        return None
    image, model = _samples(press, leds, live)
    return None if image is None else _relative_gains(image, model)


def _relative_gains(image: np.ndarray, model: np.ndarray, judged: Sequence[int] | None = None) -> np.ndarray:
    """(L,) float64 -- each LED's median over the samples of image over model (:func:`_samples`' (L, N, 3) arrays),
    over the median of the LEDs ``judged`` (indices into L; None or empty: all; an image with dark rows is off the
    model there, so it does not set the scale)."""
    gain = np.median(image / np.maximum(model, 1e-12), axis=(1, 2))
    scale = float(np.median(gain[list(judged)] if judged else gain))
    if not scale > 0:
        # the judged LEDs light none of the samples the model lights (a model far from the sensor: the ring's LEDs
        # 80 deg off their design, whose images the dark-band check also reads as dark): the lit LEDs set the scale
        lit = gain[gain > 0]
        scale = float(np.median(lit)) if lit.size else 1.0
    return gain / scale


def model_gain_check(
    press: Press, leds: Sequence[Led], live: Sequence[int], measured: MeasuredGains | None = None
) -> tuple[list[str], np.ndarray | None]:
    """Without an undeformed capture: LEDs or LED groups aged (or brightened) on their own, against the LED model.

    Why: with ``--reference`` an aged LED is measured against the undeformed capture (:func:`led_gains`); without
    it, the twin's sphere press with its red group 10 % dimmer was solved without a word 4.8 deg off (0.50 as
    captured), the cube press 5.5 deg; rescaled by :func:`model_led_gains` 0.6-1.1 deg (benchmarks/RESULTS.md,
    s28-noref). The weak-LED check leaves out only LEDs off by 40 % (``WEAK_LED_GAIN``).

    Parameters
    ----------
    press : Press -- with ``reference`` (none: no check).
    leds : sequence of Led -- the solve's LED model, in the order of ``press.led_images``.
    live : sequence of int -- the LEDs (0-based) to judge: lit, not left out, not misplaced.
    measured : MeasuredGains or None -- :func:`led_check_measured`'s of this press and ``leds``: used when measured on
        ``live`` itself (the same samples, so the same numbers), else they are measured here.

    Returns
    -------
    notes : list of str -- one warning naming the press, the LEDs and their images, empty when none is off.
    gains : (L, 3) float64 or None -- each LED's gain (all channels alike) to rescale its images by
        (:func:`nlipscalib.core.capture.with_led_gains`), 1 for LEDs not judged; None when none is off.
    """
    live = [int(i) for i in live]
    if measured is not None and measured.live == tuple(live):
        relative = measured.relative
    else:
        relative = model_relative_gains(press, leds, live)
    if relative is None:
        return [], None
    found = model_led_gains(relative, tricolor_groups(len(press.leds))[live])
    if found is None:
        return [], None
    gains = np.ones((len(press.leds), 3))
    gains[live] = found[:, None]
    names = image_names(press)
    which = ", ".join(f"LED {i + 1} ({names[i]}) {gains[i, 0]:.2f}" for i in range(len(gains)) if gains[i, 0] != 1)
    return [
        f"{press.folder}: LEDs give other shares of the light the LED model expects than the rest, beyond the "
        f"model's own error: {which}: aged (dimmer with use) or replaced? The solve rescaled their images by "
        f"these gains (report.json led_gains); capture the undeformed dome and solve with --reference FOLDER, or "
        f"calibrate the LEDs (nlips calibrate-leds) and solve with --leds FILE"
    ], gains
