"""``nlips solve PRESS``: NLiPs reconstruction of a press (or a folder of presses), saved in PRESS/nlips/."""

from __future__ import annotations

import argparse
import dataclasses
import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING

from .options import SOLVE_WORKERS_HELP, add_allow_edited, add_led_model

if TYPE_CHECKING:  # named in hints only: the solver is imported when a press is solved
    from pathlib import Path

    from ..solver import SolverOptions

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "solve",
        help="reconstruct depth/normals of a press with near-light photometric stereo",
        description="NLiPs: the normals, depth and albedo of a press (or of every press of a folder, whose "
        "reference/ is then the undeformed dome) from its LED images, written to PRESS/nlips/ (docs/formats.md) "
        "with PNG maps. A result made with the same settings and inputs is kept (the log says so); other "
        "options, LEDs, ROI or reference re-solve it (the log says what changed). Score it with `nlips eval`.",
    )
    p.add_argument("press", nargs="?", help="press folder, or a folder of press folders")
    p.add_argument(
        "--roi",
        nargs="+",
        metavar="V",
        help="x0 y0 w h (pixels, as 4 values or x0,y0,w,h) or 'auto': the box around the pixels whose images differ "
        "from the undeformed dome's (the contact), plus an 8-pixel margin (wider where too little undeformed gel is "
        "left in it to anchor the depth, and over a large contact's flank); much faster than the whole gel. "
        "A press without contact is refused with "
        "what to do (a folder's: noted, the others solved). Default: the whole gel",
    )
    p.add_argument(
        "--leds",
        help="LED subset '1,2,5' (1-based) or an LED JSON file from calibrate-leds "
        "(default: every LED, as meta.json records them)",
    )
    p.add_argument(
        "--reference",
        metavar="REF_PRESS",
        help="press folder of the undeformed dome (same camera, LEDs, exposure): the interreflection term is "
        "fitted on it, --roi auto / anchoring compare to it, and each LED image's brightness is checked against it, "
        "to warn of auto exposure or white balance left on; its light is scaled by the press's overall brightness "
        "over it (LEDs aged, exposure or gain changed since: report.json reference_gain) "
        "(default: PRESS/reference when PRESS is a folder of "
        "presses that has one, as `nlips dataset` and `nlips capture` write; else the press itself, away from the "
        "contact)",
    )
    p.add_argument(
        "--interreflection",
        choices=("auto", "on", "off"),
        default="auto",
        help="the gel's own diffuse interreflection in the image model: auto (applied when the data show "
        "indirect light; default), on, off",
    )
    p.add_argument("--bounces", type=int, choices=(1, 2), default=1, help="diffuse bounces modelled (default 1)")
    p.add_argument(
        "--dent-interreflection",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="re-solve with the indirect light of the solved surface until the normals settle (default on); "
        "off: only the undeformed surface's indirect light is subtracted",
    )
    p.add_argument(
        "--coating-reflectance",
        dest="coating_albedo",
        type=float,
        default=None,
        metavar="A",
        help="the coating's diffuse reflectance (0-1] when known, in place of the one fitted from the data "
        "(default: fitted); formerly --coating-albedo, still accepted",
    )
    # the former name, kept for scripts; one name per idea in the help (calibrate-leds says "reflectance")
    p.add_argument("--coating-albedo", dest="coating_albedo", type=float, default=None, help=argparse.SUPPRESS)
    p.add_argument(
        "--backend",
        choices=("numpy", "torch"),
        default="numpy",
        help="array library of the solver's per-pixel model: numpy (default) or torch (the same equations and "
        "results, on a GPU when present; measured 4x slower there than numpy: the sparse solves stay on the CPU)",
    )
    p.add_argument(
        "--normals",
        choices=("depth", "refined"),
        default=None,
        help="normals of the result: depth (the solved depth's gradient; default) or refined (each pixel's refitted "
        "to its own images where they reject the depth's, the depth kept: for steep relief such as a coin's; "
        "solver.normals in --config)",
    )
    p.add_argument(
        "--allow-sensor-misfit",
        dest="check_sensor",
        action="store_false",
        help="solve a press whose images do not fit the sensor its meta.json and reference.npz describe (refused by "
        "default: files copied from another sensor); for a sensor known to be built a few percent off its "
        "description. The result's report.json records it (sensor_check, and the settings' check_sensor); "
        "calibrating the LEDs (nlips calibrate-leds, --leds) usually fits such a sensor without it",
    )
    p.add_argument(
        "--keep-led-order",
        dest="reorder_leds",
        action="store_false",
        help="solve LED images that show other LEDs' light (a wiring error: two swapped, or a cycle) in the order "
        "captured; by default they are solved in the order they show, with a warning and report.json's led_order. "
        "Neighbours' images exchanged (their light too alike to reorder by; or the --reference capture's) are "
        "refused by default, naming both images; with this flag solved as captured, with a warning and report.json's "
        "leds_exchanged",
    )
    add_led_model(p)
    p.add_argument("--out", help="output folder (default PRESS/nlips); only for a single press")
    p.add_argument("--overwrite", action="store_true", help="re-solve even if an identical result exists")
    p.add_argument("--config", help="TOML/YAML file with SolverOptions fields")
    p.add_argument(
        "--workers",
        type=int,
        default=0,
        help=SOLVE_WORKERS_HELP,
    )
    p.add_argument(
        "--figures",
        choices=("none", "maps", "full"),
        default="maps",
        help="figures next to the result: maps (PNG normal/depth/residual/error maps, fast; default), "
        "full (plus a matplotlib summary sheet), none",
    )
    p.add_argument("--no-figures", dest="figures", action="store_const", const="none", help="same as --figures none")
    add_allow_edited(p, "solve")
    p.add_argument("--no-progress", action="store_true", help="no progress bars (they are off anyway when not a TTY)")
    p.set_defaults(func=run)


SOLVER_KEYWORDS = (
    "dent_interreflection",
    "coating_albedo",
    "interreflection",
    "bounces",
    "check_sensor",
    "reorder_leds",
)
"""Flags of this parser passed as keywords to solver.solve_press (add a flag above, then its name here)."""


def parse_roi(values: Sequence[str] | None) -> str | tuple[int, ...] | None:
    from ..core.errors import ConfigError

    if not values:
        return None
    parts = " ".join(values).replace(",", " ").split()  # "2 3 40 30", "2,3,40,30" and "2, 3, 40, 30" alike
    if parts == ["auto"]:
        return "auto"
    try:
        roi = tuple(int(v) for v in parts)
    except ValueError:
        roi = ()
    if len(roi) != 4:
        raise ConfigError(f"--roi needs 'x0 y0 w h' or 'auto', got {' '.join(values)}")
    return roi


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..core.config import check_count, from_mapping, read_config_file
    from ..core.errors import ConfigError
    from ..core.press_checksums import check_unchanged
    from ..core.press_folders import no_presses_error, split_reference
    from ..core.press_meta import REFERENCE_FOLDER, read_meta
    from ..pipeline import SKIPPED, SOLVED, make_settings, result_dir, solve_one, solve_presses
    from ..pipeline.provenance import identity_in_background
    from ..progress import BATCH, press_lines, print_result
    from . import imports_frozen
    from .folders import check_one_capture, check_undeformed

    _press_after_roi(args)
    identity_in_background(args.press, args.reference)  # beside the solver's import, which follows
    with imports_frozen():  # the solver's modules: no collection while they are imported, none of them walked later
        _decode_ahead(args)  # beside it too
        from ..solver import SolverOptions

    options = from_mapping(SolverOptions, read_config_file(args.config), args.config) if args.config else None
    if args.normals is not None:  # the flag over the config's value
        options = dataclasses.replace(options or SolverOptions(), normals=args.normals)
    check_count("--workers", args.workers, minimum=0)
    presses, reference = split_reference(args.press, args.reference)
    if args.reference is not None:  # before "no press": the press given as its own --reference leaves none
        check_one_capture(args.reference, "the undeformed dome's capture (--reference)")
        own = Path(args.press or ".")  # a folder of presses holds its reference/, a press lies beside it
        own = own / REFERENCE_FOLDER if (own / REFERENCE_FOLDER).is_dir() else own.parent / REFERENCE_FOLDER
        check_undeformed(
            args.reference, "the undeformed dome's capture (--reference)", "or solve without --reference", own
        )
    if not presses and reference is not None and Path(args.press).resolve() == Path(reference).resolve():
        raise ConfigError(
            f"{args.press}: given as the press and as its --reference; --reference names the undeformed dome's "
            "capture (another folder), or solve without --reference"
        )
    if not presses:
        raise no_presses_error(args.press)
    if reference is not None:
        read_meta(reference)  # a missing or broken --reference is one line now, not one failure per press
    if not args.allow_edited:  # a file copied over one: one line now, not a solve of the wrong image
        check_unchanged([*presses, reference] if reference is not None else presses)
    if args.config:  # --normals alone sets no min_leds
        _check_min_leds(options, presses[0], args.config)
    if args.out and len(presses) > 1:
        raise ConfigError("--out only applies to a single press")
    if reference is not None and args.reference is None:
        log.info("%s: the undeformed dome's capture, used as --reference (not solved as a press)", reference)
    given = {
        "reference": reference,
        "roi": parse_roi(args.roi),
        "leds": args.leds,
        "options": options,
        "backend": args.backend,
        "solver_keywords": {k: getattr(args, k) for k in SOLVER_KEYWORDS if hasattr(args, k)},
        "led_model": args.led_model,
    }
    progress = not args.no_progress
    if len(presses) == 1:  # one press: its errors are the command's (one line, exit 2)
        settings = make_settings(**given)
        solve_one(
            presses[0],
            settings,
            out=args.out,
            overwrite=args.overwrite,
            progress=progress,
            figures=args.figures,
            wait=True,  # the result asked for: another run's is waited for, and reused only when made alike
        )
        print_result(result_dir(presses[0], args.out))  # stdout: where the result is, alone (the how is on stderr)
        return 0
    from ..core.cpus import SOLVE_ROI_MEMORY, SOLVE_WHOLE_MEMORY, solve_worker_count
    from ..core.press_meta import image_size

    # the count asked for (said when it likely exceeds the memory available), else the cores' lowered to memory's
    memory = SOLVE_WHOLE_MEMORY if given["roi"] is None else SOLVE_ROI_MEMORY
    workers = solve_worker_count(args.workers, memory, *image_size(presses[0]))
    press_lines(BATCH)  # a line per press; how each was solved with -v
    statuses = solve_presses(
        presses, workers=workers, overwrite=args.overwrite, progress=progress, figures=args.figures, **given
    )
    for press in presses:  # stdout: each result's folder, one a line (solved now or before)
        if statuses.get(press.name, statuses.get(str(press))) in (SOLVED, SKIPPED):  # keyed as pipeline._names
            print_result(result_dir(press))
    return _summary(statuses)


def _decode_ahead(args: argparse.Namespace) -> None:
    """Start decoding the press's images on the second core while the solver is imported (GIL-bound, ~0.2 s of
    CPU on the main thread), when the command names one press that it will solve: without ``--overwrite`` a
    result already at its output is most likely reused, and its images never read.

    SciPy's sparse modules are imported here too, for the same reason: the solver's modules import them only where
    they use them (a reused result, or ``import nlipscalib.solver``, never waits ~0.13 s for them), and a solve's
    own first use would import them either on pyamg's background thread, competing for the GIL with the press's
    loading and the solve's start (sphere1 auto 1.45 -> 1.48 s, benchmarks/RESULTS.md s21-imp), or on the main
    thread later, where the decoding no longer runs beside them."""
    from ..core.capture import prefetch_press
    from ..core.press_folders import is_press_folder
    from ..core.reconstruction import has_reconstruction, reconstruction_dir

    if is_press_folder(args.press) and (
        args.overwrite or not has_reconstruction(reconstruction_dir(args.press, args.out))
    ):
        prefetch_press(args.press)
        _heap_ahead(args.press)
        import scipy.sparse.linalg  # noqa: F401 -- beside the decoding, as the solver's import did (see above)


HEAP_AHEAD_SHARE = 0.7
"""Share of an auto-ROI solve's modelled array memory (:data:`..core.cpus.SOLVE_ROI_MEMORY` less its base) that
``nlips solve PRESS`` maps ahead. The model is the upper end at 640x480 (the cube press's peak RSS 0.58 GB; the
sphere's 0.42, the coin's 0.45 GB), and pages mapped beyond a solve's peak are CPU and memory spent for nothing: at the
whole model the sphere and coin took 0.06-0.07 s more CPU and 80-115 MB more memory; at 0.7 neither changed
(benchmarks/RESULTS.md, s32-pages)."""


def _heap_ahead(press: str) -> None:
    """Map the solve's memory ahead on the second core's idle share (:func:`..core.pages.populate_heap_ahead`):
    :data:`HEAP_AHEAD_SHARE` of an auto-ROI solve's modelled peak (:data:`..core.cpus.SOLVE_ROI_MEMORY`, the
    libraries left out); nothing when the press's meta.json cannot be read (the load reports it)."""
    from ..core.cpus import SOLVE_ROI_MEMORY
    from ..core.errors import NlipsError
    from ..core.pages import populate_heap_ahead
    from ..core.press_meta import image_size

    try:
        width, height = image_size(press)
    except (NlipsError, KeyError, TypeError, ValueError):
        return
    arrays = SOLVE_ROI_MEMORY.estimate(width, height) - SOLVE_ROI_MEMORY.base_bytes
    populate_heap_ahead(int(HEAP_AHEAD_SHARE * arrays))


def _check_min_leds(options: SolverOptions, press: Path, config: str) -> None:
    """ConfigError naming the config file when its ``min_leds`` exceeds the capture's LEDs: the solver's own
    check ("12 LEDs given; the solver needs at least min_leds=50") says neither where the value came from
    nor which press. The presses of one folder share a sensor, so the first stands for all."""
    from ..core.errors import CaptureError, ConfigError
    from ..core.press_meta import read_meta

    try:
        leds = read_meta(press)["leds"]
    except CaptureError:
        return  # the press's own failure is reported when it is solved
    if isinstance(leds, list) and options.min_leds > len(leds):
        raise ConfigError(f"{config}: solver.min_leds = {options.min_leds} exceeds the {len(leds)} LEDs of {press}")


def _press_after_roi(args: argparse.Namespace) -> None:
    """``nlips solve --roi auto PRESS``: the press folder follows --roi's values (it takes one or four), so
    argparse gave it to --roi; take it back."""
    from ..core.errors import ConfigError

    if args.press is None and args.roi and len(args.roi) in (2, 5):
        args.press = args.roi.pop()
    if args.press is None:
        raise ConfigError("the press folder is missing (nlips solve PRESS [options])")


def _summary(statuses: dict[str, str]) -> int:
    """Say one line of counts (and the failed presses, and those without contact) on stderr; exit code 1 when any
    failed (a press without contact is not a failure: nothing to solve)."""
    from ..pipeline.status import BROKEN
    from ..progress import say

    failed = {name: s for name, s in statuses.items() if s.startswith("failed")}
    flat = [name for name, s in statuses.items() if s.startswith("no contact")]
    solved = sum(s == "solved" for s in statuses.values())
    skipped = len(statuses) - solved - len(failed) - len(flat)
    # what to do too: each is a press too light to show, or a capture of the undeformed dome among the presses,
    # which needs no solve: a folder solve with --roi auto has its reference (reference/ or --reference) already
    todo = "press deeper and capture again, or leave a capture of the undeformed dome out of the folder"
    without = f", {len(flat)} without contact (nothing solved: {', '.join(flat)}: {todo})" if flat else ""
    say(f"{solved} solved, {skipped} skipped (identical result), {len(failed)} failed{without}", warning=bool(failed))
    # a press's error was logged as it happened (an ERROR line, on stderr and in the --log-file): said again here,
    # each came twice; only the presses a killed solver process left (one line for them all) are named with why
    said = [name for name, status in failed.items() if status != BROKEN]
    if said:
        say(f"  failed, each said above: {', '.join(said)}", warning=True)
    for name, status in failed.items():
        if status == BROKEN:
            say(f"  {name}: {status}", warning=True)
    return 1 if failed else 0
