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
    (:func:`nlipscalib.solver.contact_verdict.contact_hits`, the solver's own classification of a press), each at least
    :data:`tolerances.CALIBRATION_CONTACT_FRACTION` of the gel. All False on a capture of the undeformed dome.

    Why from the fit: the capture holds no ground truth (a real sensor has none), and its LEDs are what the
    calibration finds; the robust loss keeps a dent from pulling them far, so the dent is what they misfit.
    Dilated by :data:`CONTACT_MARGIN_PX`: the dent's rim misfits just below the hit threshold.
    """
    from .contact import classify_contact
    from .contact_verdict import contact_hits

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


def contact_refusal(
    presses: Sequence[Press],
    regions: Sequence[np.ndarray],
    leds: Leds,
    albedo: Sequence[float],
    models: Sequence[IndirectModel] = (),
    start: Leds | None = None,
) -> str:
    """The one line that refuses captures showing a contact (``regions``: :func:`contact_regions`), or, when what no
    normal explains of the misfit lies in one LED's image (:func:`unexplained_shares`), that names that LED.

    Why two causes: a dent's misfit is its normals'; what a normal per pixel leaves of it spreads over the LEDs that
    light it (the twin's sphere and cube presses, the synthetic ones: its largest share among 12 LEDs 1.7-2.5x the
    fair 1/12). An LED far from its design, near the gel, is no point light there: its light misfits whatever the
    normal (the twin with every LED 4 mm / 35 deg off, seed 0: LED 1, 5.3 mm from the gel where the design's LEDs sit
    7.2-10.8 mm, 6.3x; a 3.6 mm disk LED 3.5-5.3 mm from the synthetic dome 8.5-9.5x; benchmarks/RESULTS.md,
    s28-ledfar). That capture was refused "as a press does": the user was sent to look for a press that was not there.

    ``leds``, ``albedo``: the fitted LEDs the regions were found with and the calibration's albedo; ``models``: the
    captures' indirect terms (as :func:`contact_regions`); ``start``: the LEDs the fit started from (the capture's,
    i.e. the design's on a real sensor), for how far the named LED moved from them.
    """
    found = [(i, p, r) for i, (p, r) in enumerate(zip(presses, regions)) if r.any()]
    index, p, region = found[0]
    gel = max(int(np.isfinite(p.reference.depth).sum()), 1)
    rows, cols = np.nonzero(region)
    more = f" (and {len(found) - 1} more of the captures)" if len(found) > 1 else ""
    where = (
        f"{100 * region.sum() / gel:.1f} % of the gel, around pixel ({int(np.median(cols))}, {int(np.median(rows))})"
    )
    model = list(models)[index] if len(models) > index else None
    cause = led_cause(p, region, leds, albedo, model, start)
    if cause is not None:
        return (
            f"{p.folder}: not calibrated{more}: {where}, differs from the fitted LED model far beyond the images' "
            f"noise, and {cause} and capture the undeformed dome again, or pass --allow-contact to fit without those "
            "pixels"
        )
    # what the check cannot tell from a dent: the model's own misfit where nothing pressed (LEDs far from their
    # design, the free reflectance held low by them: the twin 3 mm / 25 deg off, seeds 2-3, before s31-ledfar)
    return (
        f"{p.folder}: not a capture of the undeformed dome{more}: {where}, differs from the fitted undeformed model "
        "far beyond the images' noise, as a press does; calibrate the LEDs on the undeformed dome (a session's "
        f"reference/), or pass --allow-contact to fit without those pixels; {NOTHING_PRESSED}"
    )


NOTHING_PRESSED = (
    "if nothing touched the gel, the LED model misfits there (LEDs far from their design?): pass --allow-contact, and "
    "--coating-reflectance if the coating's is known, then check the LED file's warnings"
)
"""The refusal's advice for a capture of the undeformed dome that the check took for a press: it cannot tell a dent
from the LED model's own misfit, and a user who knows nothing pressed the gel must be told what to do."""


def led_cause(
    press: Press,
    region: np.ndarray,
    leds: Leds,
    albedo: Sequence[float],
    model: IndirectModel | None = None,
    start: Leds | None = None,
) -> str | None:
    """The words naming one LED as the cause of a capture's misfit ``region`` ("48 % of what no normal explains
    there (a press's dent would) is in LED 1's image: LED 1 sits ...; ... check LED 1's mounting against the
    design"), when its share of what no normal explains (:func:`unexplained_shares`) times the LED count reaches
    ``tolerances.CALIBRATION_ONE_LED_MISFIT``; None when the misfit is a press's (spread over the LEDs). The
    arguments are :func:`contact_refusal`'s for that capture."""
    shares = unexplained_shares(press, region, leds, albedo, model)
    k = int(np.argmax(shares))
    if shares[k] * len(shares) < tolerances.CALIBRATION_ONE_LED_MISFIT:
        return None
    said = f"{100 * shares[k]:.0f} % of what no normal explains there (a press's dent would) is in LED {k + 1}'s image"
    if dark := _dark_rows_of(press, leds, k):
        return f"{said}, {dark}"
    return (
        f"{said}: {_led_placement(press, leds, k, start)}; the point LED model does not describe an LED package that "
        f"near the gel: a sensor assembled far from its design? check LED {k + 1}'s mounting against the design"
    )


def _dark_rows_of(press: Press, leds: Leds, k: int) -> str | None:
    """Words naming LED ``k``'s (0-based) rows (or columns) at the dark frame's level where the fitted ``leds`` light
    them (:func:`.led_checks.dark_rows`), None when it has none.

    Why here, after the fit, and not before it as the solve does: before it the LEDs are the design's, and an LED far
    from its design ends its light where the design's would not (the synthetic ring: dark top rows in 2 of 12
    images, s28-rolling); the fitted LEDs light what the LEDs lit. The twin's undeformed capture with LED 5's top 60
    rows dark was refused naming LED 5's mounting (s29-darkrows)."""
    from ..core.repeated_frames import dark_cause, dark_span
    from .led_checks import dark_rows

    band = next((b for b in dark_rows(press, leds, range(len(leds))) if b.index == k), None)
    if band is None:
        return None
    return (
        f"whose {dark_span(band)} are dark (the dark frame's level, or a very dim LED, where the fitted LED lights "
        f"them): {dark_cause([band])}; keep each LED lit over the whole frame time (--flush 1 or more)"
    )


def unexplained_shares(
    press: Press, region: np.ndarray, leds: Leds, albedo: Sequence[float], model: IndirectModel | None = None
) -> np.ndarray:
    """Each LED's share of what a normal of each pixel's own leaves unexplained of a calibration capture's misfit
    region (the shading, the calibration's model, is linear in the normal where lit: per pixel a 3-unknown linear
    least squares, its solution scaled to a unit normal).

    Parameters
    ----------
    press : Press -- with ``reference``.
    region : (H, W) bool -- the region (:func:`contact_regions`).
    leds : sequence of Led, length L -- the fitted LEDs, camera frame, mm.
    albedo : (3,) float -- the calibration's uniform albedo per channel (its gauge).
    model : IndirectModel or None -- the capture's indirect term, taken from the images when on.

    Returns
    -------
    (L,) float -- sums to 1 (all 0 where the normals explain everything).

    Why a unit normal and the calibration's albedo, not a free brightness per pixel: where one LED's light is most of a
    pixel's, a brightness of its own absorbs that LED's misfit (a 3.6 mm disk LED 3.5 mm from the synthetic dome: 90 %
    of its misfit explained so, 78 % with a unit normal), or passes it on to the next LEDs' images.
    """
    from ..core.camera import depth_to_points
    from ..core.leds import led_shading

    points = depth_to_points(press.reference.depth[region].astype(np.float64), press.camera.rays[region])
    scale = np.asarray(albedo, dtype=np.float64)
    images = press.linear_led_images[:, region].astype(np.float64)  # (L, N, 3)
    if model is not None and model.enabled:
        images = images - scale * model.undeformed_light(press.camera.shape)[:, region]
    # s(e) - s(-e) per axis e is the shading's row for the normal (max(0, t) - max(0, -t) = t)
    axes = [np.broadcast_to(e, points.shape) for e in np.eye(3)]
    rows = np.stack([led_shading(points, e, leds) - led_shading(points, -e, leds) for e in axes], axis=-1)
    A = np.moveaxis(rows * scale[:, None], 1, 0).reshape(len(points), -1, 3)  # (N, 3L, 3)
    y = np.nan_to_num(np.moveaxis(images, 1, 0).reshape(len(points), -1))
    gram = np.einsum("nrk,nrj->nkj", A, A) + 1e-12 * np.eye(3)
    normal = np.linalg.solve(gram, np.einsum("nrk,nr->nk", A, y)[..., None])[..., 0]
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    left = (y - np.einsum("nrk,nk->nr", A, normal)).reshape(len(points), -1, 3)
    squared = (left**2).sum(axis=(0, 2))
    return squared / squared.sum() if squared.sum() > 0 else np.zeros(len(squared))


def _led_placement(press: Press, leds: Leds, k: int, start: Leds | None) -> str:
    """Where LED ``k`` (0-based) of ``leds`` sits: its distance to the capture's gel against the other LEDs', and
    how far it is from its place in ``start``."""
    from ..core.camera import depth_to_points

    valid = np.isfinite(press.reference.depth)
    gel = depth_to_points(press.reference.depth[valid].astype(np.float64), press.camera.rays[valid])
    near = [float(np.linalg.norm(gel - np.asarray(led.position), axis=1).min()) for led in leds]
    others = np.median([d for i, d in enumerate(near) if i != k]) if len(near) > 1 else float("nan")
    line = f"LED {k + 1} sits {near[k]:.1f} mm from the gel, the other LEDs {others:.1f} mm (median)"
    if start is not None and len(start) == len(leds):
        moved = float(np.linalg.norm(np.subtract(leds[k].position, start[k].position)))
        line += f", {moved:.1f} mm from its place in the capture's LEDs (the design's on a sensor)"
    return line


def contact_notes(presses: Sequence[Press], pixels: Sequence[int], causes: Sequence[str | None] = ()) -> list[str]:
    """The warnings for contacts left out of the fit (``pixels``: ``LedCalibration.contact_pixels``; ``causes``:
    its ``contact_causes``, :func:`led_cause` of each capture's region: an LED near the gel, not a press, named as
    the refusal without ``--allow-contact`` names it)."""
    notes = []
    causes = list(causes) or [None] * len(presses)
    for p, count, cause in zip(presses, pixels, causes):
        if count and cause is not None:
            gel = max(int(np.isfinite(p.reference.depth).sum()), 1)
            notes.append(
                f"{p.folder}: {count} pixels ({100 * count / gel:.1f} % of the gel) differ from the fitted LED model "
                f"far beyond the images' noise and were left out of the LED fit (--allow-contact): {cause}"
            )
        elif count:
            gel = max(int(np.isfinite(p.reference.depth).sum()), 1)
            notes.append(
                f"{p.folder}: shows a contact (a press?): its {count} pixels ({100 * count / gel:.1f} % of the gel) "
                "were left out of the LED fit (--allow-contact); the rest of the gel was taken as undeformed"
            )
    return notes
