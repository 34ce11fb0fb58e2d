"""What a press's contact map (:class:`.contact.ContactMap`) says: the pixels in or at the contact, the
misfit's floor and peak, and whether the press shows a contact at all (and why not).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..core import masks, tolerances
from .contact import ContactMap


def contact_hits(contact: ContactMap, threshold: float = tolerances.CONTACT_MISFIT_FACTOR) -> np.ndarray:
    """Pixels in or at the contact: misfit above ``threshold`` times the larger of its noise-only value and the
    misfit's median over the gel (the undeformed model is never exact on a real sensor).

    Parameters
    ----------
    contact : ContactMap
    threshold : float -- see :data:`nlipscalib.core.tolerances.CONTACT_MISFIT_FACTOR`.

    Returns
    -------
    (H, W) bool -- all False when no pixel sees the gel.
    """
    mis = contact.misfit
    valid = np.isfinite(mis)
    if not valid.any():
        return valid
    floor = np.maximum(contact.expected, contact.median_misfit)
    return valid & (mis > threshold * np.maximum(floor, 1e-9))  # NaN compares False, off the gel anyway


def contact_floor(contact: ContactMap) -> float:
    """The misfit's median over the gel in units of its noise-only value's median: about 1-2 where the images fit
    the undeformed model to noise, more where the LED model is off (0 when no pixel sees the gel)."""
    valid = np.isfinite(contact.misfit)
    if not valid.any():
        return 0.0
    return contact.median_misfit / max(float(np.median(contact.expected[valid])), 1e-12)


def contact_peak(contact: ContactMap) -> float:
    """The largest misfit over its floor (the floor of :func:`contact_hits`) on the gel; 0 when no pixel sees it.
    A contact's peak is far above :data:`nlipscalib.core.tolerances.NO_CONTACT_PEAK`, noise's below. Kept on the
    map (:attr:`.contact.ContactMap.peak`): the auto ROI and the dent's focus both ask (2-3 ms each at 640x480)."""
    return contact.peak


def no_contact(
    contact: ContactMap,
    hit: np.ndarray | None = None,
    model_error: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[str, bool] | None:
    """Why the press shows no contact, and whether its images match the undeformed dome within noise; None when it
    shows one.

    Where the images fit the model to noise, a contact's peak misfit is far above
    :data:`~nlipscalib.core.tolerances.NO_CONTACT_PEAK` times its floor and noise's below, or, where the LEDs see
    the dent from a narrow cone (a faint dent), its hits make a patch of a dent's size away from the gel's edge
    (:func:`_inner_dent`), which noise's scattered hits do not. Where they fit it only to
    model error (the floor :data:`~nlipscalib.core.tolerances.MODEL_MISFIT_FLOOR` times the noise or more: LEDs
    off their design power or place), a plain dent stands out by less, so only a press without a single hit
    (:func:`contact_hits`) has none, and the remedy is an LED model that fits.

    Parameters
    ----------
    contact : ContactMap
    hit : (H, W) bool or None -- :func:`contact_hits` of ``contact`` when at hand.
    model_error : as :func:`.contact_roi.contact_box`'s ``edge_model_error``
        (:func:`.point_led_error.point_led_misfit`), or None -- asked of the whole gel only when the floor says the LEDs
        do not fit and no pixel is hit: a floor that the point-LED model's known error explains (the ``flat`` design
        with its exact LEDs: 3.9 times the noise, 1.01 times hypot(noise, that error); s27-shapes2) is then "within
        noise", not "the LED model does not fit". And of the pixels that reach NO_CONTACT_PEAK times the floor when no
        patch says "dent": the peak is then over the floor and that error together (:func:`_peak_beyond_model_error`;
        the ``capsule``'s image corners, s28-capsule).

    Returns
    -------
    (reason, within_noise) or None -- ``reason`` is one clause with the numbers; ``within_noise`` False says the
        images do not fit the LED model (the press may well have a contact).
    """
    floor = contact_floor(contact)
    hit = contact_hits(contact) if hit is None else hit
    if floor < tolerances.MODEL_MISFIT_FLOOR:
        return _no_contact_within_noise(contact, hit, model_error)
    if hit.any():
        return None
    return _no_contact_beyond_noise(contact, floor, model_error)


def _no_contact_within_noise(
    contact: ContactMap, hit: np.ndarray, model_error: Callable[[np.ndarray], np.ndarray] | None
) -> tuple[str, bool] | None:
    """:func:`no_contact` where the images fit the undeformed model to noise: no peak and no inner patch of a
    dent's size says "contact"."""
    peak = contact_peak(contact)
    within = f"within noise: the strongest misfit is {peak:.1f} times its floor"
    if peak >= tolerances.NO_CONTACT_PEAK and model_error is not None:
        # the point-LED model's own error can reach it (the capsule's image corners, s28-capsule): the peak
        # over the floor and that error together decides
        peak = _peak_beyond_model_error(contact, model_error)
        within = f"within noise and the point-LED model's known error: the strongest misfit is {peak:.1f} times both"
    if peak >= tolerances.NO_CONTACT_PEAK or _inner_dent(hit, np.isfinite(contact.misfit)):
        return None
    return (
        f"images match the undeformed dome {within}, a contact's above {tolerances.NO_CONTACT_PEAK:g}, and no "
        f"patch of misfit away from the gel's edge is a dent's size ({100 * tolerances.NO_CONTACT_PATCH:g} % of "
        f"the gel)",
        True,
    )


def _no_contact_beyond_noise(
    contact: ContactMap, floor: float, model_error: Callable[[np.ndarray], np.ndarray] | None
) -> tuple[str, bool]:
    """:func:`no_contact` where the images fit the undeformed model only to more than noise (``floor``, of
    :func:`contact_floor`) and no pixel is hit: within the point-LED model's known error, or an LED model that does
    not fit."""
    if model_error is not None:
        gel = np.isfinite(contact.misfit)
        known = np.hypot(contact.expected[gel], model_error(gel)[gel])
        explained = contact.median_misfit / max(float(np.median(known)), 1e-12)
        if explained < tolerances.MODEL_MISFIT_FLOOR:
            return (
                f"images match the undeformed dome within noise and the point-LED model's known error (the misfit's "
                f"median is {explained:.1f} times theirs, {floor:.1f} times the noise alone), and no pixel misfits by "
                f"{tolerances.CONTACT_MISFIT_FACTOR:g} times more",
                True,
            )
    return (
        f"the images differ from the undeformed model all over the gel, {floor:.0f} times the noise, and no pixel "
        f"by {tolerances.CONTACT_MISFIT_FACTOR:g} times more: the LED model does not fit this sensor; calibrate the "
        f"LEDs on its undeformed capture (nlips calibrate-leds REF --out leds.json) and solve with --leds leds.json, "
        f"or solve against that capture (--reference REF)",
        False,
    )


def _peak_beyond_model_error(contact: ContactMap, model_error: Callable[[np.ndarray], np.ndarray]) -> float:
    """:func:`contact_peak` with the model's known error ``model_error`` (:func:`.point_led_error.point_led_misfit`)
    added to the floor in quadrature (independent errors), asked only of the pixels at or above
    :data:`~nlipscalib.core.tolerances.NO_CONTACT_PEAK` times the plain floor (no other can reach it), and of the
    :data:`_PEAK_FIRST` strongest of those first: when one of them still reaches it (a dent), that value is
    returned, a lower bound of the peak that settles the question without asking about the rest.

    Why: the ``capsule`` design's wall in the image corners comes within 4.4 mm of a 3.6 mm LED, where the point
    model misses 3-4 % of that LED's light, 3-5 times the floor of a 16-spp capture: its undeformed captures
    peaked at 8.0-10.1 there and 7 of 8 were solved as presses (benchmarks/RESULTS.md, s28-capsule)."""
    mis = np.nan_to_num(contact.misfit)
    floor = np.maximum(contact.expected, contact.median_misfit)
    strong = np.isfinite(contact.misfit) & (mis >= tolerances.NO_CONTACT_PEAK * floor)
    index = np.flatnonzero(strong)
    # strongest first, sorting only those (the whole frame's argsort: 0.1 s at 640x480)
    order = index[np.argsort(mis.flat[index] / np.maximum(floor.flat[index], 1e-12))[::-1]]
    peak = 0.0
    for part in (order[:_PEAK_FIRST], order[_PEAK_FIRST:]):
        if part.size == 0:
            break
        asked = np.zeros(strong.shape, bool)
        asked.flat[part] = True
        known = np.hypot(floor.flat[part], model_error(asked).flat[part])
        peak = max(peak, float((mis.flat[part] / np.maximum(known, 1e-12)).max()))
        if peak >= tolerances.NO_CONTACT_PEAK:
            break
    return peak


_PEAK_FIRST = 64
"""Strongest pixels :func:`_peak_beyond_model_error` asks about first (~5 ms with 12 LEDs; all of a dent's)."""


def _inner_dent(hit: np.ndarray, valid: np.ndarray) -> bool:
    """Whether a connected patch of ``hit`` (H, W) bool that does not touch the gel's edge (``valid``'s silhouette
    or the image border) holds :data:`~nlipscalib.core.tolerances.NO_CONTACT_PATCH` of the gel: a dent,
    however faintly it stands out.

    Why, besides the peak: where the LEDs light the dent from a narrow cone of directions (the ``capsule``
    design's apex, 22 mm above its 6.5 mm LED ring) a plain dent misfits by little per pixel but over thousands of
    them: at 320x240 / 8 spp against its undeformed capture the 1 mm cube peaked at 5.4 and a 5 mm cylinder at 4.5
    times the floor, refused as "no contact"; their patches held 3.1 and 0.65 % of the gel, while noise's (a second
    undeformed capture) held at most 10 pixels, model error's (the design LEDs) 48 inside the edge and 600-640
    along it (the capsule's and the default twin's undeformed captures as presses; benchmarks/RESULTS.md,
    s27-shapesfa)."""
    if not hit.any():
        return False
    labels, sizes = masks.components(hit)
    edge = valid & ~masks.erode(valid)
    inner = np.setdiff1d(np.arange(1, len(sizes) + 1), np.unique(labels[edge]))
    return bool((sizes[inner - 1] >= tolerances.NO_CONTACT_PATCH * valid.sum()).any())
