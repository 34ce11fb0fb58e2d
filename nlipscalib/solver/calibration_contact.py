"""The contact checks of an LED calibration's captures: where a capture shows a press rather than the undeformed
dome (from the fitted model's misfit), the line that refuses it, and the warnings when its contact is left out
(``allow_contact``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..core import masks, tolerances
from ..core.capture import Press
from ..core.leds import Leds

if TYPE_CHECKING:  # named in hints only: the functions import the indirect module where they use it
    from .indirect import IndirectModel


def contact_regions(presses: Sequence[Press], leds: Leds, models: Sequence[IndirectModel]) -> tuple[np.ndarray, ...]:
    """Per capture, (H, W) bool: where it shows a contact -- the connected regions of pixels that the fitted
    undeformed model (``leds`` and the capture's indirect term when on) misfits far beyond the images' noise
    (:func:`nlipscalib.solver.contact.contact_hits`, the solver's own classification of a press), each at least
    :data:`tolerances.CALIBRATION_CONTACT_FRACTION` of the gel. All False on a capture of the undeformed dome.

    Why from the fit: the capture holds no ground truth (a real sensor has none), and its LEDs are what the
    calibration finds; the robust loss keeps a dent from pulling them far, so the dent is what they misfit.
    Dilated by :data:`CONTACT_MARGIN_PX`: the dent's rim misfits just below the hit threshold.
    """
    from .contact import classify_contact, contact_hits

    out = []
    for p, m in zip(presses, list(models) or [None] * len(presses)):
        light = m.undeformed_light(p.camera.shape) if m is not None and m.enabled else None
        contact = classify_contact(p, leds, undeformed_light=light)
        # the LED model's own error counts as noise, as in fit_quality: without it a noise-free render's edge (its
        # noise the ADC step) misfit as a contact (80x60 bounce-free twin: 1.4 % of the gel; with it none)
        model_error = tolerances.CALIBRATION_MODEL_ERROR * np.nan_to_num(contact.level)
        contact = dataclasses.replace(contact, expected=np.hypot(contact.expected, model_error))
        labels, sizes = masks.components(contact_hits(contact))
        gel = int(np.isfinite(contact.misfit).sum())
        large = np.flatnonzero(sizes >= tolerances.CALIBRATION_CONTACT_FRACTION * gel) + 1
        region = np.isin(labels, large)
        out.append(masks.dilate(region, iterations=CONTACT_MARGIN_PX) & np.isfinite(contact.misfit))
    return tuple(out)


CONTACT_MARGIN_PX = 2
"""Pixels by which a contact found in a calibration capture is grown before it is left out (``allow_contact``):
its rim misfits less than the threshold of a hit yet still shows the dent."""


def contact_refusal(presses: Sequence[Press], regions: Sequence[np.ndarray]) -> str:
    """The one line that refuses captures showing a contact (``regions``: :func:`contact_regions`)."""
    found = [(p, r) for p, r in zip(presses, regions) if r.any()]
    p, region = found[0]
    gel = max(int(np.isfinite(p.reference.depth).sum()), 1)
    rows, cols = np.nonzero(region)
    more = f" (and {len(found) - 1} more of the captures)" if len(found) > 1 else ""
    return (
        f"{p.folder}: not a capture of the undeformed dome{more}: {100 * region.sum() / gel:.1f} % of the gel, around "
        f"pixel ({int(np.median(cols))}, {int(np.median(rows))}), differs from the fitted undeformed model far beyond "
        "the images' noise, as a press does; calibrate the LEDs on the undeformed dome (a session's reference/), or "
        "pass --allow-contact to fit without those pixels"
    )


def contact_notes(presses: Sequence[Press], pixels: Sequence[int]) -> list[str]:
    """The warnings for contacts left out of the fit (``pixels``: ``LedCalibration.contact_pixels``)."""
    notes = []
    for p, count in zip(presses, pixels):
        if count:
            gel = max(int(np.isfinite(p.reference.depth).sum()), 1)
            notes.append(
                f"{p.folder}: shows a contact (a press?): its {count} pixels ({100 * count / gel:.1f} % of the gel) "
                "were left out of the LED fit (--allow-contact); the rest of the gel was taken as undeformed"
            )
    return notes
