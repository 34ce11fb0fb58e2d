"""``nlips calibrate PRESSES``: solve every press with NLiPs, then build the NLiPsNet calibration dataset + coverage."""

from __future__ import annotations

import argparse
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.shell_words import shell_word
from .options import SOLVE_WORKERS_HELP, add_allow_edited, add_led_model

if TYPE_CHECKING:
    from ..learn.dataset import SamplingConfig

log = logging.getLogger(__name__)


OPTION_OF = {
    "min_confidence": "--min-confidence",
    "min_leds": "--min-leds",
    "rest_per_cell": "--rest-per-cell",
    "smoothing_px": "--smoothing",
    "smoothing_colour": "--smoothing-colour",
}
"""The option of `nlips calibrate` that sets each SamplingConfig field (its validation messages name the field)."""
SOLVE_OPTION_OF = {
    "normals": "--normals",
    "leds": "--leds",
    "led_model": "--led-model",
    "reference": "--reference",
    "keep_tricolor": "--keep-tricolor-mismatch",
}
"""The option of `nlips calibrate` that sets each other thing a dataset's samples depend on
(learn.dataset.dataset_run), for the line refusing a build of other samples into the same --out."""
COVERAGE_FILES = ("coverage.json", "coverage.png")
"""The coverage report beside the dataset: its numbers (written last: their presence marks the report whole), its
figure."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "calibrate",
        help="NLiPs-solve a folder of presses and pair tri-colour pixels with the normals (NLiPsNet training data)",
        description="Solve every press of FOLDER with NLiPs "
        "(skipping presses already solved with the same settings: auto ROI, the folder's reference), then write a "
        "calibration dataset of (u, v, r, g, b) -> normal samples and a coverage report (which dome regions and "
        "normal directions the presses cover, and where to press next). Resumable. On a real sensor, calibrate its "
        "LEDs first (`nlips calibrate-leds PRESSES/reference --out leds.json`) and give them with --leds leds.json.",
    )
    p.add_argument("presses", help="folder of press folders (twin or device)")
    p.add_argument(
        "--reference", metavar="REF_PRESS", help="press folder of the undeformed dome (default: PRESSES/reference)"
    )
    p.add_argument("--out", help="calibration dataset folder (default: PRESSES/calibration)")
    p.add_argument(
        "--leds",
        metavar="FILE",
        help="LED file from `nlips calibrate-leds` (of this sensor): every press is solved with these LEDs, as by "
        "`nlips solve --leds FILE` (an LED file of another sensor is refused); results solved with other LEDs are "
        "solved again (default: the LEDs each capture records)",
    )
    add_led_model(p)
    p.add_argument(
        "--normals",
        choices=("depth", "refined"),
        default="depth",
        help="normals of the labels: depth (the solved depth's gradient; default) or refined (each pixel's refitted "
        "to its own images where they reject the depth's, as `nlips solve --normals refined`: steep relief)",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=0,
        help=SOLVE_WORKERS_HELP,
    )
    p.add_argument(
        "--min-confidence",
        type=float,
        default=0.5,
        help="leave out NLiPs pixels below this confidence, 0-1 (default %(default)s)",
    )
    p.add_argument(
        "--min-leds", type=int, default=4, help="leave out NLiPs pixels lit by fewer usable LEDs (default %(default)s)"
    )
    p.add_argument(
        "--rest-per-cell",
        type=int,
        default=24,
        help="undeformed samples per image cell, 8x8 cells (default %(default)s)",
    )
    p.add_argument(
        "--smoothing",
        type=float,
        help="sigma in px of the Gaussian low-pass on the tri-colour colours the network sees (default: "
        "SamplingConfig's, 1 px; 0: raw pixels)",
    )
    p.add_argument(
        "--smoothing-colour",
        type=float,
        help="colour sigma (linear units, L1 over r, g, b) that makes that low-pass stop at colour edges, so that a "
        "steep wall's colour does not bleed into the flat gel beside it (bilateral filter; lifted Q2's unseen "
        "indenters; default: SamplingConfig's, 0.08; 0: the Gaussian alone, as before the thirty-fifth session)",
    )
    p.add_argument(
        "--keep-tricolor-mismatch",
        action="store_true",
        help="keep presses whose tri-colour frame does not hold their LED images' light (two images of different "
        "colour groups captured in each other's place, the channels in another order, another press's frame: the "
        "check `nlips solve` warns of), each warned of; by default each is left out of the dataset with one line "
        "(before the solves, unsolved, where no solve mends it), and a session whose every capture disagrees the same "
        "way (a camera that gives BGR for RGB) is refused in one",
    )
    add_allow_edited(p, "solve and sample")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import contextlib

    from ..core.atomic import check_can_make
    from ..core.config import check_count, options_named
    from ..core.errors import ConfigError
    from ..core.press_checksums import check_unchanged
    from ..core.press_folders import is_press_folder, no_presses_error, split_reference
    from ..core.press_meta import REFERENCE_FOLDER, read_meta
    from ..learn.dataset import DEFAULT_DIR, SamplingConfig, check_min_leds, dataset_run, hold_dataset
    from ..progress import BATCH, press_lines
    from .folders import check_one_capture, check_undeformed, remove_if_left_empty

    press_lines(BATCH)  # a line per solved press; how each was solved with -v
    check_count("--workers", args.workers, minimum=0)
    smoothing = SamplingConfig.smoothing_px if args.smoothing is None else args.smoothing
    if not smoothing >= 0:
        raise ConfigError(f"--smoothing must be >= 0 px, got {args.smoothing}")
    with options_named(OPTION_OF):  # checked before any solving; SamplingConfig names its fields
        cfg = SamplingConfig(
            min_confidence=args.min_confidence,
            min_leds=args.min_leds,
            rest_per_cell=args.rest_per_cell,
            smoothing_px=smoothing,
            **({} if args.smoothing_colour is None else {"smoothing_colour": args.smoothing_colour}),
        )
        root = Path(args.presses)
        if args.reference is not None:
            check_one_capture(args.reference, "the undeformed dome's capture (--reference)")
            check_undeformed(
                args.reference,
                "the undeformed dome's capture (--reference)",
                "or leave out --reference",
                root / REFERENCE_FOLDER,
            )
        presses, reference = split_reference(root, args.reference)
        if reference is not None:  # a missing or broken --reference: one line naming it, before any solving
            check_min_leds(cfg, len(read_meta(reference).get("leds") or ()), reference)
    if args.reference is not None:
        own_reference_left_out(root, Path(args.reference))
    if reference is None and is_press_folder(root) and is_press_folder(root.parent / REFERENCE_FOLDER):
        if root.name == REFERENCE_FOLDER:  # "one press" misnamed it: the folder's undeformed dome, not a press
            raise ConfigError(
                f"{root}: the undeformed dome's capture of {root.parent}, not a folder of presses; give "
                f"{shell_word(root.parent)}, which holds the presses and this {REFERENCE_FOLDER}/"
            )
        # one press of a dataset given for the dataset: "name one with --reference" calibrated that press alone
        raise ConfigError(
            f"{root}: one press, not a folder of presses; its folder {root.parent} holds them and their "
            f"{REFERENCE_FOLDER}/ (give that), or name the undeformed capture with --reference to use this press alone"
        )
    if not presses:  # before the reference: an empty or wrong folder was told to name one with --reference
        raise no_presses_error(root)
    if reference is None:
        raise ConfigError(f"{root}: no {REFERENCE_FOLDER}/ capture of the undeformed dome; name one with --reference")
    if not args.allow_edited:  # a file copied over one: one line now, not samples of the wrong image
        check_unchanged([reference, *presses])
    reference_fits(reference, presses)
    responses_agree(reference, presses)
    if args.leds is not None:
        led_file_fits(args.leds, reference)
    if args.led_model == "disks":  # an LED file without disks, or a design of no LED size: one line now, not later
        _check_disks(args.leds, reference)
    out = Path(args.out) if args.out else root / DEFAULT_DIR
    check_own_folder(out, presses, root / DEFAULT_DIR)
    check_can_make(out)  # a file in its place or a read-only disk: one line now, not after solving every press
    if not args.keep_tricolor_mismatch:  # after the arguments' own checks: a mistyped --out is said first
        tricolor_agrees(reference, presses, root)
    leds = str(Path(args.leds).resolve()) if args.leds is not None else None
    damaged = _left_out_damaged(root, presses, out)
    presses = [p for p in presses if p.name not in damaged]
    judged = {} if args.keep_tricolor_mismatch else tricolor_left_out(root, presses, out, not args.no_progress)
    solve = {"normals": args.normals, "leds": leds}
    if _solves_disks(args.led_model, leds, reference):  # recorded for disks only: point datasets keep their records
        solve["led_model"] = "disks"
    if args.keep_tricolor_mismatch:  # decides which presses the index holds; recorded only when given, as above
        solve["keep_tricolor"] = True
    run = dataset_run(presses, reference, cfg, solve=solve)
    with contextlib.ExitStack() as stack:
        # a run ended before the dataset's first write (Ctrl-C during the solves, a press refused) left an empty
        # calibration/ (its hold's folder), which `nlips train` then took for a dataset; a started one is kept
        remove_if_left_empty(stack, [out])
        # held from before the solves: a build of other samples into this --out is refused now, not after them
        stack.enter_context(hold_dataset(out, run, option_of=OPTION_OF | SOLVE_OPTION_OF))
        return _solve_and_build(args, root, presses, reference, out, cfg, run, damaged, judged)


def check_own_folder(out: Path, presses: list[Path], default: Path) -> None:
    """ConfigError naming ``out`` when it is a press folder or the folder of the presses: the calibration dataset
    (index.json, samples/, sensor.npz, coverage) was written in among the press's images or beside the presses,
    exit 0, where `nlips solve --out` refuses a press folder. ``default``: the folder to name instead."""
    from ..core.errors import ConfigError
    from ..core.press_folders import is_press_folder

    if is_press_folder(out):
        what = "a press folder (meta.json)"
    elif out.is_dir() and any(p.parent.resolve() == out.resolve() for p in presses):
        what = "the folder of the presses"
    else:
        return
    raise ConfigError(
        f"--out {out}: {what}; the calibration dataset needs a folder of its own (default {default}): "
        "give another --out, or leave it out"
    )


def _check_disks(leds: str | None, reference: Path) -> None:
    """ConfigError in one line, before the hold and any solve, where ``--led-model disks`` cannot solve: an LED file
    without fitted disks, or (no LED file: the capture's own LEDs as its design's disks, as ``nlips solve``) a
    reference whose design declares no LED size, naming its meta.json (the presses are of its design,
    ``reference_fits``)."""
    from ..pipeline.settings import disk_leds, for_press, make_settings

    if leds is not None:
        disk_leds(leds)
    else:
        for_press(reference, make_settings(led_model="disks"))


def _solves_disks(led_model: str, leds: str | None, reference: Path) -> bool:
    """Whether ``--led-model`` solves the presses' LEDs as disks: "disks", or "auto" on a design whose point LEDs
    miss its disks unevenly, with the capture's own LEDs or an LED file's fitted disks
    (:func:`nlipscalib.pipeline.settings.for_press`; the presses are of the reference's design, ``reference_fits``)."""
    from ..pipeline.settings import for_press, make_settings

    if led_model != "auto":
        return led_model == "disks"
    return "led_radius" in dict(for_press(reference, make_settings(leds=leds, led_model="auto")).solver_keywords)


def _left_out_damaged(root: Path, presses: list[Path], out: Path) -> dict[str, str]:
    """The presses left out before any solve, by name with their line (logged here): a file only the samples read
    is damaged inside (:func:`nlipscalib.learn.dataset.damaged_sampled_files`), which the build met after every
    press was solved. ConfigError when that leaves none."""
    from ..core.errors import ConfigError
    from ..learn.dataset import damaged_sampled_files

    damaged = damaged_sampled_files(presses, out)
    for line in damaged.values():
        log.error("%s; the press is left out, not solved: copy it again, or capture it again", line)
    if damaged and len(damaged) == len(presses):
        raise ConfigError(f"{root}: every press holds a damaged file (each named above)")
    return damaged


def _solve_and_build(
    args: argparse.Namespace,
    root: Path,
    presses: list[Path],
    reference: Path,
    out: Path,
    cfg: SamplingConfig,
    run: dict,
    damaged: dict[str, str],
    judged: dict[str, dict],
) -> int:
    """The solves, the dataset and its coverage report, and the summary lines (exit status); ``damaged``: the
    presses left out before solving (:func:`_left_out_damaged`), counted with those the build leaves out;
    ``judged``: those left out, unsolved, for their tri-colour frame (:func:`tricolor_left_out`), recorded by the
    build with those it leaves out."""
    from ..core.cpus import SOLVE_ROI_MEMORY, solve_worker_count
    from ..core.errors import ConfigError
    from ..core.press_meta import image_size, read_meta
    from ..core.sensor_record import camera_position_of
    from ..learn.coverage import coverage, write_coverage_json
    from ..learn.dataset import CalibrationDataset, build_dataset
    from ..progress import print_result, say
    from ..report.learn import coverage_figure

    # as `nlips solve FOLDER`: one solver per two cores, fewer where memory holds fewer (1280x960: ~1.9 GB each)
    workers = solve_worker_count(args.workers, SOLVE_ROI_MEMORY, *image_size(reference))
    status = solve_all(
        [p for p in presses if p.name not in judged],
        reference,
        workers=workers,
        progress=not args.no_progress,
        leds=args.leds,
        normals=args.normals,
        led_model=args.led_model,
    )
    solved = [p for p in presses if status.get(p.name) in ("solved", "skipped")]
    # each failure was logged with its cause as it happened (pipeline.solve._status_of): listed by name at the end only
    failed = {k: v for k, v in status.items() if v not in ("solved", "skipped")}
    if not solved:
        raise ConfigError(f"{root}: no press could be solved")
    # the coverage report is of the dataset it was made from: removed before the build, and coverage.json (which
    # marks it whole) written after its figure, so that a run killed in between leaves none rather than the
    # earlier dataset's report (or half of it) beside this one's index.json
    for name in COVERAGE_FILES:
        (out / name).unlink(missing_ok=True)
    unsampled = dict(damaged)  # a press whose tri-colour image is damaged fails alone, as a failed solve
    build_dataset(
        [p for p in presses if p in solved or p.name in judged],
        reference,
        out,
        cfg,
        progress=not args.no_progress,
        run=run,
        failed=unsampled,
        keep_tricolor=args.keep_tricolor_mismatch,
        judged=judged,
    )
    data = CalibrationDataset(out)
    mismatched = [gone["name"] for gone in data.tricolor_left_out]
    cov = coverage(data, camera_position=camera_position_of(read_meta(Path(reference))))
    coverage_figure(cov, out / COVERAGE_FILES[1])
    write_coverage_json(out / COVERAGE_FILES[0], cov)
    n = sum(e["samples"] for e in data.entries)
    n_contact = sum(e["contact_samples"] for e in data.entries)
    pressed = f"{len(data.entries)} press{'es' if len(data.entries) != 1 else ''}"
    print_result(out)  # stdout: the dataset's folder alone (scripts); what it holds is said on stderr
    say(f"{out}: {pressed}, {n} samples ({n_contact} contact)")
    nxt = cov["next_press"]
    say(f"coverage: {cov['covered_fraction'] * 100:.0f}% of (region, direction) bins; press next: {nxt['advice']}")
    if cov["steep"]["advice"]:
        say(f"coverage: {cov['steep']['advice']}")
    if cov["tricolor"]["advice"]:
        say(f"coverage: {cov['tricolor']['advice']}", warning=True)
    left_out = (
        (failed, "failed to solve"),
        (unsampled, "left out of the dataset (not sampled)"),
        (mismatched, "left out of the dataset (tri-colour frame unlike its LED images; --keep-tricolor-mismatch)"),
    )
    for names, what in left_out:
        if names:
            say(f"{len(names)} press{'es' if len(names) > 1 else ''} {what}: {', '.join(sorted(names))}", warning=True)
    # the step after this one, with this run's folder: the calibration dataset is what `nlips train` reads
    variant = "--hidden 64,64,64 --dropout 0: the real-time variant"
    say(f"next: nlips train {shell_word(out)} --out MODEL.pt (NLiPsNet; {variant})")
    return 1 if failed or unsampled or mismatched else 0


def own_reference_left_out(root: Path, given: Path) -> None:
    """``nlips calibrate ROOT --reference GIVEN`` where ROOT holds its own ``reference/``: one info line that it is
    left out (it is the undeformed dome, never a press), or a ConfigError when the two are captures of different
    sensors (ROOT's presses would then not match GIVEN: the dataset build would refuse them after the solve)."""
    from ..core.capture import load_press
    from ..core.errors import CaptureError, ConfigError
    from ..core.press_folders import is_press_folder
    from ..core.press_meta import REFERENCE_FOLDER
    from ..core.sensor_record import sensor_mismatch, sensor_of

    own = root / REFERENCE_FOLDER
    if is_press_folder(root) or not is_press_folder(own) or not is_press_folder(given):
        return  # nothing to leave out, or GIVEN is refused in one line where it is read
    if own.resolve() == given.resolve():
        return
    try:
        why = sensor_mismatch(sensor_of(load_press(given)), sensor_of(load_press(own)), f"{given} has")
    except CaptureError as exc:  # a damaged own reference is not used: say so, and go on with GIVEN
        log.info("%s: left out, --reference %s is used (it cannot be read: %s)", own, given, exc)
        return
    if why:
        raise ConfigError(
            f"{own} and --reference {given} are captures of different sensors ({own}: {why}): "
            f"leave out --reference to use {own}, or name a reference captured with the sensor of {root}'s presses"
        )
    log.info("%s: left out (not a press); the undeformed dome of --reference %s is used", own, given)


def reference_fits(reference: Path, presses: Sequence[Path]) -> None:
    """One line, before any solving, when the undeformed capture cannot be read or is of another sensor than
    the first readable press (every press's solve failed on it alike: one line per press). A press whose
    meta.json cannot be read is not compared: it fails alone, in its own line."""
    from ..core.capture import load_press, read_optics
    from ..core.errors import CaptureError, ConfigError
    from ..core.press_meta import META_FILE, parse_optics, read_meta
    from ..core.sensor_record import describe_sensor, sensor_mismatch, sensor_of, surface_mismatch
    from ..pipeline.settings import twin_reference_problem

    undeformed = load_press(reference)
    theirs = sensor_of(undeformed)
    for press in presses:
        try:
            meta = read_meta(press)
            ours = describe_sensor(*parse_optics(meta, press / META_FILE))
            surface = read_optics(press).reference
        except CaptureError:
            continue
        why = sensor_mismatch(theirs, ours, f"{reference} has")
        # camera and LEDs alike, the dome may be another (a design of one's own): said as `nlips solve --reference`
        # says it, not as "other twin settings" with a remedy of re-rendering
        if not why and surface is not None and undeformed.reference is not None:
            why = surface_mismatch(surface.depth, undeformed.reference.depth)
        if why:
            raise ConfigError(f"--reference {reference}: not a capture of the sensor of {press} ({press}: {why})")
        if why := twin_reference_problem(reference, read_meta(reference), press, meta, optional=False):
            raise ConfigError(f"--reference {why}")
        return


def tricolor_agrees(reference: Path, presses: Sequence[Path], root: Path) -> None:
    """One line, before any solving, when the undeformed capture's tri-colour frame does not hold its LED images'
    light (:mod:`nlipscalib.core.tricolor_check`): the dataset's reference frame, which the build would refuse after
    every press was solved. Only then is every press judged too (~0.2 s of CPU each at 640x480), so that a session
    whose every capture disagrees the same way (a camera that gives BGR for RGB) is said as that
    (:func:`nlipscalib.learn.dataset_tricolor.sort_presses`). A press that cannot be read is not judged: it fails
    alone, in its own line."""
    from ..core.capture import load_press
    from ..core.errors import CaptureError
    from ..core.tricolor_check import press_tricolor_verdict
    from ..learn.dataset_tricolor import RECORD_KEY, disagrees, sort_presses

    undeformed = press_tricolor_verdict(load_press(reference)).record()
    if not disagrees(undeformed):
        return
    entries = []
    for press in presses:
        try:
            record = press_tricolor_verdict(load_press(press)).record()
        except CaptureError:
            continue
        entries.append({"name": press.name, "folder": str(press), RECORD_KEY: record})
    sort_presses(entries, undeformed, reference, root, keep=False)  # raises: the reference disagrees


def tricolor_left_out(root: Path, presses: Sequence[Path], out: Path, progress: bool) -> dict[str, dict]:
    """The presses whose tri-colour frame does not hold their LED images' light, found before any solve, by name with
    their verdict's record (:meth:`~nlipscalib.core.tricolor_check.TricolorVerdict.record`), each said in one line:
    left out of the dataset, as the build left them out after solving them (minutes each at 640x480) though the
    check reads only the capture. ConfigError when that leaves none.

    Only the verdicts no solve mends (:func:`nlipscalib.learn.dataset_tricolor.judged_before_solve`): two LED images
    of different groups in each other's place are solved, as before, since the solve's LED checks may find them and
    solve them in the order they show, which the frame then fits; the build judges those after the solve. A press
    whose shard is in ``out`` already is not judged (a resumed build keeps it with its verdict, reading nothing), nor
    one that cannot be read (it fails alone, in its own line). Cost: the capture's 14 frames decoded and the check,
    ~0.1-0.2 s of CPU per 640x480 press (benchmarks/RESULTS.md, s41-tricheck)."""
    from ..core.capture import load_press
    from ..core.errors import CaptureError, ConfigError
    from ..core.tricolor_check import press_tricolor_verdict
    from ..learn.dataset import SHARD_DIR
    from ..learn.dataset_tricolor import KEEP_OPTION, judged_before_solve, left_out_line
    from ..progress import track

    judged = {}
    unsampled = [p for p in presses if not (out / SHARD_DIR / f"{p.name}.npz").is_file()]
    for press in track(unsampled, enabled=progress, desc="tri-colour check", unit="press"):
        try:
            record = press_tricolor_verdict(load_press(press)).record()
        except CaptureError:
            continue
        if judged_before_solve(record):
            log.error("%s", left_out_line(record, solved=False))
            judged[press.name] = record
    if judged and len(judged) == len(presses):
        raise ConfigError(
            f"{root}: no press left whose tri-colour frame holds its LED images' light (each one's line is above); "
            f"pass {KEEP_OPTION} to keep them"
        )
    return judged


def responses_agree(reference: Path, presses: Sequence[Path]) -> None:
    """One line, before any solving, when a press declares another camera response than the undeformed capture
    (meta.json ``sensor.camera_response``, :func:`~nlipscalib.core.sensor_record.response_mismatch`): the model
    records one response, with which ``nlips infer`` linearises the stills and streams it is given. A press whose
    meta.json cannot be read is not compared: it fails alone, in its own line."""
    from ..core.errors import CaptureError, ConfigError
    from ..core.press_meta import META_FILE, parse_optics, read_meta
    from ..core.sensor_record import describe_sensor, response_mismatch

    def sensor(folder: Path) -> dict:
        return describe_sensor(*parse_optics(read_meta(folder), folder / META_FILE))

    theirs = sensor(reference)
    for press in presses:
        try:
            ours = sensor(press)
        except CaptureError:
            continue
        if why := response_mismatch(theirs, ours, f"--reference {reference}"):
            raise ConfigError(f"{press}: {why}")


def led_file_fits(leds: str, reference: Path) -> None:
    """One line, before any solving, when ``--leds`` is not an LED file or was calibrated on another sensor than
    the undeformed capture's (whose sensor every press shares, :func:`reference_fits`): the checks of ``nlips solve
    --leds FILE`` (:func:`nlipscalib.pipeline.check_fits_capture`), made once instead of failing every press."""
    from ..core.errors import ConfigError
    from ..pipeline import check_fits_capture, make_settings

    if Path(leds).suffix.lower() != ".json" and not Path(leds).is_file():
        raise ConfigError(
            f"--leds {leds}: no LED file (a .json file from `nlips calibrate-leds`); an LED subset such as 1,5,9 is "
            "for `nlips solve` (a calibration's samples need every LED)"
        )
    check_fits_capture(reference, make_settings(leds=leds))


def solve_all(
    presses: Sequence[Path],
    reference: Path,
    workers: int = 1,
    progress: bool = True,
    leds: str | None = None,
    normals: str = "depth",
    led_model: str = "auto",
) -> dict[str, str]:
    """NLiPs results for every press (PRESS/nlips) via the pipeline: parallel, resumable, concurrency-safe;
    presses already solved with the same options and inputs are skipped. ``leds``: an LED file from ``nlips
    calibrate-leds`` to solve with (None: each capture's LEDs); its LED values are part of a result's settings,
    so a result solved with other LEDs is solved again. ``normals``: ``SolverOptions.normals`` of the labels
    (a result with the other normals is solved again). ``led_model``: "auto", "points" or "disks" (the LED file's
    fitted disk emitters, or each capture's own LEDs as its design's disks; "auto":
    :func:`nlipscalib.pipeline.settings.for_press`; ``nlips solve --led-model``; recorded in a result's settings, so a
    result of the other is solved again).

    The dataset needs every press's result, so a press another run (a second ``nlips calibrate`` or
    ``nlips solve`` on the folder) is solving is waited for (``wait=True``) rather than skipped: its
    result is reused when it was made with these settings, and the press is solved here when that run
    failed, died or used other settings.
    """
    from ..pipeline import solve_presses
    from ..solver import SolverOptions

    return solve_presses(
        presses,
        reference=reference,
        roi="auto",
        leds=leds,
        options=SolverOptions(normals=normals),
        workers=workers,
        progress=progress,
        figures=False,
        wait=True,
        led_model=led_model,
    )
