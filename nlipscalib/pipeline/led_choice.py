"""Which model a solve with the capture's own LEDs (no LED file) takes them as, per press (``--led-model auto``):
disks of the size its sensor design declares where points would miss their light unevenly over its gel, points
otherwise; and the one line that says which and why."""

from __future__ import annotations

import hashlib
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from ..core import said_once, tolerances
from ..core.errors import ConfigError

if TYPE_CHECKING:  # named in hints only
    from ..core.camera import Camera
    from ..core.leds import Led
    from ..core.surface_files import Reference

log = logging.getLogger(__package__)  # the package's one logger: log files keep naming "nlipscalib.pipeline"

SPREAD_SAMPLES = 1000
"""Gel pixels the point LEDs are judged on (the spread within 0.0002 of 4000 samples' on the shipped designs, at a
quarter of the CPU: 7-8 ms for 12 LEDs)."""


def auto_led_diameter(
    folder: str | Path, led_subset: tuple[int, ...] | None = None, given: tuple[str, bool] | None = None
) -> float:
    """The diameter (mm) of disks a ``--led-model auto`` solve of ``folder`` with its own LEDs takes them as, or 0
    for points: the design's declared ``leds.emitter_diameter`` where the point LEDs miss those disks' light over the
    undeformed gel by a spread above :data:`~nlipscalib.core.tolerances.POINT_LED_SPREAD_FOR_DISKS` (the shipped
    flat pad, oblate, capsule and fingertip designs; not the hemisphere). Says once per design which model and
    why: INFO for disks, DEBUG for points (the model solves always took, nothing new to say without -v).

    Parameters
    ----------
    folder : a press folder (meta.json, reference.npz).
    led_subset : 0-based indices of the LEDs solved with, or None for all.
    given : LEDs given instead of the capture's (an LED file), judged by the design's choice all the same: (what
        they are in words, "leds.json's LEDs"; whether they hold disks). Where the design takes disks the line says
        they are solved as their disks, or as points where they hold none (a user's point LEDs are kept).

    Returns
    -------
    float, mm, >= 0 -- 0: points.
    """
    from ..core.capture import read_optics
    from ..core.press_meta import META_FILE, read_meta
    from ..core.sensor import capture_led_diameter

    folder = Path(folder)
    try:
        diameter, source = capture_led_diameter(read_meta(folder), str(folder / META_FILE))
    except ConfigError as exc:  # a bad recorded size: points, as before sizes were recorded; a warning, said once
        _say(f"{exc}", f"{folder}: LEDs solved as points (--led-model auto: {exc})", logging.WARNING)
        return 0.0
    if not diameter > 0:
        _say(source, f"{folder}: LEDs solved as points (--led-model auto: {source.split(': ', 1)[-1]})", logging.DEBUG)
        return 0.0
    optics = read_optics(folder)
    leds = optics.leds if led_subset is None else tuple(optics.leds[i] for i in led_subset)
    if optics.reference is None:  # no undeformed surface to judge the point model on
        why = f"{folder}: LEDs solved as points (--led-model auto: no reference.npz)"
        _say(f"noref {diameter}", why, logging.DEBUG)
        return 0.0
    spread = _spread(optics.reference, optics.camera, leds, diameter)
    limit = tolerances.POINT_LED_SPREAD_FOR_DISKS
    disks = spread > limit
    side = "above" if disks else "not above"
    _say(
        f"{diameter} {spread:.4f} {[led.to_dict() for led in leds]} {given}",
        f"{folder}: {_what(diameter, disks, given)} (--led-model auto: as points they miss the {diameter:g} mm disks' "
        f"light over this gel by {100 * spread:.2f} % rms, {side} {100 * limit:.1f} %; --led-model points|disks to "
        "choose)",
        logging.INFO if disks else logging.DEBUG,  # points, the model as ever: said with -v only (experiments' logs)
    )
    return diameter if disks else 0.0


def _what(diameter: float, disks: bool, given: tuple[str, bool] | None) -> str:
    """What the solve takes the LEDs as, in words, for :func:`auto_led_diameter`'s line."""
    leds = "LEDs" if given is None else given[0]
    if not disks:
        return f"{leds} solved as points"
    if given is None:
        return f"LEDs solved as disks of its design's {diameter:g} mm"
    if given[1]:
        return f"{leds} solved as their disks"
    return (
        f"{leds} solved as points, as given: they come without fitted disks (`nlips calibrate-leds` fits them where "
        "the design declares its LEDs' size, or with --led-diameter MM)"
    )


def _say(key: str, line: str, level: int = logging.INFO) -> None:
    if said_once.first_time(f"led model {key}"):
        log.log(level, "%s", line)


def _spread(reference: Reference, camera: Camera, leds: tuple[Led, ...], diameter: float) -> float:
    """:func:`nlipscalib.solver.point_led_error.point_led_spread` on a deterministic sample of the undeformed gel,
    once per surface, LEDs and size in a process (a batch asks twice a press: its hold and its solve)."""
    import numpy as np

    from ..core.camera import depth_to_points
    from ..solver.point_led_error import point_led_spread

    rows, cols = np.nonzero(np.isfinite(reference.depth))
    step = max(1, rows.size // SPREAD_SAMPLES)  # every k-th gel pixel: deterministic, ~1000 samples
    rows, cols = rows[::step], cols[::step]
    u, v = camera.pixel_grid()  # the sampled pixels' rays only: the whole image's took ~90 ms of CPU at 640x480
    rays = camera.unproject(np.stack([u[rows, cols], v[rows, cols]], axis=-1))
    points = np.ascontiguousarray(depth_to_points(reference.depth[rows, cols], rays), np.float64)
    normals = np.ascontiguousarray(reference.normals[rows, cols], np.float64)
    digest = hashlib.sha1(points.tobytes() + normals.tobytes() + repr([led.to_dict() for led in leds]).encode())
    key = (digest.hexdigest(), diameter)
    if key not in _SPREADS:
        _SPREADS[key] = point_led_spread(points, normals, leds, diameter / 2)
    return _SPREADS[key]


_SPREADS: dict[tuple[str, float], float] = {}
"""Spreads computed in this process, by a digest of the sampled gel and LEDs, and the diameter."""
