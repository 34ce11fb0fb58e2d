"""``nlips dataset SPEC --out DIR``: render many presses in parallel, resumably, from several processes at once."""

from __future__ import annotations

import argparse
import contextlib
import logging
from typing import TYPE_CHECKING

from .options import RENDER_WORKERS_HELP

if TYPE_CHECKING:  # named in hints only
    from collections.abc import Iterable
    from pathlib import Path

    from ..sim.dataset import DatasetSpec, PressJob
    from ..sim.scene import SceneConfig

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "dataset",
        help="render many presses from a dataset spec (grid or random), in parallel, resumable",
        description="Render every press of a dataset spec (a TOML/YAML file, or a shipped spec's name). "
        "Presses already rendered are skipped, so an interrupted run resumes where it stopped. Several "
        "runs of one spec (terminals, cluster array jobs, machines sharing the disk) may fill one folder at once: "
        "each press is claimed by one of them and rendered exactly once. A run of another spec is refused while "
        "one is at work in the folder, so that it never holds presses of two specs. A spec's keys, and a small "
        'try-out spec (six presses at 160x120): docs/formats.md, "Dataset spec".',
    )
    p.add_argument(
        "spec", help="dataset spec file, or a shipped spec's name: train50 (~50 presses) or demo (the demo's)"
    )
    p.add_argument("--out", required=True, help="folder that receives one press folder per press")
    p.add_argument(
        "--workers",
        type=int,
        default=0,
        help=RENDER_WORKERS_HELP,
    )
    p.add_argument(
        "--limit",
        type=int,
        default=0,
        help="render only the first N presses of the spec (default 0: all); the reference, when the spec asks for one, "
        "is rendered too and not counted",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="re-render the presses that another spec (by a run that has ended), other twin code or another "
        "Mitsuba made, and damaged ones; presses of this very spec are kept (delete one to render it anew)",
    )
    p.add_argument(
        "--verify",
        action="store_true",
        help="read every byte of the presses already there and compare each file with the CRC-32 its press's "
        "checksums.json recorded when it was written: a press with a file changed inside (a bad disk block or "
        "copy) is rendered again. Without it a rerun compares each file's ends and size only (no image read); "
        "~25 ms a 640x480 press whose files are in memory, the disk's read rate when not",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .. import progress
    from ..core.config import check_count
    from ..core.long_paths import warn_if_too_long
    from ..sim.dataset import (
        claim_folder,
        expand_jobs,
        first_press_number,
        limit_presses,
        load_dataset_spec,
        spec_digest,
    )
    from ..sim.scene import dataset_spec_path
    from .folders import check_not_in_press

    check_count("--workers", args.workers, minimum=0)
    check_count("--limit", args.limit, minimum=0)
    spec, scene = load_dataset_spec(dataset_spec_path(args.spec))
    out = Path(args.out)
    check_not_in_press(out, "render the dataset")
    warn_if_too_long(out, "dataset")  # Windows' 260 characters: before the renders
    jobs = expand_jobs(spec, first=first_press_number(out))  # an old folder numbered from press_0000 keeps it
    todo = limit_presses(jobs, args.limit) if args.limit else jobs
    with claim_folder(out, spec_digest(spec, scene, jobs)):  # a run of another spec at work there: refused now
        result = _render(args, spec, scene, jobs, todo, out)
    if not result["failed"]:  # stdout: the dataset's folder alone, once no press failed (scripts); counts on stderr
        progress.print_result(out)
    failed = bool(result["failed"])
    # --verify's reads said: its line was a plain rerun's, so a user could not tell the check had been made
    checked = " (every file read, its CRC-32 checked)" if args.verify and result["skipped"] else ""
    progress.say(
        f"{out}: {_counted(result['rendered'])} rendered, {_counted(result['skipped'])} already there{checked}, "
        f"{_counted(name for name, _ in result['failed'])} failed",
        warning=failed,
    )
    if failed:  # each failure's error was logged as it happened (sim.dataset_pool): named here, not said twice
        progress.say("  failed, each said above: " + ", ".join(name for name, _ in result["failed"]), warning=True)
    return 1 if result["failed"] else 0


def _counted(names: Iterable[str]) -> str:
    """The summary's count of ``names``: "10 presses and the undeformed reference", "1 press", "the undeformed
    reference", "0" (none; a 10-press spec's first run said "11 rendered": the reference counted as a press)."""
    from ..sim.dataset_spec import REFERENCE_NAME

    names = list(names)
    if not names:
        return "0"
    count = sum(name != REFERENCE_NAME for name in names)
    presses = f"{count} press{'' if count == 1 else 'es'}"
    if REFERENCE_NAME not in names:
        return presses
    return f"{presses} and the undeformed reference" if count else "the undeformed reference"


def _render(
    args: argparse.Namespace,
    spec: DatasetSpec,
    scene: SceneConfig,
    jobs: list[PressJob],
    todo: list[PressJob],
    out: Path,
) -> dict:
    """Check the folder, write the manifest, render ``todo`` (the folder claimed for the spec); run_dataset's result."""
    from ..sim.dataset import check_existing, is_complete, run_dataset, warn_unlisted, write_manifest

    check_existing(scene, jobs, out, args.overwrite)  # before anything is written
    if out.is_dir():
        warn_unlisted(jobs, out)
    try:
        write_manifest(out, spec, scene, jobs)  # only if it changes: a finished dataset on read-only media re-checks
    except OSError as exc:
        if not all(is_complete(scene, job, out) for job in todo):
            raise
        log.warning("%s: could not write dataset.json (%s); the presses are complete", out, exc.strerror)
    progress = not args.no_progress
    result = run_dataset(
        scene, todo, out, workers=args.workers, progress=progress, overwrite=args.overwrite, verify=args.verify
    )
    if not result["failed"]:  # a run that takes no folder claim (an older nlips) may have written its own
        with contextlib.suppress(OSError):
            write_manifest(out, spec, scene, jobs)
    return result
