"""``--roi auto``: the box around a press's contact (:func:`contact_box`), the misfits it leaves out along the
gel's edge, and the refusal of a press that shows no contact.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..core import masks, tolerances
from ..core.errors import CaptureError, NoContactError
from ..core.shell_words import shell_word
from .contact import ContactMap
from .contact_flank import grow_over_flank
from .contact_grid import edge_noise_gain
from .contact_verdict import contact_floor, contact_hits, no_contact

log = logging.getLogger(__name__)


EDGE_CONTACT_PX = 2
"""``--roi auto`` notes a contact whose misfitting pixels come within this many pixels of the image's border: its box
has no undeformed gel beyond it on that side."""


def _undeformed_advice(folder: str | Path, reference: str | Path | None) -> str:
    """What to do with a press that is the undeformed dome, fitted to where its reference came from.

    Why: the advice was always "use it as the reference", also to a folder that had its reference/ already (the
    press is then a second capture of the undeformed dome, best moved out of the folder) and to a press solved
    with an explicit --reference (which is that capture already)."""
    if reference is None:
        return f"if it is the undeformed dome, use it as the reference (--reference {folder}, or a folder's reference/)"
    press, reference = Path(folder), Path(reference)
    if reference.resolve() == (press.parent / "reference").resolve():
        return (
            f"if it is another capture of the undeformed dome, it needs no solve: move it out of {press.parent}, "
            f"whose reference/ is that capture"
        )
    return f"if it is another capture of the undeformed dome, it needs no solve: {reference} is that capture"


def auto_roi(contact: ContactMap, shape: tuple[int, int], **kwargs: Any) -> tuple[int, int, int, int]:
    """Bounding box (x0, y0, w, h) of the pixels whose images disagree with the undeformed dome: :func:`contact_box`
    (the same keywords) without its note, which goes to the log as a warning."""
    box, note = contact_box(contact, shape, **kwargs)
    if note:
        log.warning("%s: %s", kwargs.get("folder", ""), note)
    return box


def contact_box(
    contact: ContactMap,
    shape: tuple[int, int],
    margin: int = 8,
    min_size: int = 32,
    threshold: float = tolerances.CONTACT_MISFIT_FACTOR,
    min_component: float = 0.05,
    folder: str | Path = "",
    reference: str | Path | None = None,
    edge_model_error: Callable[[np.ndarray], np.ndarray] | None = None,
    flank: bool = False,
) -> tuple[tuple[int, int, int, int], str]:
    """Bounding box (x0, y0, w, h) of the pixels whose images disagree with the undeformed dome, and a note.

    ``folder`` is the press's, ``reference`` the folder of the undeformed dome's capture it was compared with (None:
    not known), both named in the refusal of a press without contact (:func:`_undeformed_advice`).

    Candidates are the pixels :func:`.contact_verdict.contact_hits` calls hit (with ``threshold``); of their connected
    components only those at least ``min_component`` times the largest are kept, so isolated misfits (cast
    shadows far from the dent, silhouette aliasing, hot pixels) do not stretch the box.

    When that box would cover most of the gel (:data:`tolerances.ROI_LARGE_FRACTION` of the gel's bounding
    box), the components along the gel's edge are left out if a large one remains inside
    (:func:`_inner_regions`): an unmodelled effect that grows toward the view's edge -- vignetting, the view
    through the gel at grazing angles, a glossy coat -- misfits there, away from the dent. Seen on the
    ``nlipstac_realistic`` twin (160x120): the four corners misfit as much as the dent and the box was the
    whole frame; without them it is the dent's. A dent that reaches the edge keeps its edge part (parts
    within ``2 margin`` pixels of the inner one join it).

    Where the images fit the undeformed model to noise, components that peak below what noise reaches
    (:func:`_noise_like`) are left out first: a tiny or shallow contact's hits are fewer than the weak ones noise
    makes along the view's edge, and ``min_component`` alone kept those and boxed the whole gel.
    ``edge_model_error``, given the (H, W) bool pixels left out along the edge, returns the misfit (H, W, image
    units) the undeformed model is known to leave there (:func:`.point_led_error.point_led_misfit`); pixels within
    ``threshold`` times it (and their floor, in quadrature: :func:`_beyond`) are that model's error, and unless the
    others hold :data:`tolerances.ROI_MIN_INNER_FRACTION` of the gel they are left out without a note (the box is the
    same either way). ``flank``: the box grows over the contact's flank (:func:`.contact_flank.grow_over_flank`; ``--roi
    auto``'s box, not the outer loop's dent focus, whose wide margin holds it).

    Returns
    -------
    box : (x0, y0, w, h) pixels
    note : str -- empty, or what was left out, or a warning that the box still covers most of the gel.
    """
    valid = np.isfinite(contact.misfit)
    if not valid.any():
        raise CaptureError(f"{folder}: no pixel sees the gel; nothing to reconstruct")
    hit = contact_hits(contact, threshold)
    _refuse_without_contact(contact, hit, edge_model_error, folder, reference)
    region, note = _contact_region(contact, hit, margin, min_component, threshold, edge_model_error, folder)
    rows, cols = np.nonzero(region)
    box = _padded_box(contact, region, (rows, cols), shape, margin, min_size, flank)
    return box, note or _spread_note(region, valid) or _edge_note((rows, cols), shape)


def _refuse_without_contact(
    contact: ContactMap,
    hit: np.ndarray,
    edge_model_error: Callable[[np.ndarray], np.ndarray] | None,
    folder: str | Path,
    reference: str | Path | None,
) -> None:
    """Raise :class:`NoContactError` (images within noise of the undeformed dome) or :class:`CaptureError` (the LED
    model does not fit) where :func:`.contact_verdict.no_contact` finds no contact; :func:`contact_box`'s
    arguments."""
    if why := no_contact(contact, hit, edge_model_error):
        reason, within_noise = why
        # the command named: `nlips calibrate` and `nlips demo` print this too, and take no --roi
        press = shell_word(folder) if folder else "PRESS"
        solve_anyway = f"`nlips solve {press} --roi X0 Y0 W H`, or without --roi, solves it anyway"
        if within_noise:
            # what to do, as well as what was found: a press too light to show, or the undeformed dome's capture
            raise NoContactError(
                f"{folder}: --roi auto found no contact ({reason}); nothing solved: the surface is the reference's. "
                f"If it was pressed, press deeper (or with a larger object) and capture it again; "
                f"{_undeformed_advice(folder, reference)} ({solve_anyway})"
            )
        raise CaptureError(f"{folder}: --roi auto found no contact ({reason}); nothing solved ({solve_anyway})")


def _contact_region(
    contact: ContactMap,
    hit: np.ndarray,
    margin: int,
    min_component: float,
    threshold: float,
    edge_model_error: Callable[[np.ndarray], np.ndarray] | None,
    folder: str | Path,
) -> tuple[np.ndarray, str]:
    """(region, note): the (H, W) bool pixels :func:`contact_box` boxes -- the components of ``hit`` that are not
    noise-like and at least ``min_component`` times the largest, without those along the gel's edge where they
    spread the box over most of the gel and a large one remains inside -- and the note on what was left out (empty:
    nothing, or only the point-LED model's known error). Arguments as :func:`contact_box`'s."""
    valid = np.isfinite(contact.misfit)
    labels, sizes = masks.components(hit)
    sizes = np.where(_noise_like(contact, labels, len(sizes), 2 * margin), 0, sizes)
    keep = np.flatnonzero(sizes >= min_component * sizes.max()) + 1
    region = np.isin(labels, keep)
    if _box_fraction(region, valid) < tolerances.ROI_LARGE_FRACTION:
        return region, ""
    inner = _inner_regions(labels, sizes, valid, 2 * margin, min_component)
    left = region & ~inner if inner is not None else None
    if left is None or not left.any():
        return region, ""
    return inner, _left_out_note(contact, left, threshold, edge_model_error, folder)


def _left_out_note(
    contact: ContactMap,
    left: np.ndarray,
    threshold: float,
    edge_model_error: Callable[[np.ndarray], np.ndarray] | None,
    folder: str | Path,
) -> str:
    """The note on the misfitting pixels ``left`` ((H, W) bool) left out along the gel's edge; empty (and a line in
    the log) where all that misfits beyond the point-LED model's known error is specks. Arguments as
    :func:`contact_box`'s."""
    valid = np.isfinite(contact.misfit)
    unexplained = left if edge_model_error is None else left & _beyond(contact, edge_model_error(left), threshold)
    # specks beyond it (the capsule's image corners: 6-118 px each, an effect not modelled here) are not
    # worth a warning; an effect that is makes a patch as large as an inner component the box counts
    if _largest_patch(unexplained) >= (
        1 if edge_model_error is None else tolerances.ROI_MIN_INNER_FRACTION * valid.sum()
    ):
        return (
            f"--roi auto left out {int(left.sum())} misfitting pixels along the gel's edge "
            f"({int(unexplained.sum())} beyond the point-LED model's known error; an effect the undeformed "
            f"model does not have there, e.g. vignetting or the view at grazing angles); `nlips solve "
            f"{folder or 'PRESS'} --roi X0 Y0 W H` solves them too"
        )
    log.info(
        "%s: --roi auto left out %d pixels along the gel's edge that misfit by what the point-LED model "
        "misses of LEDs %.1f mm across",
        folder,
        int(left.sum()),
        2 * tolerances.LED_EMITTER_RADIUS_MM,
    )
    return ""


def _padded_box(
    contact: ContactMap,
    region: np.ndarray,
    pixels: tuple[np.ndarray, np.ndarray],
    shape: tuple[int, int],
    margin: int,
    min_size: int,
    flank: bool,
) -> tuple[int, int, int, int]:
    """(x0, y0, w, h): the bounding box of ``region`` (its ``pixels``, rows and columns) plus ``margin``, grown over
    the contact's flank where ``flank``, at least ``min_size`` on each side, within the image of ``shape`` (H, W)."""
    rows, cols = pixels
    H, W = shape
    y0, y1 = max(rows.min() - margin, 0), min(rows.max() + 1 + margin, H)
    x0, x1 = max(cols.min() - margin, 0), min(cols.max() + 1 + margin, W)
    if flank:
        x0, y0, x1, y1 = grow_over_flank(contact, region, (x0, y0, x1, y1), margin)
    if x1 - x0 < min_size:
        c = (x0 + x1) // 2
        x0, x1 = max(c - min_size // 2, 0), min(c + min_size // 2, W)
    if y1 - y0 < min_size:
        c = (y0 + y1) // 2
        y0, y1 = max(c - min_size // 2, 0), min(c + min_size // 2, H)
    return (int(x0), int(y0), int(x1 - x0), int(y1 - y0))


def _spread_note(region: np.ndarray, valid: np.ndarray) -> str:
    """The warning where the boxed ``region`` still spans most of the gel's (``valid``) extent; else empty."""
    # judged on the misfit itself, not on the box's margin and minimum size: at 96x72 those alone make a
    # small dent's box cover half the gel, and the warning is about images that do not fit the model
    spread = _box_fraction(region, valid)
    if spread < tolerances.ROI_LARGE_FRACTION:
        return ""
    return (
        f"--roi auto: the pixels whose images differ from the undeformed model span {100 * spread:.0f} % of "
        f"the gel's extent (its bounding box): a press that large, or LEDs / reference that do not fit this "
        f"sensor (try nlips calibrate-leds or --reference); `nlips solve PRESS --roi X0 Y0 W H` chooses the region"
    )


def _edge_note(pixels: tuple[np.ndarray, np.ndarray], shape: tuple[int, int]) -> str:
    """The note where the contact's ``pixels`` (rows, columns) come within :data:`EDGE_CONTACT_PX` of the border of
    the image of ``shape`` (H, W); else empty."""
    # the contact itself at the border, not its box's margin: at 64x48-96x72 (tests, the demo) every contact lies
    # within the 8-pixel margin of some border, and the note fired on presses whose box holds undeformed gel
    # all round (the lead, s27)
    rows, cols = pixels
    H, W = shape
    edge = EDGE_CONTACT_PX
    if not (min(rows.min(), cols.min()) < edge or rows.max() + edge >= H or cols.max() + edge >= W):
        return ""
    # the twin at polar 40-70 deg, 320x240: 0.1-0.4 deg more contact AAE than the whole gel (s27-unusual)
    return (
        "--roi auto: the contact reaches the image's edge, where its box has no undeformed gel around it on that "
        "side: its normals near the edge are less reliable than a whole-gel solve's (`nlips solve PRESS` without "
        "--roi)"
    )


def _noise_like(contact: ContactMap, labels: np.ndarray, count: int, join: int) -> np.ndarray:
    """(count,) bool -- the hit components (``labels`` 1..count of :func:`.contact_verdict.contact_hits`) that noise
    alone could make: peak misfit below :data:`tolerances.NO_CONTACT_PEAK` times its floor, and farther than ``join``
    pixels from any component above it (the weaker rim of a dent joins its core). None is noise-like where the images
    fit the undeformed model only to model error (:data:`tolerances.MODEL_MISFIT_FLOOR`): a dent's peak there
    stands out by less.

    Why: the twin at 320x240 has 3-4x-floor hits in the image's corners; a 1 mm sphere's contact (peak 38, 187
    hits) or a 0.05 mm-deep press's (7.4, 110 hits) was smaller than them, so the box was the whole gel
    (benchmarks/RESULTS.md, s27-unusual)."""
    weak = np.zeros(count, bool)
    if count == 0 or contact_floor(contact) >= tolerances.MODEL_MISFIT_FLOOR:
        return weak
    on = labels > 0
    floor = np.maximum(contact.expected[on], contact.median_misfit)
    peaks = np.zeros(count + 1)
    np.maximum.at(peaks, labels[on], contact.misfit[on] / np.maximum(floor, 1e-9))
    strong = peaks >= tolerances.NO_CONTACT_PEAK
    strong[0] = False
    if not strong.any():
        return weak
    near = masks.dilate(strong[labels], iterations=join)
    weak = ~strong[1:]
    weak[np.unique(labels[near & on]) - 1] = False
    return weak


def _largest_patch(mask: np.ndarray) -> int:
    """Pixels in the largest connected patch of ``mask`` (H, W) bool (0 when empty)."""
    if not mask.any():
        return 0
    return int(masks.components(mask)[1].max())


def _beyond(contact: ContactMap, model_error: np.ndarray, threshold: float, blur_px: float = 1.5) -> np.ndarray:
    """(H, W) bool -- pixels whose misfit exceeds ``threshold`` times their floor and a known model error
    ``model_error`` (H, W) added in quadrature (independent errors). The floor is
    :func:`.contact_verdict.contact_hits`'s plus, in quadrature, the noise the smoothing leaves beyond the noise-only
    misfit where it averages fewer pixels (:func:`.contact_grid.edge_noise_gain`, on the pixel grid with
    :func:`.contact.classify_contact`'s ``blur_px``). Why: the capsule's undeformed capture misfits 4.2-5.7 times the
    plain floor in the image's corners (s27-shapes2)."""
    gel = np.isfinite(contact.misfit)
    floor = np.maximum(contact.expected, contact.median_misfit)
    extra_noise = contact.expected * np.sqrt(np.maximum(edge_noise_gain(gel, blur_px) ** 2 - 1.0, 0.0))
    return np.nan_to_num(contact.misfit) > threshold * np.sqrt(floor**2 + extra_noise**2 + model_error**2)


def _box_fraction(region: np.ndarray, valid: np.ndarray) -> float:
    """Area of ``region``'s bounding box over that of the gel's (``valid``), both (H, W) bool."""

    def area(mask: np.ndarray):
        # from the rows and columns that hold a pixel: 50x faster than the pixels' coordinates (2.4 ms at 640x480)
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        return 0 if rows.size == 0 else (rows[-1] - rows[0] + 1) * (cols[-1] - cols[0] + 1)

    return area(region) / max(area(valid), 1)


def _inner_regions(
    labels: np.ndarray, sizes: np.ndarray, valid: np.ndarray, join: int, min_component: float
) -> np.ndarray | None:
    """(H, W) bool -- the misfit components that do not touch the gel's edge (the gel's silhouette or the image
    border), at least ``min_component`` times the largest of them and :data:`tolerances.ROI_MIN_INNER_FRACTION`
    of the gel, plus the edge components that come within ``join`` pixels of them; None when no such inner
    component exists (then every component is kept: a dent may lie at the edge)."""
    edge = valid & ~masks.erode(valid)
    edge_labels = np.unique(labels[edge])
    inner = np.setdiff1d(np.arange(1, len(sizes) + 1), edge_labels)
    inner = inner[sizes[inner - 1] >= tolerances.ROI_MIN_INNER_FRACTION * valid.sum()]
    if inner.size == 0:
        return None
    inner = inner[sizes[inner - 1] >= min_component * sizes[inner - 1].max()]
    region = np.isin(labels, inner)
    near = masks.dilate(region, iterations=join)
    touching = np.setdiff1d(np.unique(labels[near & (labels > 0)]), inner)
    return region | np.isin(labels, touching)
