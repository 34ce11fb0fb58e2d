"""Solving press folders into reconstruction folders: one press or a batch (serially or in worker processes),
each result reused when identical, else solved and saved with its figures."""

from __future__ import annotations

import contextlib
import functools
import logging
import threading
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Future
from pathlib import Path
from typing import TYPE_CHECKING

from ..core import said_once
from ..core.errors import (
    PATH,
    CaptureError,
    ConfigError,
    NlipsError,
    NoContactError,
    check_flag,
    check_kind,
    check_paths,
    check_whole,
)
from ..core.reconstruction import (
    Reconstruction,
    check_replaceable,
    content_problem,
    load_reconstruction,
    reconstruction_dir,
)
from ..progress import PRESS_SUMMARY
from .provenance import capture_identity, make_provenance, run_record
from .reuse import _claim, _clean_interrupted, _hold, _leftovers, _published_since, _reuse, _wait_for_release
from .settings import SolveSettings, check_fits_capture, for_press, make_settings
from .status import BUSY, FAILED, NO_CONTACT, SOLVED
from .workers import _solve_in_processes

if TYPE_CHECKING:  # named in hints only: the solver and captures are imported when a press is solved
    from ..core.capture import Press
    from ..core.leds import Led
    from ..solver import SolverOptions

log = logging.getLogger(__package__)  # the package's one logger: log files keep naming "nlipscalib.pipeline"


def solve_folder(
    folder: str | Path,
    *,
    reference: str | Path | None = None,
    roi: str | Sequence[int] | None = "auto",
    leds: str | Path | Sequence[int] | Sequence[Led] | None = None,
    options: SolverOptions | None = None,
    backend: str = "numpy",
    overwrite: bool = False,
    progress: bool = True,
    figures: bool | str = True,
    out: str | Path | None = None,
    solver_keywords: dict | None = None,
    announce_reuse: bool = True,
    led_model: str = "auto",
    led_disks: tuple[Sequence[Led] | None, float] | None = None,
) -> tuple[Reconstruction | None, str]:
    """Solve one press folder into ``out`` (default PRESS/nlips), or reuse an identical result there.

    Parameters are those of :func:`solve_presses`, plus ``out`` and ``announce_reuse`` (False: a reused
    result is not logged, for a caller that solved the press itself a moment ago and only loads it).

    Returns
    -------
    (reconstruction, status) : the result (solved now or reused) and "solved" or "skipped". When another
        process of these settings is solving the press, this waits for it and reuses its result (or solves the
        press when it failed).

    Raises
    ------
    NlipsError (CaptureError, ConfigError, ShapeError) with one line naming the file and the problem;
    ConfigError naming the press, ``out`` and the other run's settings when a live run of other settings holds
    ``out`` (its result is never replaced while it runs; see :func:`solve_presses`).
    """
    check_kind(folder, PATH, "folder", "a press folder's path (str or Path)")
    check_kind(out, (*PATH, type(None)), "out", "the result folder's path (str or Path), or None (PRESS/nlips)")
    _check_flags(overwrite=overwrite, progress=progress, announce_reuse=announce_reuse)
    settings = make_settings(
        reference=reference,
        roi=roi,
        leds=leds,
        options=options,
        backend=backend,
        solver_keywords=solver_keywords,
        led_model=led_model,
        led_disks=led_disks,
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
    roi: str | Sequence[int] | None = "auto",
    leds: str | Path | Sequence[int] | Sequence[Led] | None = None,
    options: SolverOptions | None = None,
    backend: str = "numpy",
    workers: int = 1,
    overwrite: bool = False,
    progress: bool = True,
    figures: bool | str = True,
    solver_keywords: dict | None = None,
    wait: bool = False,
    led_model: str = "auto",
    led_disks: tuple[Sequence[Led] | None, float] | None = None,
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
    led_model : "auto" (default: the capture's own LEDs as disks of its design's declared size where points miss
        them unevenly over its gel, points otherwise, :func:`.settings.for_press`; given LEDs by the same choice, as
        their disks, the LED file's fitted ``emitters`` or ``led_disks``, a file of point LEDs as points), "points",
        or "disks" (the LED file's fitted disk emitters, or the capture's own as its design's disks: a view that sees
        the gel beside the LEDs, the flat pad; ``nlips solve --led-model``)
    led_disks : with ``leds`` a sequence of Led: their disks, (emitters in their order, or None for the LEDs
        themselves, radius mm), as an LED file's ``emitters``; None: the LEDs are points
    wait : a press another live process of these settings is solving is waited for at once (then its result
        is reused, or the press solved here when that process failed); without it such presses are left to
        that process first and waited for once this run's other presses are done (two runs of one settings on
        one folder share the work)

    Returns
    -------
    dict press name -> "solved" | "skipped" | "failed: reason", in the order of ``folders``. "skipped":
    an identical result exists (made earlier, or by another process that held the press). A press whose output
    a live run of other settings holds (from its start to its end, each press's ``PRESS/.claim-nlips~run~...``)
    is "failed: PRESS/nlips: another run is solving PRESS into it with other settings (roi auto (this run:
    none); process PID on HOST); ...": left to that run, never replaced while it runs. Failures of one
    press (bad capture, bad LED file) do not stop the others; a file-system error (disk full, read-only) stops
    the batch (OSError naming the path). A result is reused only when its
    arrays pass their checksums, so damage inside result.npz is re-computed too.

    A fault of the whole session (LED images out of order, LEDs aged since the undeformed capture) is logged as a
    WARNING once per call (its workers too), at INFO for the other presses, each press's report keeping it
    (:func:`nlipscalib.core.said_once.scope`): a second call on the same folder warns again.
    """
    from ..report import figure_level

    folders = check_paths(folders, "folders", "a list of press folders' paths (str or Path)")
    check_whole(workers, "workers", minimum=1)
    _check_flags(overwrite=overwrite, progress=progress, wait=wait)
    settings = make_settings(
        reference=reference,
        roi=roi,
        leds=leds,
        options=options,
        backend=backend,
        solver_keywords=solver_keywords,
        led_model=led_model,
        led_disks=led_disks,
    )
    figure_level(figures)
    folders = [Path(f) for f in folders]
    if settings.reference is not None:  # the undeformed dome is the reference, not a press to solve
        folders = [f for f in folders if f.resolve() != settings.reference.resolve()]
    names = _names(folders)
    started = _fs_clock(folders)
    # a session's fault (swapped, aged LEDs) said once per call: a notebook's second call says it again
    with said_once.scope(), contextlib.ExitStack() as held:  # every press held for these settings until the end
        statuses = _hold_presses(held, folders, settings)  # those a run of other settings holds: failed
        todo = [f for f in folders if f not in statuses]
        statuses |= _solve_batch(todo, names, settings, workers, overwrite, progress, figures, wait)
        busy = [f for f in todo if statuses[f] == BUSY]  # another run's: left to it, now waited for
        if busy:
            log.info("%d presses were being solved by another process; waiting for them", len(busy))
            # --overwrite: what another run of these settings published meanwhile is fresh, not solved a third time
            statuses |= _solve_batch(busy, names, settings, workers, overwrite, progress, figures, True, started)
    return {names[f]: statuses[f] for f in folders}


def _check_flags(**flags: object) -> None:
    """ShapeError naming the first of ``flags`` that is not True or False (``overwrite="no"`` overwrote)."""
    for name, value in flags.items():
        check_flag(value, name)


def _hold_presses(held: contextlib.ExitStack, folders: list[Path], settings: SolveSettings) -> dict[Path, str]:
    """Hold every press's output for ``settings`` in ``held`` (pipeline.reuse._hold), for the whole batch: a result
    this run made stays its own until the run ends (another run of other settings reaching the press later, once
    it was released, replaced it while this run went on). Returns the failed status of each press a live run of
    other settings holds."""
    refused = {}
    for folder in folders:
        try:  # each press's own settings: --led-model disks without an LED file takes its design's LED size
            held.enter_context(_hold(folder, result_dir(folder, None), run_record(for_press(folder, settings))))
        except NlipsError as exc:
            log.error("%s", _failure_line(folder, exc))
            refused[folder] = f"{FAILED}: {exc}"
    return refused


def _solve_batch(
    folders: list[Path],
    names: dict[Path, str],
    settings: SolveSettings,
    workers: int,
    overwrite: bool,
    progress: bool,
    figures: bool | str,
    wait: bool,
    fresh_since: float | None = None,
) -> dict[Path, str]:
    if workers == 1 or len(folders) <= 1:
        return _solve_serially(folders, names, settings, overwrite, progress, figures, wait, fresh_since)
    args = (settings, overwrite, False, figures, wait, fresh_since)  # a worker's press shows no bars of its own
    return _solve_in_processes(_status_of, folders, names, workers, progress, args)


def _fs_clock(folders: Sequence[Path]) -> float | None:
    """Now by the clock of the file system holding the presses (results' mtimes are compared with it)."""
    from ..core.claims import fs_now

    return fs_now(Path(folders[0]).parent) if folders else None


def solve_one(
    folder: Path,
    settings: SolveSettings,
    *,
    out: str | Path | None = None,
    overwrite: bool = False,
    progress: bool = False,
    figures: bool | str = True,
    want_result: bool = True,
    announce_reuse: bool = True,
    wait: bool = False,
    fresh_since: float | None = None,
) -> tuple[Reconstruction | None, str]:
    """:func:`solve_folder` with prepared settings; ``want_result=False`` skips loading a reused result;
    ``wait``: as in :func:`solve_presses` (a press being solved by another process is waited for);
    ``fresh_since``: with ``overwrite``, a result of these settings published at or after this time (file-system
    clock; another run of the same command, waited for) is reused, not solved again."""
    from ..report import figure_level

    figures = figure_level(figures)  # a bad value fails now, not after the solve
    settings = for_press(folder, settings)  # the press's design's LED size for --led-model disks without a file
    check_fits_capture(folder, settings)  # before anything is said about an earlier result
    out = result_dir(folder, out)
    # a dataset, a press, a user's folder or an NLiPsNet result at --out is never replaced by a result
    check_replaceable(out, method="nlips")
    provenance = make_provenance(folder, settings)
    with _hold(folder, out, run_record(settings)):  # a live run of other settings keeps its press: refused here
        return _reuse_or_solve(
            folder,
            out,
            settings,
            provenance,
            overwrite,
            progress,
            figures,
            want_result,
            announce_reuse,
            wait,
            fresh_since,
        )


def result_dir(folder: Path, out: str | Path | None = None) -> Path:
    """Where ``folder``'s result goes, named from the press as the user gave it (or ``out``): the log lines name it
    so, beside the press's own (``x/press_0001/nlips`` for ``x/press_0001``, not an absolute path among relative
    ones); absolute only for ``--out .``, which has no name to claim or write beside."""
    out = reconstruction_dir(folder, out)
    return out if out.name else out.absolute()


def _failure_line(folder: Path, exc: Exception) -> str:
    """A press's failure for the log, naming the press as the user gave it, once: the error's own line when it
    starts with the press (its file: ``x/press_0001/meta.json: ...``), else that line after the press."""
    line = str(exc)
    return line if line.startswith(str(folder)) else f"{folder}: {line}"


def _reuse_or_solve(
    folder: Path,
    out: Path,
    settings: SolveSettings,
    provenance: dict,
    overwrite: bool,
    progress: bool,
    figures: str,
    want_result: bool,
    announce_reuse: bool,
    wait: bool,
    fresh_since: float | None,
) -> tuple[Reconstruction | None, str]:
    """:func:`solve_one` once ``out`` is held for its settings."""
    from ..report import figures_missing

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
        _wait_for_release(folder, out)  # then claimed here: its result reused (a run of these settings made it)


def _write_missing_figures(folder: Path, out: Path, result: Reconstruction | None, figures: str) -> None:
    """Give a reused result the figures this run asks for that the run which made it did not write
    (``--no-figures`` then, ``--figures full`` now), or left empty or cut short (a power cut soon after it was
    published): drawing them takes milliseconds, re-solving seconds. Called under the result's claim, so no other
    process replaces the folder meanwhile."""
    from ..core.capture import load_press
    from ..core.file_checks import MISSING
    from ..report import figures_problem, write_reconstruction_figures

    problem = figures_problem(out, figures)
    if problem is None:
        return
    if result is None:
        result = load_reconstruction(out)
    press = load_press(folder)
    write_reconstruction_figures(out, result, lambda: press.ground_truth, figures, *_figure_context(press))
    if problem.endswith(f" {MISSING}"):
        log.info("%s: figures (%s) added to the existing result", out, figures)
    else:
        log.warning("%s: %s; figures (%s) drawn again, the result kept", out, problem, figures)


def _bars(requested: bool) -> bool:
    from ..progress import bars_enabled

    return bars_enabled(requested)


def _solve_and_save(
    folder: Path, out: Path, settings: SolveSettings, provenance: dict, progress: bool, figures: bool | str
) -> Reconstruction:
    import time

    from ..core.atomic import check_writable
    from ..core.capture import load_press
    from ..core.reconstruction import save_reconstruction
    from ..report import figure_level, write_reconstruction_figures
    from ..solver import solve_press
    from ..solver.krylov import import_amg_in_background
    from ..solver.press import LED_LIST_KEYS

    level = figure_level(figures)
    check_writable(out.parent, len(out.name))  # a read-only disk fails now, not after the solve
    t0 = time.perf_counter()
    # the images decode on a thread of their own (PNG decoding releases the GIL) while the rest of the capture is
    # read and checked here: reference.npz, and with --reference the undeformed capture's files (0.1-0.2 s at
    # 640x480 one after the other); the load's seconds end once the images are decoded
    import_amg_in_background()  # beside the loading, not at the solve's first AMG set-up (~25-70 ms)
    press = load_press(folder, led_subset=settings.led_subset, decode="background")
    # error.png's ground truth (a twin's gt.npz: ~0.06 s of CPU inflating and checking it at 640x480) is read from
    # now on, beside the rest of the loading and the solve, on the core they leave idle (the images were decoded
    # beside the solver's import: cli.solve), not at the end, where the figures waited for it and the command for
    # them; a solve itself reads none
    truth = _read_beside(lambda: press.ground_truth) if level != "none" else None
    ref = None
    if settings.reference is not None:
        ref = _load_reference(settings.reference, settings.led_subset, capture_identity(settings.reference))
    if settings.leds is not None and len(settings.leds) != len(press.leds):
        raise ConfigError(
            f"{settings.leds_file or 'leds'}: {len(settings.leds)} LEDs, but {folder} has {len(press.leds)}"
        )
    press.led_images  # noqa: B018 -- waits for the decoding (a bad PNG raises here, naming its file)
    t1 = time.perf_counter()
    result = solve_press(
        press,
        roi=settings.roi,
        leds=settings.leds,
        leds_name=settings.leds_file,
        options=settings.options,
        backend=settings.backend,
        progress=progress,
        indirect=ref,
        **dict(settings.solver_keywords),
    )
    t2 = time.perf_counter()
    if settings.led_subset is not None:  # the solver numbers the LEDs it was given: back to the capture's
        for key in LED_LIST_KEYS:
            if key in result.report:
                result.report[key] = [settings.led_subset[i] for i in result.report[key]]
    result.report["method"] = "nlips"
    result.report["provenance"] = provenance
    result.report["command_seconds"] = {"load": round(t1 - t0, 3), "solve": round(t2 - t1, 3)}
    if problem := content_problem(result.arrays()):  # never published: every later run would re-solve it
        raise CaptureError(f"{folder}: the solve gave an unusable result ({problem})")
    context = _figure_context(press)

    def figures(tmp: Path) -> None:
        write_reconstruction_figures(tmp, result, truth.result, level, *context)  # damaged: no error.png

    save_reconstruction(result, out, overwrite=True, extra_files=figures if level != "none" else None)
    _log_solved(folder, out, result.report, time.perf_counter() - t2)
    hint_disk_leds(folder, settings, result.report, press.led_images.shape[-3] * press.led_images.shape[-2])
    return result


def _read_beside(read: Callable[[], object]) -> Future:
    """``read()`` started on a daemon thread of its own; its value or error comes out of the returned future."""
    future = Future()

    def run() -> None:
        try:
            future.set_result(read())
        except BaseException as exc:  # noqa: BLE001 -- raised again by future.result(), where it is needed
            future.set_exception(exc)

    threading.Thread(target=run, name="read-beside", daemon=True).start()
    return future


def _figure_context(press: Press) -> tuple:
    """What the figures of ``press``'s result take beside it: the undeformed depth (reference.npz; None when the
    capture has none), so depth.png shows the indentation, and the press's name for the summary's title."""
    return (press.reference.depth if press.reference is not None else None), Path(press.folder).resolve().name


@functools.lru_cache(maxsize=2)
def _load_reference(folder: Path, subset: tuple[int, ...] | None, identity: str):
    """The reference capture, loaded once per process and identity (presses of a batch share it); its images are
    read but decoded only when a solve needs them: a warm process finds its results on disk by their bytes."""
    from ..core.capture import load_press

    return load_press(folder, led_subset=subset, decode=False)


def hint_disk_leds(folder: Path, settings: SolveSettings, report: dict, frame_pixels: int) -> None:
    """Say once per LED file when a whole-frame solve with its point LEDs sees past the gel (the gel under
    :data:`~nlipscalib.core.tolerances.GEL_FRAME_SHARE_FOR_DISKS` of the frame) while the file holds fitted disks:
    ``--led-model disks`` is then the better model (docs/twin.md, "A view beyond the gel"), a flag a user could
    not know to pass."""
    from ..core import tolerances
    from ..core.ledfile import read_led_file

    points = "emitters" not in dict(settings.solver_keywords)
    if settings.roi is not None or not settings.leds_file or not points:
        return
    share = report.get("pixels_solved", frame_pixels) / max(frame_pixels, 1)
    if share >= tolerances.GEL_FRAME_SHARE_FOR_DISKS or not said_once.first_time(f"disks {settings.leds_file}"):
        return
    if read_led_file(settings.leds_file).emitters:
        log.warning(
            "%s: the camera sees past the gel (%.0f %% of the frame is gel) and %s holds the LEDs' fitted disks: "
            "solve with --led-model disks (near the dome's base the point LEDs miss the light, which bends the "
            "whole gel's depth; the box of --roi auto is not affected)",
            folder,
            100 * share,
            settings.leds_file,
        )


def _log_solved(folder: Path, out: Path, rep: dict, save_s: float) -> None:
    log.info(
        "%s: %s/%s pixels reconstructed, %s with too few LEDs, dead LEDs %s, solver %.1f s, saved in %.2f s -> %s",
        folder,
        rep.get("pixels_reconstructed", "?"),
        rep.get("pixels_solved", "?"),
        rep.get("pixels_too_few_leds", "?"),
        [i + 1 for i in rep.get("dead_leds", [])],
        rep.get("seconds", float("nan")),
        save_s,
        out,
        extra=PRESS_SUMMARY,
    )


def _names(folders: Sequence[Path]) -> dict[Path, str]:
    """Press names for the status table: the folder name, or the whole path where names repeat."""
    counts: dict[str, int] = {}
    for f in folders:
        counts[f.name] = counts.get(f.name, 0) + 1
    return {f: f.name if counts[f.name] == 1 else str(f) for f in folders}


def _status_of(
    folder: Path,
    settings: SolveSettings,
    overwrite: bool,
    progress: bool,
    figures: bool | str,
    wait: bool = False,
    fresh_since: float | None = None,
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
    except NoContactError as exc:  # noted, not failed: the press is the undeformed dome's
        log.warning("%s", _failure_line(folder, exc))
        return f"{NO_CONTACT}: {exc}"
    except NlipsError as exc:
        log.error("%s", _failure_line(folder, exc))
        return f"{FAILED}: {exc}"


def _solve_serially(
    folders: list[Path],
    names: dict[Path, str],
    settings: SolveSettings,
    overwrite: bool,
    progress: bool,
    figures: bool | str,
    wait: bool = False,
    fresh: float | None = None,
) -> dict[Path, str]:
    from ..progress import track

    single = len(folders) == 1
    statuses = {}
    bar = track(folders, enabled=progress and not single, desc="presses", unit="press")
    for folder in bar:
        bar.set_postfix_str(names[folder], refresh=False)
        statuses[folder] = _status_of(folder, settings, overwrite, progress and single, figures, wait, fresh)
    return statuses
