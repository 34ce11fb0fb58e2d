"""Solving presses as a user's command does: resumable, honest about re-runs, concurrency-safe, parallel.

The one place that turns press folders into reconstruction folders (PRESS/nlips/), shared by
``nlips solve``, ``nlips demo``, ``nlips eval`` (re-computing a damaged result), and later
``nlips calibrate`` and the experiments.

- **Honest re-runs.** Every result records what made it (report.json ``provenance``): the solver
  settings (options, ROI request, LED subset or calibrated LEDs, backend, extra solver keywords), the
  identities of its inputs (content hashes of the press and the reference capture) and the software
  version, and one ``key`` hashing them all. A result is reused only when its key equals the key of
  the new request; otherwise it is re-solved (and the log says what changed).
- **Damaged results** (truncated result.npz, an array failing its checksum, broken report.json) are
  re-computed with a warning.
- **Concurrency.** Work on PRESS/nlips is claimed (:func:`nlipscalib.core.claims.claim`): a press that
  another live process is solving is left to it and waited for at the end, and interrupted writes
  (``.tmp-nlips-*``) are removed only by the claim's holder, i.e. when no live process can own them.
- **Parallel.** ``workers > 1`` solves presses in separate processes (the solver runs single-threaded
  BLAS, so one process per core is the efficient split). Ctrl-C stops the batch in the parent: queued
  presses are not started, running ones finish; a SIGTERM'd worker removes its claim and temporary first.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
import os
from collections.abc import Iterable, Sequence
from pathlib import Path

from . import __version__
from .core.atomic import TMP_PREFIX
from .core.reconstruction import (
    REPORT_FILE,
    Reconstruction,
    check_replaceable,
    content_problem,
    load_reconstruction,
    read_report,
    reconstruction_dir,
    reconstruction_problem,
)
from .errors import CaptureError, ConfigError, NlipsError

log = logging.getLogger(__name__)

SOLVED, SKIPPED, FAILED = "solved", "skipped", "failed"
"""Statuses of one press (a failure reads "failed: reason")."""
BUSY = "busy"
"""Internal status: another live process holds the press's claim (left to it, then waited for)."""
BROKEN = f"{FAILED}: not solved, a solver process was killed (by a signal or for lack of memory); run again"
"""Status of the presses a parallel batch could not finish because one of its processes died."""


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

    def describe(self) -> dict:
        """JSON-able record of the settings (paths as given; values that decide the result)."""
        from .core.reconstruction import jsonable

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


# ---------------------------------------------------------------------- public API
def make_settings(
    *,
    reference: str | Path | None = None,
    roi="auto",
    leds=None,
    options=None,
    backend: str = "numpy",
    solver_keywords: dict | None = None,
) -> SolveSettings:
    """Check and normalise solve arguments (see :func:`solve_presses`) into :class:`SolveSettings`."""
    from .solver import SolverOptions

    if options is None:
        options = SolverOptions()
    elif not isinstance(options, SolverOptions):
        raise ConfigError(f"options must be a SolverOptions, got {type(options).__name__}")
    if backend not in ("numpy", "torch"):
        raise ConfigError(f"backend must be 'numpy' or 'torch', got {backend!r}")
    subset, led_values, leds_file, leds_sensor = _resolve_leds(leds)
    reference = getattr(reference, "folder", reference)  # a loaded Press stands for its folder
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
    )


def settings_from_record(record: dict) -> SolveSettings:
    """The :class:`SolveSettings` recorded in a report.json (``provenance.settings``), e.g. to re-make a result.

    The LED file is not re-read: the recorded LED values are used.
    """
    from .core.leds import Led
    from .solver import SolverOptions

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


def solve_folder(
    folder: str | Path,
    *,
    reference: str | Path | None = None,
    roi="auto",
    leds=None,
    options=None,
    backend: str = "numpy",
    overwrite: bool = False,
    progress: bool = True,
    figures=True,
    out: str | Path | None = None,
    solver_keywords: dict | None = None,
    announce_reuse: bool = True,
) -> tuple[Reconstruction | None, str]:
    """Solve one press folder into ``out`` (default PRESS/nlips), or reuse an identical result there.

    Parameters are those of :func:`solve_presses`, plus ``out`` and ``announce_reuse`` (False: a reused
    result is not logged, for a caller that solved the press itself a moment ago and only loads it).

    Returns
    -------
    (reconstruction, status) : the result (solved now or reused) and "solved" or "skipped". When another
        process is solving the press, this waits for it: its result is reused when made with these
        settings, else the press is solved here.

    Raises
    ------
    NlipsError (CaptureError, ConfigError, ShapeError) with one line naming the file and the problem.
    """
    settings = make_settings(
        reference=reference, roi=roi, leds=leds, options=options, backend=backend, solver_keywords=solver_keywords
    )
    return solve_one(
        Path(folder),
        settings,
        out=out,
        overwrite=overwrite,
        progress=progress,
        figures=figures,
        announce_reuse=announce_reuse,
        wait=True,
    )


def solve_presses(
    folders: Iterable[str | Path],
    *,
    reference: str | Path | None = None,
    roi="auto",
    leds=None,
    options=None,
    backend: str = "numpy",
    workers: int = 1,
    overwrite: bool = False,
    progress: bool = True,
    figures=True,
    solver_keywords: dict | None = None,
    wait: bool = False,
) -> dict[str, str]:
    """Solve several press folders (each into PRESS/nlips), in parallel processes when ``workers > 1``.

    Parameters
    ----------
    folders : press folders; the ``reference`` folder, if among them, is not solved
    reference : press folder (or loaded Press) of the undeformed dome (same camera, LEDs, exposure):
        interreflection compensation and auto ROI against it (solver.solve_press ``indirect``)
    roi : "auto", (x0, y0, w, h) pixels, or None (the whole visible gel)
    leds : None (the capture's LEDs); an LED JSON file from ``nlips calibrate-leds``; a string like
        "1,2,5" (1-based LED subset); a sequence of core.leds.Led; or a sequence of 0-based int indices
    options : solver.SolverOptions or None (defaults)
    backend : "numpy" or "torch"
    workers : processes solving presses at once (1: in this process)
    overwrite : re-solve even when an identical result exists
    progress : progress bars (shown only on a terminal)
    figures : True/"maps" (cheap PNG maps), "full" (plus a matplotlib summary), False/"none"
    solver_keywords : further keyword arguments of solver.solve_press (recorded and hashed too)
    wait : a press another live process is solving is waited for at once (then its result is reused when it
        was made with these settings, else the press is solved here); without it such presses are left to
        that process first and waited for once this run's other presses are done (two runs on one folder
        share the work, and each ends with a result of its own settings for every press)

    Returns
    -------
    dict press name -> "solved" | "skipped" | "failed: reason", in the order of ``folders``. "skipped":
    an identical result exists (made earlier, or by another process that held the press). Failures of one
    press (bad capture, bad LED file) do not stop the others; a file-system error (disk full, read-only) stops
    the batch (OSError naming the path). A result is reused only when its
    arrays pass their checksums, so damage inside result.npz is re-computed too.
    """
    from .report import figure_level

    settings = make_settings(
        reference=reference, roi=roi, leds=leds, options=options, backend=backend, solver_keywords=solver_keywords
    )
    figure_level(figures)
    folders = [Path(f) for f in folders]
    if settings.reference is not None:  # the undeformed dome is the reference, not a press to solve
        folders = [f for f in folders if f.resolve() != settings.reference.resolve()]
    if not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"workers must be a whole number >= 1, got {workers!r}")
    names = _names(folders)
    started = _fs_clock(folders)
    statuses = _solve_batch(folders, names, settings, workers, overwrite, progress, figures, wait)
    busy = [f for f in folders if statuses[f] == BUSY]  # another run's: left to it, now waited for
    if busy:
        log.info("%d presses were being solved by another process; waiting for them", len(busy))
        # --overwrite: what another run of these settings published meanwhile is fresh, not solved a third time
        statuses |= _solve_batch(busy, names, settings, workers, overwrite, progress, figures, True, started)
    return {names[f]: statuses[f] for f in folders}


def _solve_batch(folders, names, settings, workers, overwrite, progress, figures, wait, fresh_since=None):
    if workers == 1 or len(folders) <= 1:
        return _solve_serially(folders, names, settings, overwrite, progress, figures, wait, fresh_since)
    return _solve_in_processes(folders, names, settings, workers, overwrite, progress, figures, wait, fresh_since)


def _fs_clock(folders) -> float | None:
    """Now by the clock of the file system holding the presses (results' mtimes are compared with it)."""
    from .core.claims import fs_now

    return fs_now(Path(folders[0]).parent) if folders else None


def solve_one(
    folder: Path,
    settings: SolveSettings,
    *,
    out: str | Path | None = None,
    overwrite: bool = False,
    progress: bool = False,
    figures=True,
    want_result: bool = True,
    announce_reuse: bool = True,
    wait: bool = False,
    fresh_since: float | None = None,
) -> tuple[Reconstruction | None, str]:
    """:func:`solve_folder` with prepared settings; ``want_result=False`` skips loading a reused result;
    ``wait``: as in :func:`solve_presses` (a press being solved by another process is waited for);
    ``fresh_since``: with ``overwrite``, a result of these settings published at or after this time (file-system
    clock; another run of the same command, waited for) is reused, not solved again."""
    from .report import figure_level, figures_missing

    figures = figure_level(figures)  # a bad value fails now, not after the solve
    check_fits_capture(folder, settings)  # before anything is said about an earlier result
    out = reconstruction_dir(folder, out).absolute()  # "." has no name to claim or write beside
    check_replaceable(out)  # a dataset, a press or a user's folder at --out is never replaced by a result
    provenance = make_provenance(folder, settings)
    # leftovers are cleaned, and figures a reused result lacks are drawn, under the claim, below
    if not overwrite and not _leftovers(out) and not figures_missing(out, figures):
        reused = _reuse(out, provenance, want_result, quiet=True, announce=announce_reuse)
        if reused is not None:
            return reused
    progress = _bars(progress)
    while True:
        with _claim(out) as mine:
            if mine:
                _clean_interrupted(out)
                if not overwrite or _published_since(out, fresh_since):  # it may have appeared while we waited
                    reused = _reuse(out, provenance, want_result, quiet=False, announce=announce_reuse)
                    if reused is not None:
                        _write_missing_figures(folder, out, reused[0], figures)
                        return reused
                return _solve_and_save(folder, out, settings, provenance, progress, figures), SOLVED
        if not wait:
            log.info("%s: being solved by another process; left to it for now", folder)
            return None, BUSY
        _wait_for_release(folder, out)  # then claimed here: its result reused when made with these settings


def _published_since(out: Path, since: float | None) -> bool:
    """Whether ``out``'s result was published at or after ``since`` (file-system clock; False without one)."""
    if since is None:
        return False
    try:
        return (out / REPORT_FILE).stat().st_mtime >= since
    except OSError:
        return False


def _write_missing_figures(folder: Path, out: Path, result: Reconstruction | None, figures) -> None:
    """Give a reused result the figures this run asks for that the run which made it did not write
    (``--no-figures`` then, ``--figures full`` now): drawing them takes milliseconds, re-solving seconds.
    Called under the result's claim, so no other process replaces the folder meanwhile."""
    from .core.capture import load_press
    from .report import figures_missing, write_reconstruction_figures

    if not figures_missing(out, figures):
        return
    if result is None:
        result = load_reconstruction(out)
    press = load_press(folder)
    write_reconstruction_figures(out, result, press.ground_truth, figures, *_figure_context(press))
    log.info("%s: figures (%s) added to the existing result", out, figures)


def _wait_for_release(folder: Path, out: Path) -> None:
    """Wait until no live process holds the claim on ``out`` (it published its result, failed, or died:
    a dead owner's claim goes stale and is taken over)."""
    import time

    from .core import claims

    log.info("%s: being solved by another process; waiting for it", folder)
    while claims.holder(out) is not None:
        time.sleep(claims.CLAIM_POLL_S)  # read here, so a test's patch of it holds


def check_fits_capture(folder: Path, settings: SolveSettings) -> None:
    """A ROI inside the capture's image, an LED subset or LED file that fits its LEDs (read from meta.json), a
    reference captured by the same sensor; else ConfigError or CaptureError naming what does not fit (``nlips
    calibrate --leds`` checks its LED file with it before any solving)."""
    from .core.capture import META_FILE, read_meta, read_optics
    from .solver.press import check_roi, check_undeformed

    meta = read_meta(folder)
    camera, leds = meta.get("camera") or {}, meta.get("leds") or []
    if isinstance(settings.roi, tuple) and isinstance(camera, dict) and "width" in camera and "height" in camera:
        check_roi(settings.roi, int(camera["width"]), int(camera["height"]))
    n = len(leds)
    if settings.led_subset is not None and not all(0 <= i < n for i in settings.led_subset):
        raise ConfigError(f"leds {[i + 1 for i in settings.led_subset]}: {folder / META_FILE} has LEDs 1..{n}")
    used = len(settings.led_subset) if settings.led_subset is not None else n
    if settings.leds is not None and len(settings.leds) != used:
        raise ConfigError(f"{settings.leds_file or 'leds'}: {len(settings.leds)} LEDs, but {folder} has {used}")
    if settings.leds is not None and settings.led_subset is None:
        _check_leds_sensor(folder, meta, settings)
    if settings.reference is not None:  # another sensor's capture: refused now, not after "re-solving" is logged
        check_undeformed(read_optics(folder), read_optics(settings.reference))


_WARNED_UNRECORDED: set[str] = set()
"""LED files already warned about for recording no sensor (in this process)."""


def _check_leds_sensor(folder: Path, meta: dict, settings: SolveSettings) -> None:
    """Calibrated LEDs of another sensor are refused (the LED file records the sensor it was calibrated on).

    An LED file that records no sensor (written before 2026-12-04) is compared with the capture's LEDs: far
    from them, a warning -- not an error, since a calibration may rightly find a real sensor's LEDs millimetres
    and degrees from its design. LED values passed in (an experiment's deliberately offset LEDs) are not.
    """
    from .core.capture import META_FILE, parse_optics
    from .core.leds import led_geometry_mismatch
    from .core.sensor_record import describe_sensor, leds_file_mismatch

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


def make_provenance(folder: Path, settings: SolveSettings) -> dict:
    """What makes the reconstruction of ``folder`` with ``settings``: settings, input identities, and their key.

    Input identities are content hashes (SHA-256) of the capture files the solver reads (meta.json,
    the images, reference.npz), so a moved or copied press keeps its identity and a re-captured one
    does not.
    """
    inputs = {
        "press": capture_identity(folder),
        "reference": None if settings.reference is None else capture_identity(settings.reference),
    }
    described = settings.describe()
    keyed = {k: v for k, v in described.items() if k not in ("leds_file", "reference")}  # paths: not content
    key_source = {"settings": keyed, "inputs": inputs, "software_version": __version__}
    key = hashlib.sha256(json.dumps(key_source, sort_keys=True).encode()).hexdigest()
    return {"key": key, "software_version": __version__, "settings": described, "inputs": inputs}


@functools.lru_cache(maxsize=16)
def _capture_identity_cached(folder: str, stamp: tuple) -> str:
    from .core.capture import META_FILE, read_meta

    meta = read_meta(folder)
    digest = hashlib.sha256((Path(folder) / META_FILE).read_bytes())
    images = meta["images"]
    for name in [images["dark"], images["tricolor"], *images["leds"], meta.get("reference")]:
        if not name:
            continue
        path = Path(folder) / name
        try:
            digest.update(name.encode() + b"\0" + path.read_bytes())
        except FileNotFoundError:
            raise CaptureError(f"{path}: listed in {META_FILE} but missing") from None
    return digest.hexdigest()


def capture_identity(folder: str | Path) -> str:
    """SHA-256 (hex) of a press folder's solver inputs: meta.json, images and reference.npz contents."""
    from .core.capture import META_FILE

    meta = Path(folder) / META_FILE
    try:
        st = meta.stat()
    except FileNotFoundError:
        raise CaptureError(f"{meta}: missing; {folder} is not a complete press folder") from None
    # cached per process while meta.json is the same file (press folders are replaced whole, atomically)
    return _capture_identity_cached(str(Path(folder).resolve()), (st.st_ino, st.st_mtime_ns, st.st_size))


# ---------------------------------------------------------------------- internals
def _bars(requested: bool) -> bool:
    from .progress import bars_enabled

    return bars_enabled(requested)


def _claim(target: Path):
    from .core.claims import claim

    return claim(target)


def _reuse(out: Path, provenance: dict, want_result: bool, quiet: bool, announce: bool = True):
    """(result or None, "skipped") when ``out`` holds a sound result made with the same key; else None.

    ``quiet``: no word on why a result is not reused; ``announce``: say that one is."""
    if not out.exists():
        return None
    problem = reconstruction_problem(out, verify=not want_result)  # a loaded result is checked as it loads
    if problem is not None:
        if not quiet:
            log.warning("%s; re-computing it", problem)
        return None
    old = read_report(out).get("provenance")
    if not isinstance(old, dict):  # absent, or a hand-edited report: no record of what made it
        old = {}
    if old.get("key") != provenance["key"]:
        if not quiet:
            log.info("%s: made with other settings or inputs (%s), re-solving", out, _what_changed(old, provenance))
        return None
    reused_level = logging.INFO if announce else logging.DEBUG
    if not want_result:
        log.log(reused_level, "%s: identical result exists, skipped (--overwrite re-solves)", out)
        return None, SKIPPED
    try:
        result = load_reconstruction(out)
    except CaptureError as exc:
        if not quiet:
            log.warning("%s; re-computing it", exc)
        return None
    log.log(reused_level, "%s: identical result exists, skipped (--overwrite re-solves)", out)
    return result, SKIPPED


def _what_changed(old: dict, new: dict) -> str:
    if not old:
        return "no record of them"
    settings, inputs = old.get("settings"), old.get("inputs")
    settings = settings if isinstance(settings, dict) else {}
    inputs = inputs if isinstance(inputs, dict) else {}
    changed = [k for k, v in new["settings"].items() if k not in ("leds_file", "reference") and settings.get(k) != v]
    changed += [f"{k} capture" for k, v in new["inputs"].items() if inputs.get(k) != v]
    if old.get("software_version") != new["software_version"]:
        changed.append("software version")
    return ", ".join(changed) or "record differs"


def _leftovers(out: Path) -> bool:
    """Whether temporary entries of ``out`` (live or interrupted writes) lie beside it."""
    return any(out.parent.glob(f"{TMP_PREFIX}{out.name}[~-]*"))


def _clean_interrupted(out: Path) -> None:
    """Remove interrupted writes of ``out`` beside it. Call only while holding its claim.

    Owner-tagged temporary folders (``.tmp-nlips~host~pid~*``) go when their owner is gone
    (core.atomic.clean_interrupted); untagged ones of older versions (``.tmp-nlips-XXXXXXXX``, ``.tmp-nlips-old``)
    go too: holding the claim means no live process of this pipeline is writing ``out``. Only ``out``'s own:
    ``.tmp-res-2~host~pid~*`` is the live temporary of another output (``--out res-2``), which the claim on
    ``res`` does not cover (a glob ``.tmp-res-*`` removed it under a running solve).
    """
    import glob
    import re
    import shutil

    from .core.atomic import clean_interrupted

    gone = clean_interrupted(out.parent, item=out.name)
    # tempfile.mkdtemp's suffix, or "old": another item's legacy name has a second "-", a tagged one a "~"
    untagged = re.compile(re.escape(f"{TMP_PREFIX}{out.name}-") + r"[a-z0-9_]+")
    legacy = [p for p in out.parent.glob(glob.escape(f"{TMP_PREFIX}{out.name}-") + "*") if untagged.fullmatch(p.name)]
    for tmp in legacy:
        shutil.rmtree(tmp, ignore_errors=True) if tmp.is_dir() else tmp.unlink(missing_ok=True)
    for tmp in gone + legacy:
        log.warning("%s: removed an interrupted write", tmp)


def _solve_and_save(folder: Path, out: Path, settings: SolveSettings, provenance: dict, progress: bool, figures):
    import time

    from .core.atomic import check_writable
    from .core.capture import load_press
    from .report import figure_level, write_reconstruction_figures
    from .solver import save_result, solve_press

    level = figure_level(figures)
    check_writable(out.parent, len(out.name))  # a read-only disk fails now, not after the solve
    t0 = time.perf_counter()
    press = load_press(folder, led_subset=settings.led_subset)
    ref = None
    if settings.reference is not None:
        ref = _load_reference(settings.reference, settings.led_subset, capture_identity(settings.reference))
    if settings.leds is not None and len(settings.leds) != len(press.leds):
        raise ConfigError(
            f"{settings.leds_file or 'leds'}: {len(settings.leds)} LEDs, but {folder} has {len(press.leds)}"
        )
    t1 = time.perf_counter()
    result = solve_press(
        press,
        roi=settings.roi,
        leds=settings.leds,
        options=settings.options,
        backend=settings.backend,
        progress=progress,
        indirect=ref,
        **dict(settings.solver_keywords),
    )
    t2 = time.perf_counter()
    if settings.led_subset is not None:  # the solver numbers the LEDs it was given: back to the capture's
        for key in ("leds_used", "dead_leds", "dead_leds_contact"):
            if key in result.report:
                result.report[key] = [settings.led_subset[i] for i in result.report[key]]
    result.report["method"] = "nlips"
    result.report["provenance"] = provenance
    result.report["command_seconds"] = {"load": round(t1 - t0, 3), "solve": round(t2 - t1, 3)}
    if problem := content_problem(result.arrays()):  # never published: every later run would re-solve it
        raise CaptureError(f"{folder}: the solve gave an unusable result ({problem})")
    gt, context = press.ground_truth, _figure_context(press)
    save_result(
        result,
        out,
        overwrite=True,
        extra_files=lambda tmp: write_reconstruction_figures(tmp, result, gt, level, *context),
    )
    _log_solved(folder, out, result.report, time.perf_counter() - t2)
    return result


def _figure_context(press) -> tuple:
    """What the figures of ``press``'s result take beside it: the undeformed depth (reference.npz; None when the
    capture has none), so depth.png shows the indentation, and the press's name for the summary's title."""
    return (press.reference.depth if press.reference is not None else None), Path(press.folder).resolve().name


@functools.lru_cache(maxsize=2)
def _load_reference(folder: Path, subset: tuple[int, ...] | None, identity: str):
    """The reference capture, loaded once per process and identity (presses of a batch share it)."""
    from .core.capture import load_press

    return load_press(folder, led_subset=subset)


def _log_solved(folder: Path, out: Path, rep: dict, save_s: float) -> None:
    log.info(
        "%s: %s/%s pixels reconstructed, %s with too few LEDs, dead LEDs %s, solver %.1f s, saved in %.2f s -> %s",
        folder.name,
        rep.get("pixels_reconstructed", "?"),
        rep.get("pixels_solved", "?"),
        rep.get("pixels_too_few_leds", "?"),
        [i + 1 for i in rep.get("dead_leds", [])],
        rep.get("seconds", float("nan")),
        save_s,
        out,
    )


def _resolve_roi(roi):
    if roi is None or roi == "auto":
        return roi
    if isinstance(roi, str):
        raise ConfigError(f"roi must be 'auto', None or (x0, y0, w, h), got {roi!r}")
    try:
        box = tuple(int(v) for v in roi)
    except (TypeError, ValueError):
        box = ()
    from .solver.press import MIN_ROI_SIDE as side

    if len(box) != 4 or min(box) < 0 or min(box[2:]) < side:  # the same minimum as the solver's check_roi
        raise ConfigError(f"roi {roi!r} must be (x0, y0, w, h) with x0, y0 >= 0, at least {side}x{side} pixels")
    return box


def _resolve_leds(leds):
    """(0-based subset or None, calibrated LEDs or None, LED file or None, the sensor the file records or None)
    from the ``leds`` argument."""
    from .core.leds import Led
    from .solver.io import read_led_file

    if leds is None:
        return None, None, None, None
    if isinstance(leds, (str, Path)):
        path = Path(leds)
        if path.suffix.lower() == ".json" or path.is_file():
            led_file = read_led_file(path)
            return None, led_file.leds, str(path), led_file.sensor
        try:
            return tuple(int(v) - 1 for v in str(leds).split(",")), None, None, None
        except ValueError:
            raise ConfigError(f"leds must be like '1,2,5' (1-based) or an LED .json file, got {leds!r}") from None
    leds = tuple(leds)
    if leds and all(isinstance(v, Led) for v in leds):
        return None, leds, None, None
    if leds and all(isinstance(v, int) for v in leds):
        return leds, None, None, None
    raise ConfigError("leds must be an LED file, '1,2,5', a sequence of Led, or a sequence of 0-based indices")


def _solver_keywords(given: dict | None) -> dict:
    """``given`` checked against solve_press's keywords and completed with their defaults.

    Completing with the defaults makes "not given" and "given at its default" the same request (one key).
    """
    import inspect

    from .solver import solve_press
    from .solver.press import check_modes

    own = {"press", "roi", "leds", "options", "backend", "progress", "indirect"}
    params = {
        name: p.default
        for name, p in inspect.signature(solve_press).parameters.items()
        if name not in own and p.default is not inspect.Parameter.empty
    }
    unknown = sorted(set(given or {}) - set(params))
    if unknown:
        raise ConfigError(f"unknown solver keywords {unknown}; solve_press accepts {sorted(params)}")
    keywords = params | dict(given or {})
    check_modes(*(keywords[k] for k in ("interreflection", "bounces", "outer_relaxation", "coating_albedo")))
    return keywords


def _names(folders: Sequence[Path]) -> dict[Path, str]:
    """Press names for the status table: the folder name, or the whole path where names repeat."""
    counts: dict[str, int] = {}
    for f in folders:
        counts[f.name] = counts.get(f.name, 0) + 1
    return {f: f.name if counts[f.name] == 1 else str(f) for f in folders}


def _status_of(
    folder: Path, settings: SolveSettings, overwrite: bool, progress: bool, figures, wait=False, fresh_since=None
) -> str:
    """One press's status; a bad capture or bad settings become "failed: ...".

    File-system errors (disk full, read-only, permission) propagate: every later press would fail
    alike, so the batch stops and the CLI prints one line naming the path.
    """
    try:
        return solve_one(
            folder,
            settings,
            overwrite=overwrite,
            progress=progress,
            figures=figures,
            want_result=False,
            wait=wait,
            fresh_since=fresh_since,
        )[1]
    except NlipsError as exc:
        log.error("%s: %s", folder.name, exc)
        return f"{FAILED}: {exc}"


def _solve_serially(folders, names, settings, overwrite, progress, figures, wait=False, fresh=None) -> dict[Path, str]:
    from .progress import track

    single = len(folders) == 1
    statuses = {}
    bar = track(folders, enabled=progress and not single, desc="presses", unit="press")
    for folder in bar:
        bar.set_postfix_str(names[folder], refresh=False)
        statuses[folder] = _status_of(folder, settings, overwrite, progress and single, figures, wait, fresh)
    return statuses


def _solve_in_processes(
    folders, names, settings, workers, overwrite, progress, figures, wait=False, fresh=None
) -> dict[Path, str]:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    from .progress import progress_bar, worker_logging

    # forkserver: workers start from a clean process with the solver imported once, not from a fork of
    # a caller that may hold threads (claims' heartbeats, progress monitors) or a multi-threaded BLAS
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
    if "forkserver" in methods:
        ctx.set_forkserver_preload(["nlipscalib.pipeline", "nlipscalib.solver"])
    statuses = {}
    with ProcessPoolExecutor(
        max_workers=min(workers, len(folders)),
        mp_context=ctx,
        initializer=_worker_init,
        initargs=worker_logging(),
    ) as pool:
        futures = {pool.submit(_status_of, f, settings, overwrite, False, figures, wait, fresh): f for f in folders}
        bar = progress_bar(len(futures), enabled=progress, desc="presses", unit="press")
        try:
            for done in as_completed(futures):
                folder = futures[done]
                try:
                    statuses[folder] = done.result()
                except BrokenProcessPool:
                    # a worker was killed (SIGKILL, the out-of-memory killer): the pool ends every other
                    # worker (they release their claims, _worker_signals) and fails every press not done
                    if not any(s == BROKEN for s in statuses.values()):
                        log.error("a solver process was killed; the presses not finished are left for the next run")
                    statuses[folder] = BROKEN
                bar.set_postfix_str(names[folder], refresh=False)
                bar.update()
        except BaseException as exc:  # Ctrl-C, a bug: queued presses never start, running ones finish
            if isinstance(exc, KeyboardInterrupt):  # the workers ignore Ctrl-C (_worker_signals)
                log.warning("interrupted: the presses being solved are finished, the others are not started")
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        finally:
            bar.close()
    return statuses


def _worker_init(log_level: int, log_file: str | None = None) -> None:
    """Log like the parent (stderr and its ``--log-file``); one core per worker: the solver limits BLAS
    itself, OpenCV's pool is limited here."""
    from .progress import configure_worker

    configure_worker(log_level, log_file)
    _worker_signals()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from .solver import threads

    threads.set_workers(1)
    try:
        import cv2

        cv2.setNumThreads(1)
    except ImportError:  # pragma: no cover - OpenCV is a core dependency
        pass


def _worker_signals() -> None:
    """Leave Ctrl-C to the parent; on SIGTERM release this worker's claims and temporaries, then exit.

    Ctrl-C in a terminal reaches every process of the command. A worker waiting for its next press
    dies of it with a traceback (concurrent.futures catches it only around a press), the pool counts
    as broken and kills the other workers in the middle of their presses, leaving their claims
    behind. Ignored here, the parent alone stops the batch: queued presses are cancelled, running
    ones finish and release their claims (:func:`_solve_in_processes`).

    SIGTERM (a scheduler's time limit, ``kill`` of the process group) would end a worker at once,
    leaving its claim and its half-written ``.tmp-nlips~...`` folder for the next run to clean; the
    handler removes both first, as ``nlips`` itself does (cli._terminate_cleanly). It runs when the
    current native call (a sparse solve) returns, and ends the process with ``os._exit``: an
    exception raised there could land inside a library.
    """
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_terminated)


def _worker_terminated(signum, frame) -> None:
    from .core import atomic, claims

    claims.release_all()
    atomic.remove_in_progress()
    os._exit(128 + signum)
