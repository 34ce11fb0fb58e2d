"""Solve settings: the arguments of a solve checked and normalised (:class:`SolveSettings`), read back from a
report.json, and checked against a capture before anything is solved."""

from __future__ import annotations

import dataclasses
import logging
import numbers
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..core import tolerances
from ..core.errors import PATH, CaptureError, ConfigError, ShapeError, check_kind
from ..core.sensor import UNRENDERED_DESIGN_KEYS

if TYPE_CHECKING:  # named in hints only: the solver is imported when settings are made
    from ..core.leds import Led
    from ..solver import SolverOptions

log = logging.getLogger(__package__)  # the package's one logger: log files keep naming "nlipscalib.pipeline"


@dataclasses.dataclass(frozen=True)
class SolveSettings:
    """Everything besides the press that decides a reconstruction (recorded and hashed in report.json)."""

    roi: str | tuple[int, int, int, int] | None = "auto"
    """"auto" (around the contact), (x0, y0, w, h) pixels, or None (the whole visible gel)."""
    led_subset: tuple[int, ...] | None = None
    """0-based LED indices to use (an ablation), or None for all."""
    leds: tuple | None = None
    """Calibrated LEDs (core.leds.Led) replacing the capture's, or None."""
    leds_file: str | None = None
    """Where ``leds`` were read from (informational; their values are what counts)."""
    leds_sensor: dict | None = None
    """The sensor ``leds`` were calibrated on, as the LED file records it (core.sensor_record), or None:
    a press of another sensor is refused."""
    reference: Path | None = None
    """Press folder of the undeformed dome (interreflection compensation, auto ROI), or None."""
    options: object = None
    """solver.SolverOptions (None: the defaults)."""
    backend: str = "numpy"
    """Solver backend: "numpy" or "torch"."""
    solver_keywords: tuple[tuple[str, object], ...] = ()
    """Further keyword arguments of solver.solve_press (name, value), e.g. dent_interreflection."""
    design_leds: str = "points"
    """The model of each press's own LEDs (no LED file): "disks" (``--led-model disks``: disks of the size its sensor
    design declares, ``leds.emitter_diameter``), "auto" (those disks where points miss their light unevenly over its
    gel, :func:`nlipscalib.pipeline.led_choice.auto_led_diameter`) or "points"; resolved per press by
    :func:`for_press` (a disk solve's ``led_radius`` is then recorded, a point solve's settings are a point solve's).
    "auto" with ``leds`` given (an LED file, LED values): the model the design's own LEDs get, ``given_disks``."""
    given_disks: tuple | None = None
    """The given ``leds``' disks, (emitters or None for ``leds`` themselves, radius mm): an LED file's fitted
    ``emitters``, or those given with LED values; what ``design_leds`` "auto" solves with where the press's design
    takes disks. None: the given LEDs are points, solved as points all the same (said once, INFO)."""

    def describe(self) -> dict:
        """JSON-able record of the settings (paths as given; values that decide the result)."""
        from ..core.reconstruction import jsonable

        return jsonable(
            {
                "roi": list(self.roi) if isinstance(self.roi, tuple) else self.roi,
                "led_subset": None if self.led_subset is None else [i + 1 for i in self.led_subset],
                "leds": None if self.leds is None else [led.to_dict() for led in self.leds],
                "leds_file": self.leds_file,
                "reference": None if self.reference is None else str(self.reference),
                "options": dataclasses.asdict(self.options) if self.options is not None else None,
                "backend": self.backend,
                "solver_keywords": dict(self.solver_keywords),
            }
        )


def make_settings(
    *,
    reference: str | Path | None = None,
    roi: str | Sequence[int] | None = "auto",
    leds: str | Path | Sequence[int] | Sequence[Led] | None = None,
    options: SolverOptions | None = None,
    backend: str = "numpy",
    solver_keywords: dict | None = None,
    led_model: str = "auto",
    led_disks: tuple[Sequence[Led] | None, float] | None = None,
) -> SolveSettings:
    """Check and normalise solve arguments (see :func:`solve_presses`) into :class:`SolveSettings`.

    ``led_disks`` with LED values (``leds``, a sequence of Led): their disks, (emitters in their order or None for
    the values themselves, radius mm), as an LED file's ``emitters`` (the experiments' design and calibrated rows).

    ``led_model`` "disks": the LED file's fitted disk emitters and their radius are solve_press's ``emitters`` and
    ``led_radius`` (recorded in ``solver_keywords``), the NLiPs solves' and the indirect term's LEDs; its point LEDs
    stay ``leds`` (the ``--roi auto`` edge's point-LED misfit). Without an LED file (the capture's own LEDs, a
    subset of them too) they are the capture's LEDs as disks of its design's size, per press (:func:`for_press`).
    "auto" (the default): the capture's own LEDs as those disks where its design's point LEDs miss them unevenly (the
    flat pad, oblate and capsule designs), points otherwise; given LEDs by the same rule, as their disks (an LED
    file's fitted ``emitters``, ``led_disks``) where the design takes disks, a file of point LEDs as points."""
    from ..solver import SolverOptions

    if options is None:
        options = SolverOptions()
    elif not isinstance(options, SolverOptions):
        raise ConfigError(f"options must be a SolverOptions, got {type(options).__name__}")
    if backend not in ("numpy", "torch"):
        raise ConfigError(f"backend must be 'numpy' or 'torch', got {backend!r}")
    subset, led_values, leds_file, leds_sensor = _resolve_leds(leds)
    if led_model not in ("auto", "points", "disks"):
        raise ConfigError(f"led_model must be 'auto', 'points' or 'disks', got {led_model!r}")
    if led_disks is not None and (led_values is None or leds_file is not None):  # a file's disks are its own
        raise ConfigError("led_disks: the disks of LED values given as leds (a sequence of Led), none given")
    chosen = "led_radius" in (solver_keywords or {})  # the caller's own disks or points: taken as they are
    own = leds_file is None and led_values is None and not chosen
    given = not own and not chosen
    given_disks = _given_disks(leds_file, led_values, led_disks) if given and led_model != "points" else None
    design_leds = led_model if own else ("auto" if given and led_model == "auto" else "points")
    if led_model == "disks" and not own:  # the NLiPs solves', the indirect term's and the contact map's LEDs
        emitters, radius = given_disks if given_disks is not None else disk_leds(leds_file)
        solver_keywords = {**(solver_keywords or {}), "led_radius": radius, "emitters": emitters}
    reference = getattr(reference, "folder", reference)  # a loaded Press stands for its folder
    check_kind(
        reference, (*PATH, type(None)), "reference", "the undeformed capture's folder (str or Path), a Press, or None"
    )
    return SolveSettings(
        roi=_resolve_roi(roi),
        led_subset=subset,
        leds=led_values,
        leds_file=leds_file,
        leds_sensor=leds_sensor,
        reference=None if reference is None else Path(reference),
        options=options,
        backend=backend,
        solver_keywords=tuple(sorted(_solver_keywords(solver_keywords).items())),
        design_leds=design_leds,
        given_disks=given_disks if design_leds == "auto" else None,
    )


def _given_disks(
    leds_file: str | None, led_values: tuple[Led, ...] | None, led_disks: tuple[Sequence[Led] | None, float] | None
) -> tuple | None:
    """(emitters or None, radius mm) of given LEDs: an LED file's fitted disks, or ``led_disks`` given with LED
    values; None where they hold none."""
    from ..core.ledfile import read_led_file

    if leds_file is not None:
        led_file = read_led_file(leds_file)
        return (led_file.emitters, led_file.emitter_radius) if led_file.emitters else None
    if led_disks is None:
        return None
    emitters, radius = led_disks
    if not (isinstance(radius, numbers.Real) and radius > 0):
        raise ConfigError(f"led_disks: the disks' radius must be a number > 0 mm, got {radius!r}")
    if emitters is not None and len(emitters) != len(led_values or ()):
        raise ConfigError(f"led_disks: {len(emitters)} disk LEDs given for {len(led_values or ())} LEDs")
    return (None if emitters is None else tuple(emitters), float(radius))


def for_press(folder: Path, settings: SolveSettings) -> SolveSettings:
    """``settings`` for one press: with :attr:`SolveSettings.design_leds` "disks", its own LEDs as disks of the
    diameter its sensor design declares (``core.sensor.capture_led_diameter``: meta.json's design or the twin's
    scene), recorded as solve_press's ``led_radius``; with "auto", those disks where the point LEDs miss them unevenly
    over its gel and points otherwise (:func:`nlipscalib.pipeline.led_choice.auto_led_diameter`, which says so once
    per design), and given LEDs (an LED file, LED values) by the same choice: their disks (``given_disks``) where it
    takes disks, points otherwise and where they hold none (said); otherwise ``settings`` unchanged. Every solve of a
    press goes through here (``nlips solve``, ``demo``, ``calibrate``'s press solves, the experiments' press tasks),
    so one press gets one model.

    Raises
    ------
    ConfigError
        "disks" on a capture whose design declares no LED size, naming its meta.json and what to do instead.
    """
    if settings.design_leds == "points":
        return settings
    from ..core.press_meta import META_FILE, read_meta
    from ..core.sensor import capture_led_diameter
    from .led_choice import auto_led_diameter

    emitters = None
    if settings.design_leds == "auto":
        named = f"{settings.leds_file}'s LEDs" if settings.leds_file else "the given LEDs"
        given = None if settings.leds is None else (named, settings.given_disks is not None)
        diameter = auto_led_diameter(folder, settings.led_subset, given)
        if not diameter > 0 or (given is not None and not settings.given_disks):
            # points: the settings of a point solve, whose results and records stay as they were; a user's point
            # LEDs (a file of no disks) are kept so, the line above says it
            return dataclasses.replace(settings, design_leds="points", given_disks=None)
        if given is not None:  # the given LEDs' own disks
            emitters, radius = settings.given_disks
            diameter = 2 * radius
    else:
        diameter, source = capture_led_diameter(read_meta(folder), str(Path(folder) / META_FILE))
        if not diameter > 0:
            raise ConfigError(
                f"{source}: --led-model disks without --leds needs the LEDs' size: give --leds FILE from `nlips "
                "calibrate-leds REFERENCE --led-diameter MM`, or solve with --led-model points"
            )
    keywords = {**dict(settings.solver_keywords), "led_radius": diameter / 2, "emitters": emitters}
    return dataclasses.replace(
        settings,
        design_leds="points",
        given_disks=None,
        solver_keywords=tuple(sorted(_solver_keywords(keywords).items())),
    )


def settings_from_record(record: dict) -> SolveSettings:
    """The :class:`SolveSettings` recorded in a report.json (``provenance.settings``), e.g. to re-make a result.

    The LED file is not re-read: the recorded LED values are used.
    """
    from ..core.leds import Led
    from ..solver import SolverOptions

    try:
        leds = None
        if record.get("leds") is not None:
            leds = tuple(Led.from_dict(d) for d in record["leds"])
        elif record.get("led_subset") is not None:
            leds = tuple(int(i) - 1 for i in record["led_subset"])
        roi = record.get("roi")
        options = SolverOptions(**record["options"]) if record.get("options") is not None else None
        settings = make_settings(
            reference=record.get("reference"),
            roi=tuple(roi) if isinstance(roi, list) else roi,
            leds=leds,
            options=options,
            backend=record.get("backend", "numpy"),
            solver_keywords=record.get("solver_keywords") or {},
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"recorded solve settings are not usable ({exc})") from None
    return dataclasses.replace(settings, leds_file=record.get("leds_file"))


def check_fits_capture(folder: Path, settings: SolveSettings) -> None:
    """A ROI inside the capture's image, an LED subset or LED file that fits its LEDs (read from meta.json), a
    reference captured by the same sensor; else ConfigError or CaptureError naming what does not fit (``nlips
    calibrate --leds`` checks its LED file with it before any solving)."""
    from ..core.capture import read_optics, subset_problem
    from ..core.press_meta import META_FILE, read_meta
    from ..solver.press_checks import check_roi, check_undeformed

    meta = read_meta(folder)
    camera, leds = meta.get("camera") or {}, meta.get("leds") or []
    if isinstance(settings.roi, tuple) and isinstance(camera, dict) and "width" in camera and "height" in camera:
        check_roi(settings.roi, int(camera["width"]), int(camera["height"]))
    n = len(leds)
    if settings.led_subset is not None and (why := subset_problem(settings.led_subset, n)):
        # the argument the caller gave (`leds`, --leds), 1-based as typed: load_press's own check names led_subset
        raise ConfigError(f"leds {[i + 1 for i in settings.led_subset]}: {folder / META_FILE} has LEDs 1..{n}: {why}")
    used = len(settings.led_subset) if settings.led_subset is not None else n
    if settings.led_subset is not None and used < tolerances.MIN_LEDS_PER_PIXEL:  # "only 2 LED images are lit"
        raise ConfigError(
            f"leds {[i + 1 for i in settings.led_subset]}: {used} LED(s); NLiPs needs at least "
            f"{tolerances.MIN_LEDS_PER_PIXEL} (a normal and an albedo per pixel)"
        )
    if settings.leds is not None and len(settings.leds) != used:
        raise ConfigError(f"{settings.leds_file or 'leds'}: {len(settings.leds)} LEDs, but {folder} has {used}")
    if settings.leds is not None and settings.led_subset is None:
        _check_leds_sensor(folder, meta, settings)
    if settings.reference is not None:  # another sensor's capture: refused now, not after "re-solving" is logged
        check_undeformed(read_optics(folder), read_optics(settings.reference))
        reference_meta = read_meta(settings.reference)
        if why := twin_reference_problem(settings.reference, reference_meta, folder, meta):
            raise CaptureError(why)
        warn_other_origin(settings.reference, reference_meta, folder, meta)


def warn_other_origin(reference: Path, reference_meta: dict, press: Path, press_meta: dict) -> None:
    """One warning, once per command and pair of origins (core.said_once), when the undeformed capture ``reference``
    and ``press`` were made by different sources (:func:`~nlipscalib.core.press_meta.capture_origin`: a twin render,
    the emulated sensor, a sensor); nothing when either records none (a capture of other software, or by hand).

    Why a warning, not a refusal: a lab may solve its sensor's presses against a twin reference on purpose (no
    undeformed capture yet) and the twin's presses against its sensor's to compare; but a twin press solved against
    the emulated sensor's reference (noise, lens, exposure of another path) was solved without a word, its
    interreflection term and contact measured against a light that was not its own."""
    from ..core.press_meta import capture_origin
    from ..core.said_once import first_time

    ours, theirs = capture_origin(press_meta), capture_origin(reference_meta)
    if ours is None or theirs is None or ours == theirs:
        return
    if first_time(f"other origin\0{Path(reference).resolve()}\0{ours}"):
        log.warning(
            "%s: %s, solved against the undeformed capture %s, %s: its light (interreflection term, contact) may "
            "not be the press's; give an undeformed capture made as the press was (said once)",
            press,
            ours,
            reference,
            theirs,
        )


def twin_reference_problem(
    reference: Path, reference_meta: dict, press: Path, press_meta: dict, optional: bool = True
) -> str:
    """The line refusing ``reference`` as the undeformed capture of ``press`` when both are twin renders of other
    light settings (:func:`twin_render_difference`), else "". ``optional``: the command can solve without a
    reference (``nlips solve``), so the line offers that; ``nlips calibrate`` always solves with one."""
    why = twin_render_difference(reference_meta, press_meta)
    if not why:
        return ""
    return (
        f"{reference}: rendered with other twin settings than {press} ({why}): its light is not the press's "
        "sensor's, so the interreflection term fitted on it and the contact found against it would be wrong; render "
        "the reference as the press was (nlips render --undeformed with the press's scene and options: --bounces, "
        "--spp, ...)" + (", or solve without --reference" if optional else "")
    )


TWIN_SETTINGS_OF_NO_LIGHT = frozenset(
    {"name", "render.spp", "render.seed", "render.threads", "render.variant"}
    | {f"{section}.{key}" for section, key in UNRENDERED_DESIGN_KEYS}
)
"""Scene settings two twin renders of one sensor may differ in (``provenance.scene`` of meta.json, "section.key"):
the scene's name, the sample count (the experiments render their references at more samples per pixel than their
presses), seeds, threads, the Mitsuba variant and the design's fields no render reads
(``core.sensor.UNRENDERED_DESIGN_KEYS``: a reference rendered before the shipped scenes declared their LEDs' size).
Every other one changes the sensor's light."""


BOUNCE_LIGHT_SETTINGS = ("render.denoise_indirect", "render.denoise.")
"""Scene settings (prefixes of "section.key") that shape only the bounce light: two renders of direct light only
(``render.bounces`` 0 both) may differ in them. Why: a reference rendered before the twin had its bounce-light filter
(2026-12-01) records none of them, and was refused as the reference of a direct-light press rendered since."""


def twin_render_difference(reference_meta: dict, press_meta: dict) -> str:
    """'render.bounces 0 here, 1 for the press', naming up to three scene settings in which two twin renders differ
    (:data:`TWIN_SETTINGS_OF_NO_LIGHT` aside, and :data:`BOUNCE_LIGHT_SETTINGS` between direct-light renders); ""
    when they agree or one of them is no twin render (a real sensor's capture, an older folder).

    Why: `nlips render --undeformed` at the scene's defaults (direct light) as the reference of a press rendered with
    ``--bounces 1 --spp 16`` (as README's NLiPsNet walk renders a press) fitted an indirect share of 0.014 (term off)
    and then found no contact ("--roi auto found no contact (images match the undeformed dome)"), or, on the whole gel,
    "anchoring off: weak evidence", exit 0."""
    a, b = (_twin_scene(m) for m in (reference_meta, press_meta))
    if a is None or b is None:
        return ""
    flat_a, flat_b = _flat(a), _flat(b)
    direct_only = flat_a.get("render.bounces") == 0 and flat_b.get("render.bounces") == 0
    keys = sorted(
        k
        for k in flat_a.keys() | flat_b.keys()
        if k not in TWIN_SETTINGS_OF_NO_LIGHT and not (direct_only and k.startswith(BOUNCE_LIGHT_SETTINGS))
    )
    differ = [k for k in keys if flat_a.get(k) != flat_b.get(k)]
    said = [f"{k} {flat_a.get(k)!r} here, {flat_b.get(k)!r} for the press" for k in differ[:3]]
    return "; ".join(said) + (f"; and {len(differ) - 3} more" if len(differ) > 3 else "")


def _twin_scene(meta: dict) -> dict | None:
    provenance = meta.get("provenance")
    if not isinstance(provenance, dict) or provenance.get("source") != "sim":
        return None
    scene = provenance.get("scene")
    return scene if isinstance(scene, dict) else None


def _flat(d: dict, prefix: str = "") -> dict:
    """{"section.key": value} of a nested dict (lists kept whole)."""
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out |= _flat(v, f"{prefix}{k}.")
        else:
            out[f"{prefix}{k}"] = v
    return out


_WARNED_UNRECORDED: set[str] = set()
"""LED files already warned about for recording no sensor (in this process)."""


def _check_leds_sensor(folder: Path, meta: dict, settings: SolveSettings) -> None:
    """Calibrated LEDs of another sensor are refused (the LED file records the sensor it was calibrated on).

    An LED file that records no sensor (written before 2026-12-04) is compared with the capture's LEDs: far
    from them, a warning -- not an error, since a calibration may rightly find a real sensor's LEDs millimetres
    and degrees from its design. LED values passed in (an experiment's deliberately offset LEDs) are not.
    """
    from ..core.leds import led_geometry_mismatch
    from ..core.press_meta import META_FILE, parse_optics
    from ..core.sensor_record import describe_sensor, leds_file_mismatch

    camera, leds, response = parse_optics(meta, folder / META_FILE)
    where = settings.leds_file or "the calibrated LEDs"
    if settings.leds_sensor is not None:  # the check `nlips capture --leds FILE` makes too
        why = leds_file_mismatch(settings.leds_sensor, settings.leds, describe_sensor(camera, leds, response))
        if why:
            raise CaptureError(f"{where}: calibrated on another sensor than {folder} ({why})")
        return
    far = led_geometry_mismatch(
        [led.position for led in leds],
        [led.direction for led in leds],
        [led.position for led in settings.leds],
        [led.direction for led in settings.leds],
    )
    if far and settings.leds_file and where not in _WARNED_UNRECORDED:  # LED values passed in: the caller's
        _WARNED_UNRECORDED.add(where)  # once per file, not once per press of a batch
        log.warning(
            "%s: records no sensor to check against %s, and its LEDs differ from the capture's (%s): make sure "
            "they are a calibration of this sensor (a new `nlips calibrate-leds` records the sensor)",
            where,
            folder,
            far,
        )


def _resolve_roi(roi: str | Sequence[int] | None) -> str | tuple[int, ...] | None:
    if roi is None or roi == "auto":
        return roi
    if isinstance(roi, str):
        raise ConfigError(f"roi must be 'auto', None or (x0, y0, w, h), got {roi!r}")
    from ..solver.press_checks import MIN_ROI_SIDE as side
    from ..solver.press_checks import roi_numbers

    box = roi_numbers(roi)  # four whole numbers (2.5 was taken for 2)

    if len(box) != 4 or min(box) < 0 or min(box[2:]) < side:  # the same minimum as the solver's check_roi
        raise ConfigError(f"roi {roi!r} must be (x0, y0, w, h) with x0, y0 >= 0, at least {side}x{side} pixels")
    return box


def _resolve_leds(
    leds: str | Path | Sequence[int] | Sequence[Led] | None,
) -> tuple[tuple[int, ...] | None, tuple[Led, ...] | None, str | None, dict | None]:
    """(0-based subset or None, calibrated LEDs or None, LED file or None, the sensor the file records or None)
    from the ``leds`` argument."""
    import numpy as np

    from ..core.ledfile import read_led_file
    from ..core.leds import Led

    if leds is None:
        return None, None, None, None
    if not isinstance(leds, (str, os.PathLike, Sequence, np.ndarray)):
        raise ShapeError(
            f"leds must be an LED file's path, '1,2,5', a sequence of Led or of 0-based indices, or None, "
            f"got {type(leds).__name__} {leds!r}"
        )
    if isinstance(leds, (str, os.PathLike)):
        path = Path(leds)
        if path.suffix.lower() == ".json" or path.exists():  # a folder too: read_led_file says what it is
            led_file = read_led_file(path)
            _warn_not_fitted(path, led_file.not_fitted)
            return None, led_file.leds, str(path), led_file.sensor
        try:
            return tuple(int(v) - 1 for v in str(leds).split(",")), None, None, None
        except ValueError:
            raise ConfigError(f"leds must be like '1,2,5' (1-based) or an LED .json file, got {leds!r}") from None
    leds = tuple(leds)
    if leds and all(isinstance(v, Led) for v in leds):
        return None, leds, None, None
    if leds and all(isinstance(v, numbers.Integral) and not isinstance(v, (bool, np.bool_)) for v in leds):
        return leds, None, None, None
    raise ConfigError("leds must be an LED file, '1,2,5', a sequence of Led, or a sequence of 0-based indices")


def disk_leds(leds_file: str | None) -> tuple[tuple[Led, ...], float]:
    """The disk emitters of an LED file and their radius (mm), for ``led_model="disks"``; ConfigError naming the
    file (or the missing file) when there are none."""
    from ..core.ledfile import read_led_file

    if leds_file is None:
        raise ConfigError("--led-model disks needs --leds FILE, an LED file from `nlips calibrate-leds` (its disks)")
    led_file = read_led_file(leds_file)
    if not led_file.emitters:
        raise ConfigError(
            f"{leds_file}: no disk LEDs fitted (`nlips calibrate-leds` fits them when the capture records its LEDs' "
            "size, or with --led-diameter MM): calibrate again so, or solve with --led-model points"
        )
    return led_file.emitters, led_file.emitter_radius


def _warn_not_fitted(path: Path, held: tuple[int, ...]) -> None:
    """Say (once per command) that an LED file's not-fitted LEDs shade with their starting values only: a user
    solving with the file would otherwise take every LED for a calibrated one."""
    from ..core.said_once import first_time

    if held and first_time(f"not_fitted {path.resolve()}"):
        log.warning(
            "%s: LED%s %s not fitted by its calibration (kept at the starting values); capture the undeformed dome "
            "again and re-run `nlips calibrate-leds` to calibrate %s",
            path,
            "s" if len(held) > 1 else "",
            ", ".join(str(i + 1) for i in held),
            "them" if len(held) > 1 else "it",
        )


def _solver_keywords(given: dict | None) -> dict:
    """``given`` checked against solve_press's keywords and completed with their defaults.

    Completing with the defaults makes "not given" and "given at its default" the same request (one key).
    """
    import inspect

    from ..solver import solve_press
    from ..solver.press_checks import check_keywords

    own = {"press", "roi", "leds", "options", "backend", "progress", "indirect"}
    params = {
        name: p.default
        for name, p in inspect.signature(solve_press).parameters.items()
        if name not in own and p.default is not inspect.Parameter.empty
    }
    check_kind(given, (Mapping, type(None)), "solver_keywords", "a dict of solve_press's keywords, or None")
    unknown = sorted(set(given or {}) - set(params))
    if unknown:
        raise ConfigError(f"unknown solver keywords {unknown}; solve_press accepts {sorted(params)}")
    keywords = params | dict(given or {})
    check_keywords(given or {}, list(params))
    if keywords["led_radius"] == 0.0:  # point LEDs, as before s32: not recorded, so earlier results keep their keys
        del keywords["led_radius"], keywords["emitters"]
    elif keywords["emitters"] is not None:  # recorded as the LED file holds them (JSON)
        keywords["emitters"] = tuple(e if isinstance(e, dict) else e.to_dict() for e in keywords["emitters"])
    return keywords
