"""Interreflection of the undeformed dome as an array: the indirect term evaluated on the reference surface.

The model and its fit live in :mod:`nlipscalib.solver.indirect` (radiosity gather in
:mod:`nlipscalib.solver.radiosity`); :func:`nlipscalib.solver.solve_press` applies it, including the
dent's own interreflection (outer loop on the solved surface). This module gives the undeformed dome's
indirect light as a plain (L, H, W, 3) array, for callers that subtract it themselves
(``solve_press(..., indirect=array)``) or inspect it.
"""

from __future__ import annotations

import numpy as np

from ..core.capture import Press
from ..core.errors import CaptureError, ShapeError
from ..core.leds import Leds
from .indirect import fit_indirect


def estimate_indirect(reference: Press, leds: Leds | None = None, *, mode: str = "on", bounces: int = 1) -> np.ndarray:
    """Indirect (interreflected) light of every LED and pixel of a capture of the undeformed dome.

    Parameters
    ----------
    reference : Press -- the undeformed dome (with ``reference``), same camera, LEDs and exposure as
        the presses it will be subtracted from.
    leds : sequence of Led or None -- the LED model (e.g. from ``calibrate-leds``); default the capture's.
    mode : "on" (always evaluate the fitted term), or "auto" (zeros when the data show no indirect light).
    bounces : 1 or 2 diffuse bounces.

    Returns
    -------
    (L, H, W, 3) float32 -- linear image units (``Press.linear`` scale); 0 off the gel.
    """
    if reference.reference is None:
        raise CaptureError(f"{reference.folder}: interreflection needs the reference surface (reference.npz)")
    leds = reference.leds if leds is None else tuple(leds)
    model = fit_indirect(reference, leds, mode=mode, bounces=bounces)
    ref = reference.reference
    H, W = reference.camera.shape
    if not model.enabled:
        return np.zeros((len(leds), H, W, 3), np.float32)
    valid = np.isfinite(ref.depth)
    # the fit's typical albedo (per-patch values vary little on a coating and carry the capture's noise)
    light = model.undeformed_light((H, W)) * np.asarray(model.off_view_albedo, np.float32)
    light[:, ~valid] = 0.0
    return light


def compensate(images: np.ndarray, indirect: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Subtract the indirect light from linear LED images.

    Parameters
    ----------
    images : (L, H, W, 3) float -- linear, ``Press.linear`` scale.
    indirect : (L, H, W, 3) float -- e.g. from :func:`estimate_indirect`.
    out : (L, H, W, 3) float32 or None -- written and returned when given (a view into a kept buffer: no
        whole-frame temporaries, 44 MB each at 640x480 with 12 LEDs).

    Returns
    -------
    (L, H, W, 3) float32 -- clipped at 0 (the solver treats near-zero samples as shadow).
    """
    if np.shape(images) != np.shape(indirect):
        raise ShapeError(f"indirect light {np.shape(indirect)} must match the images {np.shape(images)}")
    out = np.subtract(np.asarray(images, np.float32), np.asarray(indirect, np.float32), out=out)
    return np.maximum(out, 0.0, out=out)
