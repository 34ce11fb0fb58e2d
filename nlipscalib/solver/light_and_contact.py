"""What a press's solve knows before NLiPs runs: the indirect term of the image model fitted (on the undeformed
dome's capture, or on the press itself away from its contact, fitted again once the contact is known) and the
contact classification against the undeformed model with that term (:func:`light_and_contact`), with the keys
that let a later press or process reuse the undeformed capture's fit and blurred images."""

from __future__ import annotations

import dataclasses
import functools
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

import numpy as np

from ..core import diskcache, tolerances
from ..core.capture import Press, unusable_digest
from ..core.errors import ShapeError
from ..progress import PRESS_DETAIL
from . import reuse
from .contact import ContactMap, classify_contact, prepare_press_side
from .image_stats import led_levels
from .indirect import IndirectModel, design_of, fit_indirect, fit_patch_share, reference_shading, term_key
from .press_checks import check_undeformed
from .roi import box_mask, contact_pixels

if TYPE_CHECKING:  # named in hints only
    from ..core.leds import Leds

log = logging.getLogger(__name__)


@dataclasses.dataclass
class _Light:
    """What a solve knows before NLiPs runs: the indirect term, the contact classification, the reference
    surface's direct shading, and the seconds each took."""

    model: object
    """IndirectModel or None (a fixed light, or no reference surface)."""
    cmap: ContactMap | None
    """The contact classification (None without a reference surface)."""
    shading: reuse.Deferred | None
    """The reference surface's direct shading (:func:`reference_shading`, deferred), or None."""
    indirect_seconds: float
    """The term's fits."""
    contact_seconds: float
    """The contact classifications."""


@dataclasses.dataclass(frozen=True, eq=False)
class Sources:
    """What the indirect term's fit and the contact classification read of a solve's arguments (the same for
    both: :func:`light_and_contact`, :func:`_indirect_fitter`)."""

    press: Press
    leds: Leds
    """The LEDs the solve uses (``solve_press``'s ``leds`` or the press's; its disks' centres and axes with
    ``radius``)."""
    ref_capture: Press | None
    """The undeformed dome's capture to fit the term on, or None (the press itself, away from its contact)."""
    fixed_light: np.ndarray | None
    """(L, H, W, 3) float32 -- a light to subtract as is (no term fitted), or None."""
    explicit_roi: tuple[int, int, int, int] | None
    """(x0, y0, w, h) pixels of an explicit ROI (the press's own fit leaves it out), or None."""
    interreflection: str
    """The term's mode: "auto", "on" or "off"."""
    bounces: int
    """Diffuse bounces in the term (1 or 2)."""
    radius: float = 0.0
    """mm -- the LEDs emit from disks of this radius (the solve's ``--led-model disks``): the reference surface's
    shading (the fit's, the contact map's, the outer loop's) and the term are the disks'
    (:func:`.indirect.term_shading`), and their keys name it (:func:`.indirect.term_key`); 0: point LEDs."""


def split_indirect(press: Press, indirect: np.ndarray | Press | None) -> tuple[Press | None, np.ndarray | None]:
    """(reference capture or None, fixed light array or None) from ``solve_press``'s ``indirect``."""
    if indirect is None:
        return None, None
    if isinstance(indirect, Press):
        check_undeformed(press, indirect)
        return indirect, None
    light = np.asarray(indirect, np.float32)
    if light.shape != press.led_images.shape:
        raise ShapeError(f"indirect light {light.shape} must match the LED images {press.led_images.shape}")
    return None, light


def light_and_contact(sources: Sources, dead_level: float) -> _Light:
    """Fit the indirect term, then classify the contact against the undeformed model with it (when the press
    stands in for the undeformed capture: a rough fit finds the contact, the term is fitted again without it
    and the classification redone). ``dead_level``: ``SolverOptions.dead_led_level``, the classification's too."""
    press, leds, ref_capture, fixed_light = sources.press, sources.leds, sources.ref_capture, sources.fixed_light
    prior = press.reference.depth if press.reference is not None else None
    t0 = time.perf_counter()
    # the reference surface's direct shading, computed once: the fit, the contact and the outer loop share it
    # (and the next press of the same sensor: solver.reuse). Deferred: when they all find their own results
    # kept (a warm process), it is only named in their keys, and the 88 MB (640x480) array is never loaded
    shading = None
    if prior is not None:
        shading = reference_shading(press.camera, leds, prior, press.reference.normals, True, sources.radius)
    fit = _indirect_fitter(sources, shading)
    cache = fit.contact_cache if fit else {}
    with ThreadPoolExecutor(1, "contact-press-side") as pool:  # left (joined) before anything else, on an error too
        side = None
        if fit is not None:  # a term to fit, so a reference surface to classify against
            # the press's side of the contact classification (its images' block means, blur and noise; ~0.08 s of
            # CPU at 640x480) does not depend on the term: made on the second core while the term is fitted
            # made once here, not by both threads (the fit's inputs and the contact's press side each ask for the
            # LED levels on the gel; reuse.reused keeps them, but two threads asking at once both computed them)
            led_levels(press.linear_led_images, np.isfinite(prior))
            side = pool.submit(prepare_press_side, press, cache, dead_level=dead_level)
        model = fit.first() if fit is not None else None
        if side is not None:
            side.result()  # its error (no LED lit) is raised here
    t_indirect = time.perf_counter() - t0  # the fit, and the press's side of the classification beside it

    t0 = time.perf_counter()
    cmap, refit = None, 0.0
    if press.reference is not None:
        cmap = _contact(press, leds, ref_capture, fixed_light, model, shading, dead_level, cache)
        if fit is not None and fit.refits and model.enabled:
            # the press stands in for the undeformed capture: fit again without its contact
            t1 = time.perf_counter()
            model = fit.again(exclude=contact_pixels(cmap))
            refit = time.perf_counter() - t1
            cmap = _contact(press, leds, None, None, model, shading, dead_level, fit.contact_cache)
    t_contact = time.perf_counter() - t0 - refit
    return _Light(model, cmap, shading, t_indirect + refit, t_contact)


@dataclasses.dataclass
class _IndirectFitter:
    """How a solve fits its indirect term: once on the undeformed capture (the sensor's fit, reused by
    later presses), or on the press itself, where the first fit only finds the contact (``refits``) and
    :meth:`again` fits without it."""

    first: object
    """() -> IndirectModel: the first fit."""
    again: object
    """(exclude=...) -> IndirectModel: the fit again, leaving out ``exclude`` (the press's own fit)."""
    refits: bool
    """Whether the contact found with the first fit should be left out of a second one (set by :attr:`first` when
    an explicit box leaves too little of the gel to fit on: :func:`_box_leaves_fit`)."""
    contact_cache: dict = dataclasses.field(default_factory=dict)
    """The press's side of the contact classification, shared by the classifications of one solve."""


def _indirect_fitter(sources: Sources, shading: reuse.Deferred | None) -> _IndirectFitter | None:
    """The :class:`_IndirectFitter` of a solve; None when no term is fitted (a fixed light, no reference)."""
    press, leds, ref_capture, explicit_roi = sources.press, sources.leds, sources.ref_capture, sources.explicit_roi
    interreflection, bounces = sources.interreflection, sources.bounces
    if sources.fixed_light is not None or press.reference is None:
        return None
    H, W = press.camera.shape
    source = ref_capture if ref_capture is not None else press
    box = box_mask(explicit_roi, (H, W)) if ref_capture is None and explicit_roi is not None else None
    cache = {}
    fit = functools.partial(
        fit_indirect,
        source,
        leds,
        mode=interreflection,
        bounces=bounces,
        shading=shading if source is press else None,
        cache=cache,
        radius=sources.radius,
    )
    if ref_capture is not None:  # the undeformed capture's fit is the sensor's: reused by later presses

        def first():
            model = reuse.reused(
                "fit",
                (capture_key(ref_capture), term_key(leds, sources.radius), interreflection, bounces),
                lambda: fit(exclude=None, iterations=3),
                persist=True,
            )
            reuse.freeze(model.off_view, model.fitted_light)
            return model

    else:

        def first():
            # the press stands in for the undeformed capture: its fit leaves out the user's box when enough of the
            # gel is left outside it; else (no box, or one over most of the gel) a first fit only finds the contact
            # and the fit is made again without it (``again``)
            if box is not None and not _box_leaves_fit(
                press, leds, box, interreflection, shading, cache, sources.radius
            ):
                fitter.refits = True
            return fit(exclude=None if fitter.refits else box, iterations=1 if fitter.refits else 3)

    def again(exclude: np.ndarray) -> IndirectModel:
        # on from the rough fit's kappa and light (warm): 2 alternations land as near the fixed point as 3 from
        # kappa = 0 (kappa within 1e-6 of it on the twin's sphere, cube and coin presses, as close as a 4th
        # alternation moves it), one kappa search and gather fewer
        return fit(exclude=exclude, iterations=REFIT_ALTERNATIONS, warm=True)

    fitter = _IndirectFitter(first=first, again=again, refits=ref_capture is None and box is None)
    return fitter


def _box_leaves_fit(
    press: Press,
    leds: Leds,
    box: np.ndarray,
    mode: str,
    shading: reuse.Deferred | None,
    cache: dict,
    radius: float = 0.0,
) -> bool:
    """Whether the press's own indirect fit can leave out the explicit ROI ``box`` ((H, W) bool): at least
    ``tolerances.INDIRECT_FIT_MIN_SHARE`` of the patches it fits on over the whole gel lie outside it (a box
    over the whole frame leaves none, a thin ring fits the term low). ``cache``: the fit's, filled here;
    ``radius``: the LEDs' disk radius, mm (0: points)."""
    if mode == "off":  # nothing is fitted
        return True
    share = fit_patch_share(press, leds, box, shading=shading, cache=cache, radius=radius)
    if share >= tolerances.INDIRECT_FIT_MIN_SHARE:
        return True
    log.info(
        "%s: the --roi box leaves %.0f %% of the gel's patches outside it (under %.0f %%): the interreflection term "
        "is fitted on the whole gel away from the contact found, as without --roi",
        press.folder,
        100 * share,
        100 * tolerances.INDIRECT_FIT_MIN_SHARE,
        extra=PRESS_DETAIL,
    )
    return False


REFIT_ALTERNATIONS = 2
"""Alternations of a press's refit without its contact (:func:`_indirect_fitter`), started from the rough fit
(``fit_indirect(warm=True)``). Measured (kappa relative to 3 alternations from kappa = 0, the refit before; the twin's
one-bounce 640x480 presses sphere / cube / coin): 1 warm 8e-3 / 3e-2 / 9e-3, 2 warm 1e-6 / 3e-6 / 9e-7; 2 from kappa =
0 2.6e-5 / 2.4e-5 / 1.7e-5; 4 from kappa = 0 1e-6 / 5e-7 / 4e-7 (benchmarks/RESULTS.md, s20-fixed)."""


def capture_key(capture: Press) -> tuple:
    """What an indirect fit reads of a capture, named by content: camera, response, a digest of the stored
    images (:meth:`Press.images_digest`) and of the reference surface, and the sensor design (the dome beyond
    the view). A fit on the undeformed dome is the sensor's, so it is kept for later presses and processes
    under this key. Worked out once per loaded capture.

    The images are named by the raw bytes of their files when the capture was loaded undecoded (``load_press(...,
    decode=False)``), not by a stamp (size, mtime, inode): a file replaced in place by one of the same size, with
    its time kept (``cp -p``, ``rsync -t``) or within the clock's tick, would keep its stamp and be served the
    old file's fit. Hashing the bytes costs ~10 ms at 640x480; decoding them to hash the arrays 0.2-0.3 s, for a
    warm process that then reads nothing else of the capture (its fit and blurred images are on disk)."""

    def key():
        ref = capture.reference
        surface = reuse.digest(ref.depth, ref.normals)
        design = diskcache.stable_key(design_of(capture))
        masked = unusable_digest(capture)  # samples left out (an LED image's dark rows): another fit
        return (capture.camera, capture.response, capture.images_digest(), surface, design) + (
            () if masked is None else (masked,)
        )

    return reuse.reused("capture key", id(capture), key, keep=capture)


def _undeformed_images(capture: Press) -> reuse.Deferred:
    """The undeformed capture's linear images ((L, H, W, 3) float32, read-only), deferred (:func:`reuse.deferred`)
    under its content key: the contact classification's blur of them (0.13-0.25 s at 640x480) names them by that
    key and is kept on disk for the next process (``contact._smoothed_undeformed``), which then does not
    linearise them at all (a 44 MB array at 640x480 with 12 LEDs)."""
    return reuse.deferred("undeformed capture", capture_key(capture), lambda: capture.linear_led_images)


def _contact(
    press: Press,
    leds: Leds,
    ref_capture: Press | None,
    fixed_light: np.ndarray | None,
    model: IndirectModel | None,
    shading: reuse.Deferred | None,
    dead_level: float,
    cache: dict | None = None,
) -> ContactMap:
    """The one contact classification: against the undeformed capture, or the model with its indirect term.

    ``shading``: :func:`reference_shading` of the reference surface, deferred; ``dead_level``:
    ``SolverOptions.dead_led_level``, the fit's level of a dead LED; ``cache``: the press's side of the
    classification, shared by the classifications of one solve (``classify_contact(cache=...)``)."""
    if ref_capture is not None:
        return undeformed_contact(press, leds, ref_capture, dead_level, cache)
    classify = functools.partial(classify_contact, press, leds, dead_level=dead_level, cache=cache)
    if model is not None and model.enabled:
        # one LED's light at a time: the classification block-averages each, and never needs the 44 MB stack
        light = model.undeformed_light_per_led(press.camera.shape)
        return classify(undeformed_images=shading, undeformed_light=light)
    return classify(undeformed_images=shading, indirect=fixed_light)


def undeformed_contact(
    press: Press, leds: Leds, ref_capture: Press, dead_level: float, cache: dict | None = None
) -> ContactMap:
    """The contact classification of ``press`` against the undeformed capture ``ref_capture`` (its images' blur
    kept under the capture's content key, :func:`_undeformed_images`); arguments as :func:`_contact`'s. The solve's,
    and the one ``--roi auto`` measures the per-LED gains away from before the solve (``solver.press``)."""
    return classify_contact(
        press,
        leds,
        undeformed_images=_undeformed_images(ref_capture),
        undeformed_noise=True,
        dead_level=dead_level,
        cache=cache,
    )
