"""Rendering a dataset's jobs into its folder: parallel (worker processes, each with its share of the cores) and
resumable, from several processes at once.

A press whose folder is complete is never rendered again, and interrupted writes leave only ``.tmp-*``
folders, which are cleaned before the run. A press folder without meta.json (a partial copy, a
deleted file) is incomplete: the process that claims the press removes it and renders it again; so is
one that lost a file its meta.json lists (an image, reference.npz, gt.npz), or whose file is cut short or changed
since it was written (its size, with ``verify`` its CRC-32, against the press's checksums.json), rendered again in
its place.
"""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import shutil
import time
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING

from ..core import said_once
from ..core.atomic import check_free_space, check_writable, clean_interrupted
from ..core.claims import CLAIM_STALE_S
from ..core.cpus import RENDER_MEMORY, usable_cores, worker_count
from ..core.errors import NUMBER, PATH, ConfigError, NlipsError, check_flag, check_kind, check_paths, check_whole
from ..core.main_guard import check_main_guarded
from ..core.press_folders import is_press_folder
from ..core.press_meta import META_FILE
from ..core.processes import end_processes, end_with_parent, sigint_held, worker_signals
from ..progress import FILE_ONLY, SINGLE, configure_worker, progress_bar, worker_logging
from .dataset_folder import (
    changed_error,
    check_existing,
    described_missing,
    is_complete,
    live_claim_inside,
    missing_files,
    results_inside,
    same_spec,
    torn_own_meta,
)
from .dataset_spec import PressJob
from .scene import SceneConfig

if TYPE_CHECKING:  # named in hints only
    from tqdm import tqdm

log = logging.getLogger(__name__)
PNG_BYTES_PER_PIXEL = 3.5
"""One stored 16-bit RGB image (an LED's, the dark or the tri-colour frame) per pixel as written: 3.32-3.47 on
average over a press's 14 PNGs (6 uncompressed: the noise's low bits do not compress), measured on 19 presses of
the default twin (sphere, cube and coin; 160x120, 320x240 at 4-16 spp, 640x480 at 16 spp), 2026-12-05."""
NPZ_BYTES_PER_PIXEL = 39.5
"""gt.npz and reference.npz together per pixel as written (deflated at level 1): 38.95-39.32 on the same presses
(46 uncompressed)."""
META_BYTES = 8 << 10
"""A press's meta.json: 7.0-7.5 KiB."""
BLOCK_BYTES = 4 << 10
"""What a file may take beyond its bytes: it fills whole blocks of the disk (4 KiB on ext4 and tmpfs)."""
PRESS_SIZE_MARGIN = 1.1
"""Above the largest measured sizes, for scenes whose images hold more noise or light than the default twin's
(PNG sizes follow the content; the PNGs are 55 % of a press, so 10 % of the whole is 18 % of them). The estimate is
13 % above what the measured presses took on the disk, 160x120 to 640x480: only a disk with room for one press but
not 13 % more is refused for nothing. No larger margin: an underestimate costs only a render that stops at its first
failed write (the run stops, nothing half-written is kept), an overestimate refuses a run that fits. The earlier
bound, uncompressed (130 bytes per pixel, 2437 KiB at 160x120), refused a run with 2188 KiB free for presses of
1.62-1.67 MB."""
BUSY_POLL_S = 1.0
"""Seconds between checks on presses another process is rendering."""


def run_dataset(
    scene: SceneConfig,
    jobs: list[PressJob],
    out: str | Path,
    workers: int = 0,
    progress: bool = True,
    overwrite: bool = False,
    stale_s: float = CLAIM_STALE_S,
    verify: bool = False,
) -> dict:
    """Render every job not yet done into ``out``; returns {"rendered", "skipped", "failed"} lists.

    Several processes (terminals, cluster array jobs, machines sharing the disk) may run this on one
    folder at once: each press is claimed (core.claims) before it is rendered, a press another live
    process holds is left to it (and waited for, in case that process dies), and a finished press is
    never rendered again nor replaced. An OSError (disk full, read-only, permission, name too long)
    stops the run at the first failure and is raised; other per-press errors are reported in
    ``failed`` and the rest goes on.

    Parameters
    ----------
    workers : processes (0 = one per two cores, at least 1); each gets cores // workers threads.
    overwrite : re-render presses whose folder was made from a different spec (else that is an error)
    stale_s : seconds without heartbeat after which another process's claim is taken over (every process
        rendering into ``out`` must use the same: keep the default, :data:`nlipscalib.core.claims.CLAIM_STALE_S`)
    verify : read every byte of each finished press's files and compare their CRC-32 with its checksums.json (a
        press that differs is rendered again); else their ends and sizes only (core.press_checksums)
    """
    jobs = _check_arguments(scene, jobs, out, workers, stale_s)
    for name, flag in (("progress", progress), ("overwrite", overwrite), ("verify", verify)):
        check_flag(flag, name)
    out = Path(out)
    with said_once.scope():  # each call warns of older renders again; inside a command, once with its own check
        check_existing(scene, jobs, out, overwrite)
    todo = [j for j in jobs if not is_complete(scene, j, out, overwrite, verify)]
    result = {"rendered": [], "skipped": [j.name for j in jobs if j not in todo], "failed": []}
    if not todo:
        return result
    check_writable(out, longest_name=max(len(j.name) for j in todo))
    check_space(out, scene, len(todo))
    for stale in clean_interrupted(out):
        log.info("removed interrupted write %s", stale.name)
    cores = usable_cores()
    # one per two cores (each renders on two threads), fewer where memory holds fewer (1280x960: ~2.7 GB each)
    each = worker_count(workers, max(1, cores // 2), RENDER_MEMORY, scene.camera.width, scene.camera.height)
    workers = min(len(todo), each)
    scene = scene.replace(render={"threads": max(1, cores // workers)})
    with progress_bar(
        total=len(jobs), initial=len(result["skipped"]), unit="press", desc="rendering", enabled=progress
    ) as bar:
        if workers == 1:
            _rounds(todo, lambda job: _render_job(scene, job, out, overwrite, stale_s, verify), result, bar)
        else:
            check_main_guarded(f"rendering presses in {workers} processes (workers={workers})")
            with ProcessPoolExecutor(
                workers, mp_context=get_context("spawn"), initializer=_worker_init, initargs=worker_logging()
            ) as pool:

                def submit(job: PressJob) -> Future:
                    with sigint_held():  # a render process it starts never sees Ctrl-C (_worker_init)
                        return pool.submit(_render_job, scene, job, out, overwrite, stale_s, verify)

                try:
                    _rounds(todo, submit, result, bar, pool=True)
                except BrokenProcessPool:
                    raise NlipsError(
                        f"{out}: a render process died (out of memory, or killed); finished presses are kept, "
                        "run again to resume (fewer --workers needs less memory)"
                    ) from None
                except KeyboardInterrupt:
                    _stop_pool(pool)
                    raise
                except BaseException:  # an error: the renders under way finish (and are kept)
                    pool.shutdown(wait=True, cancel_futures=True)
                    raise
    return result


def _check_arguments(scene: object, jobs: object, out: object, workers: object, stale_s: object) -> list[PressJob]:
    """``jobs`` as a list; an NlipsError naming the argument of :func:`run_dataset` of another kind (or out of range),
    before any folder is looked at.

    Why: a scene's name or a dict for ``scene``, the spec for ``jobs``, ``out`` None or ``workers="2"`` failed in
    Python's AttributeError or TypeError from inside, and ``stale_s="60"`` or -1 was taken (s38-apikinds)."""
    check_kind(scene, SceneConfig, "scene", "a SceneConfig (load_scene(...), or load_dataset_spec(path)[1])")
    listed = check_paths(jobs, "jobs", "a list of PressJob (expand_jobs(spec))", PressJob, "a PressJob")
    check_kind(out, PATH, "out", "the dataset folder's path (str or Path)")
    check_whole(workers, "workers", minimum=0)  # 0: one per two cores
    check_kind(stale_s, NUMBER, "stale_s", "a number of seconds")
    if not stale_s > 0:
        raise ConfigError(f"stale_s must be > 0 seconds, got {stale_s}")
    return listed


def press_bytes(scene: SceneConfig) -> int:
    """One press folder's size on disk as a render writes it (16-bit RGB PNGs, gt.npz, reference.npz, meta.json),
    with :data:`PRESS_SIZE_MARGIN`: 1.95 MB at 160x120 (presses took 1.71-1.72 MB of the disk), 30.0 MB at 640x480
    (26.3-26.5 MB)."""
    pixels = scene.camera.width * scene.camera.height
    n_images = len(scene.led_models()) + 2  # LEDs, dark, tri-colour
    n_files = n_images + 3  # + gt.npz, reference.npz, meta.json
    per_pixel = n_images * PNG_BYTES_PER_PIXEL + NPZ_BYTES_PER_PIXEL
    return int(pixels * per_pixel * PRESS_SIZE_MARGIN) + META_BYTES + n_files * BLOCK_BYTES


def check_space(out: Path, scene: SceneConfig, n_presses: int) -> None:
    """No room for even one press: fail now (ENOSPC). Room for some only: warn how many fit and that the run will
    stop when the disk is full."""
    need = press_bytes(scene)
    free = check_free_space(out, need, "a press" if n_presses == 1 else f"each of the {n_presses} presses")
    if free < need * n_presses:
        log.warning(
            "%s: %d MiB free, room for ~%d of the %d presses (~%.1f MiB each): the run will stop when the disk is full",
            out,
            free >> 20,
            free // need,
            n_presses,
            need / (1 << 20),
        )


# ---------------------------------------------------------------------- internals
def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Ctrl-C: end the render processes now (each releases its claim and removes its half-written press folder,
    :func:`nlipscalib.core.processes.worker_signals`) and start no other press.

    Why not ``pool.shutdown(wait=True)``: it waited for the renders under way, tens of seconds each at 640x480.
    Finished presses are kept; the interrupted ones are rendered again by the next run.
    """
    end_processes(list(pool._processes.values()))  # the pool's processes: no public accessor before Python 3.14
    pool.shutdown(wait=True, cancel_futures=True)  # its manager thread, which finds them gone, ends


def _worker_init(log_level: int, log_file: str | None = None, press_lines: int = SINGLE, quiet: bool = False) -> None:
    """A render process: logs like the parent; ignores Ctrl-C, which the parent answers by ending it (a terminal
    sends Ctrl-C to every process of the command: a render process died of it with a traceback of its own, or
    waited at its exit for the render it interrupted); on SIGTERM (sent by a stopped ``nlips dataset``, or to the
    whole process group) releases its claim and removes its half-written press folder, then exits, as the parent
    does. The handler runs at once, a render being on a thread of its own (``sim.render.interruptible``); ended with
    ``os._exit``, as an exception raised there could land inside the library."""
    configure_worker(log_level, log_file, press_lines, quiet)
    worker_signals()
    end_with_parent()  # a command killed with SIGKILL cannot end this render process: it ends itself


def _rounds(
    todo: list[PressJob], start: Callable[[PressJob], object], result: dict, bar: tqdm, pool: bool = False
) -> None:
    """Run jobs; jobs busy in another process are retried until done or taken over (owner died)."""
    waited = False
    while todo:
        if pool:
            futures = {start(job): job for job in todo}
            outcomes = ((futures[f], f.result()) for f in as_completed(futures))
        else:
            outcomes = ((job, start(job)) for job in todo)
        busy = []
        for job, (status, detail) in outcomes:
            if status == "oserror":
                raise OSError(*detail)
            if status == "changed":  # another run published it from its own spec: refused, as before a run
                raise ConfigError(detail)
            if status == "busy":
                busy.append(job)
                continue
            result["failed" if status == "failed" else status].append(
                (job.name, detail) if status == "failed" else job.name
            )
            if status == "failed":
                log.error("%s failed: %s", job.name, detail)
            # in the --log-file (stderr: -v) with how far the run got: a long render's file held only its end
            done = sum(len(result[key]) for key in ("rendered", "skipped", "failed"))
            log.info("press %s: %s (%d of %s)", job.name, status, done, bar.total, extra=FILE_ONLY)
            bar.update(1)
        if busy:
            (log.info if not waited else log.debug)(
                "waiting for %d press(es) another process is rendering (taken over if it dies)", len(busy)
            )
            waited = True
            time.sleep(BUSY_POLL_S)
        todo = busy


def _render_job(
    scene: SceneConfig, job: PressJob, out: Path, overwrite: bool, stale_s: float, verify: bool = False
) -> tuple[str, object]:
    """Worker body: claim, render, release. Returns (status, detail); errors must not kill the pool.

    status is "rendered", "skipped" (finished meanwhile by another process), "busy" (another live
    process holds it), "changed" (detail: the error line; without ``overwrite``, the press was rendered
    meanwhile by a run of another spec), "failed" (detail: the error text) or "oserror" (detail: errno,
    text, path).
    """
    from ..core.claims import claim

    try:
        with claim(out / job.name, stale_s=stale_s) as mine:
            if not mine:
                return "busy", None
            if is_complete(scene, job, out, overwrite, verify):
                return "skipped", None
            clean_interrupted(out, item=job.name)  # a dead owner's half-written folder, if any
            folder = out / job.name
            replace = overwrite
            if is_press_folder(folder):
                torn = torn_own_meta(scene, job, out)
                if not torn and not overwrite and not same_spec(scene, job, out):
                    return "changed", changed_error(scene, job, out)
                missing = {} if torn else missing_files(folder, verify)
                if torn or missing:
                    # torn: its own render (dataset.json lists it), so made again as a torn image is
                    said = f"{META_FILE} damaged ({torn}; the dataset's own press)" if torn else None
                    said = said or described_missing(missing)
                    busy = live_claim_inside(folder)
                    if busy:
                        short = said if torn else described_missing(missing, most=1)
                        return "failed", f"{folder}: {short}, but {busy}; run again when it is done"
                    results = results_inside(folder)
                    log.warning(
                        "%s: %s; rendering it again%s",
                        folder,
                        said,
                        f" (its results {', '.join(results)} go with it)" if results else "",
                    )
                    replace = True
            elif folder.exists():
                busy = live_claim_inside(folder)
                if busy:
                    return "failed", f"{folder}: incomplete (no {META_FILE}), but {busy}; run again when it is done"
                log.warning("%s: incomplete press folder (no %s): removed, rendering it again", folder, META_FILE)
                _remove_incomplete(folder)
            _run_one(scene, job, out, replace)
            return "rendered", None
    except FileExistsError:  # published by a process that lost its claim: the folder is whole
        if is_press_folder(out / job.name) and not overwrite and not same_spec(scene, job, out):
            return "changed", changed_error(scene, job, out)
        return "skipped", None
    except OSError as exc:
        return "oserror", (exc.errno, exc.strerror or str(exc), exc.filename or str(out / job.name))
    except Exception as exc:  # reported per press; the other presses go on
        return "failed", f"{type(exc).__name__}: {exc}"


def _run_one(scene: SceneConfig, job: PressJob, out: Path, overwrite: bool = False) -> None:
    from .press import render_press

    render_press(scene, job.press, out / job.name, seed=job.seed, overwrite=overwrite)


def _remove_incomplete(folder: Path) -> None:
    """Remove a press folder without meta.json; the caller holds the press's claim.

    The folder is first renamed to a temporary name owned by this process (so a clean-up elsewhere
    removes what is left if this process dies while deleting), then deleted. A complete folder that
    another process published in the instant between the check and the rename (possible only over an
    empty folder) is put back.
    """
    from ..core.atomic import tmp_prefix

    aside = folder.with_name(tmp_prefix(folder.name) + "incomplete-" + secrets.token_hex(4))
    try:
        os.rename(folder, aside)
    except FileNotFoundError:
        return
    if is_press_folder(aside):
        with contextlib.suppress(OSError):  # else a duplicate: cleaned as this process's leftover
            os.rename(aside, folder)
        return
    if aside.is_dir() and not aside.is_symlink():
        shutil.rmtree(aside)
    else:
        aside.unlink()
