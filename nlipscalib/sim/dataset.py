"""Many presses from one spec: a grid (indenters x locations x depths) or a seeded random draw.

Rendering is parallel (worker processes, each with its share of the cores) and resumable: a press
whose folder is complete is never rendered again, and interrupted writes leave only ``.tmp-*``
folders, which are cleaned before the run. A press folder without meta.json (a partial copy, a
deleted file) is incomplete: the process that claims the press removes it and renders it again; so is
one that lost a file its meta.json lists (an image, reference.npz, gt.npz), rendered again in its place.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import hashlib
import itertools
import json
import logging
import os
import secrets
import shutil
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.atomic import check_writable, clean_interrupted, write_if_changed
from ..core.capture import META_FILE, REFERENCE_FOLDER, is_press_folder
from ..core.claims import CLAIM_STALE_S
from ..core.config import check_count, check_range, from_mapping, read_config_file
from ..core.cpus import usable_cores
from ..core.errors import CaptureError, ConfigError, NlipsError
from ..progress import configure_worker, progress_bar, worker_logging
from .indent import IndenterConfig, PressConfig
from .scene import SceneConfig, load_scene

if TYPE_CHECKING:  # named in hints only
    from types import FrameType

    from tqdm import tqdm

log = logging.getLogger(__name__)
REFERENCE_NAME = REFERENCE_FOLDER  # the name every folder of presses uses (core.capture)
MANIFEST = "dataset.json"
FOLDER_CLAIM = "dataset"
"""Target of the folder's claim by the runs of one spec (:func:`claim_folder`): files ``.claim-dataset*`` in it."""
GT_BYTES_PER_PIXEL = 4 + 12 + 12 + 2 + 4 + 12
"""gt.npz (depth, points, normals, masks) and reference.npz (depth, normals) per pixel, uncompressed."""
BUSY_POLL_S = 1.0
"""Seconds between checks on presses another process is rendering."""


@dataclasses.dataclass(frozen=True)
class GridSpec:
    """Every combination of the listed values."""

    indenters: tuple[IndenterConfig, ...]
    """Indenters to press."""
    polar_deg: tuple[float, ...] = (0.0,)
    """Press locations: polar angles from the dome axis, degrees."""
    azimuth_deg: tuple[float, ...] = (0.0,)
    """Press locations: azimuths from +x toward +y, degrees."""
    depth: tuple[float, ...] = (1.0,)
    """Indentation depths, mm."""
    spin_deg: tuple[float, ...] = (0.0,)
    """Rotations of the indenter about the press axis, degrees."""

    def __post_init__(self):
        _check_values(self, ranges=False)


@dataclasses.dataclass(frozen=True)
class RandomSpec:
    """``count`` presses drawn uniformly from the ranges, with the dataset's seed."""

    count: int
    """Number of presses."""
    indenters: tuple[IndenterConfig, ...]
    """Indenters to choose from (uniformly)."""
    polar_deg: tuple[float, float] = (0.0, 30.0)
    """Range of polar angles, degrees."""
    azimuth_deg: tuple[float, float] = (0.0, 360.0)
    """Range of azimuths, degrees."""
    depth: tuple[float, float] = (0.3, 1.5)
    """Range of depths, mm."""
    spin_deg: tuple[float, float] = (0.0, 360.0)
    """Range of spins, degrees."""

    def __post_init__(self):
        check_count("count", self.count, minimum=1)
        _check_values(self, ranges=True)
        for name in ("polar_deg", "azimuth_deg", "depth", "spin_deg"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ConfigError(f"{name}: the range [{lo}, {hi}] is empty (low > high)")


def _check_values(spec: GridSpec | RandomSpec, ranges: bool) -> None:
    """Shared range checks of grid values (``ranges`` False) and random ranges (True): polar angles, depths,
    indenters."""
    from .press import check_polar

    min_count = 2 if ranges else 1
    if not spec.indenters:
        raise ConfigError("indenters: give at least one indenter")
    for name in ("polar_deg", "azimuth_deg", "depth", "spin_deg"):
        if len(getattr(spec, name)) < min_count:
            raise ConfigError(f"{name}: give at least {min_count} value(s)")
    # every grid angle is pressed; a random range's high end only bounds the draw (uniform in [low, high))
    ends = spec.polar_deg[:1] if ranges else spec.polar_deg
    for v in ends:
        check_polar("polar_deg", v)
    for v in spec.polar_deg:
        check_range("polar_deg", v, 0.0, 90.0)
    for v in spec.depth:
        check_range("depth", v, 0.0, open_lo=True)


@dataclasses.dataclass(frozen=True)
class DatasetSpec:
    """What to render; exactly one of ``grid`` and ``random``."""

    scene: str = "nlipstac"
    """Scene file (relative to the spec file) or shipped scene name."""
    seed: int = 0
    """Seed of the random draw and of each press's render noise."""
    reference: bool = True
    """Also render the undeformed dome (folder ``reference``), e.g. for LED calibration."""
    render: dict = dataclasses.field(default_factory=dict)
    """Overrides of the scene's [render] section, e.g. {spp = 16, bounces = 1}."""
    noise: dict = dataclasses.field(default_factory=dict)
    """Overrides of the scene's [noise] section."""
    camera: dict = dataclasses.field(default_factory=dict)
    """Overrides of the scene's [camera] section, e.g. {width = 160, height = 120} for previews."""
    grid: GridSpec | None = None
    """``[grid]``: every combination of the listed indenters, locations, depths and spins (or None)."""
    random: RandomSpec | None = None
    """``[random]``: ``count`` presses drawn from ranges with the spec's ``seed`` (or None)."""

    def __post_init__(self):
        if (self.grid is None) == (self.random is None):
            raise ConfigError("give exactly one of [grid] and [random]")
        check_count("seed", self.seed, minimum=0)


@dataclasses.dataclass(frozen=True)
class PressJob:
    name: str
    press: PressConfig | None
    seed: int


def load_dataset_spec(path: str | Path) -> tuple[DatasetSpec, SceneConfig]:
    """Read a dataset spec file and the scene it names (render/noise/camera overrides applied)."""
    path = Path(path)
    spec = from_mapping(DatasetSpec, _meshes_beside(read_config_file(path), path.parent), str(path))
    scene_path = path.parent / spec.scene
    try:
        scene = load_scene(scene_path if scene_path.is_file() else spec.scene)
    except ConfigError as exc:  # an unknown scene name: the spec file that names it is the one to edit
        message = str(exc)
        raise ConfigError(message if message.startswith(str(path)) else f"{path}: {message}") from None
    sections = {k: v for k, v in (("render", spec.render), ("noise", spec.noise), ("camera", spec.camera)) if v}
    try:
        scene = scene.replace(**sections) if sections else scene
    except ConfigError as exc:  # an override out of range: name the spec file, not the scene
        raise ConfigError(f"{path}: {str(exc).removeprefix('scene.')}") from None
    _check_presses(spec, scene, path)
    return spec, scene


def _meshes_beside(data: dict, folder: Path) -> dict:
    """The raw spec with relative indenter mesh paths found beside the spec file (``indenters.with_mesh_beside``)."""
    from .indenters import with_mesh_beside

    for mode in ("grid", "random"):
        section = data.get(mode)
        if isinstance(section, dict) and isinstance(section.get("indenters"), list):
            indenters = [with_mesh_beside(ind, folder) for ind in section["indenters"]]
            data = data | {mode: section | {"indenters": indenters}}
    return data


def _check_presses(spec: DatasetSpec, scene: SceneConfig, path: Path) -> None:
    """Cheap checks of every press against the scene, so a bad one fails now, naming the spec file."""
    from .indenters import make_indenter

    mode = "grid" if spec.grid else "random"
    for i, ind in enumerate((spec.grid or spec.random).indenters):
        if ind.kind == "mesh":
            try:
                make_indenter(ind)
            except ConfigError as exc:
                raise ConfigError(f"{path}: {mode}.indenters[{i}]: {exc}") from None
    depths = spec.grid.depth if spec.grid else spec.random.depth
    if max(depths) > scene.dome.thickness:
        raise ConfigError(f"{path}: {mode}.depth: {max(depths)} mm exceeds the gel thickness {scene.dome.thickness} mm")


def expand_jobs(spec: DatasetSpec) -> list[PressJob]:
    """The presses of a spec, in a fixed order, each with its own seed."""
    presses = _grid_presses(spec.grid) if spec.grid else _random_presses(spec.random, spec.seed)
    seeds = np.random.SeedSequence(spec.seed).generate_state(len(presses) + 1)
    jobs = [PressJob(f"press_{i:04d}", p, int(s)) for i, (p, s) in enumerate(zip(presses, seeds[1:]))]
    if spec.reference:
        jobs.insert(0, PressJob(REFERENCE_NAME, None, int(seeds[0])))
    return jobs


def limit_presses(jobs: list[PressJob], limit: int) -> list[PressJob]:
    """The reference (if any) and the first ``limit`` presses of ``jobs`` (``--limit`` counts presses only)."""
    presses = [j.name for j in jobs if j.press is not None][:limit]
    return [j for j in jobs if j.press is None or j.name in presses]


def run_dataset(
    scene: SceneConfig,
    jobs: list[PressJob],
    out: str | Path,
    workers: int = 0,
    progress: bool = True,
    overwrite: bool = False,
    stale_s: float = CLAIM_STALE_S,
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
    """
    out = Path(out)
    if workers < 0:
        raise ConfigError(f"workers must be >= 0 (0 = automatic), got {workers}")
    check_existing(scene, jobs, out, overwrite)
    todo = [j for j in jobs if not is_complete(scene, j, out)]
    result = {"rendered": [], "skipped": [j.name for j in jobs if j not in todo], "failed": []}
    if not todo:
        return result
    check_writable(out, longest_name=max(len(j.name) for j in todo))
    check_space(out, scene, len(todo))
    for stale in clean_interrupted(out):
        log.info("removed interrupted write %s", stale.name)
    cores = usable_cores()
    workers = min(len(todo), workers or max(1, cores // 2))
    scene = scene.replace(render={"threads": max(1, cores // workers)})
    with progress_bar(
        total=len(jobs), initial=len(result["skipped"]), unit="press", desc="rendering", enabled=progress
    ) as bar:
        if workers == 1:
            _rounds(todo, lambda job: _render_job(scene, job, out, overwrite, stale_s), result, bar)
        else:
            with ProcessPoolExecutor(
                workers, mp_context=get_context("spawn"), initializer=_worker_init, initargs=worker_logging()
            ) as pool:
                submit = lambda job: pool.submit(_render_job, scene, job, out, overwrite, stale_s)  # noqa: E731
                try:
                    _rounds(todo, submit, result, bar, pool=True)
                except BrokenProcessPool:
                    raise NlipsError(
                        f"{out}: a render process died (out of memory, or killed); finished presses are kept, "
                        "run again to resume (fewer --workers needs less memory)"
                    ) from None
                except BaseException:
                    pool.shutdown(wait=True, cancel_futures=True)
                    raise
    return result


def press_bytes(scene: SceneConfig) -> int:
    """Rough upper bound of one press folder's size on disk: 16-bit RGB images + ground truth + reference."""
    pixels = scene.camera.width * scene.camera.height
    n_images = len(scene.led_models()) + 2  # LEDs, dark, tri-colour
    return pixels * (n_images * 6 + GT_BYTES_PER_PIXEL)


def check_space(out: Path, scene: SceneConfig, n_presses: int) -> None:
    """No room for even one press: fail now (ENOSPC). Room for some only: warn that the run will stop."""
    free = shutil.disk_usage(out).free
    need = press_bytes(scene)
    if free < need:
        raise OSError(
            errno.ENOSPC, f"No space left on device ({free >> 10} KiB free, a press needs ~{need >> 10} KiB)", str(out)
        )
    if free < need * n_presses:
        log.warning(
            "%s: %d MiB free, the %d presses may need up to %d MiB: the run will stop when the disk is full",
            out,
            free >> 20,
            n_presses,
            (need * n_presses) >> 20,
        )


def manifest_text(spec: DatasetSpec, scene: SceneConfig, jobs: list[PressJob]) -> str:
    """dataset.json's content: what was asked (the whole spec, whatever ``--limit`` renders)."""
    from ..core.config import to_mapping

    data = {
        "spec": to_mapping(spec),
        "scene": scene.to_dict(),
        "presses": [{"name": j.name, "seed": j.seed, "press": to_mapping(j.press)} for j in jobs],
    }
    return json.dumps(data, indent=2) + "\n"


def write_manifest(out: Path, spec: DatasetSpec, scene: SceneConfig, jobs: list[PressJob]) -> bool:
    """Write dataset.json beside the presses, only if its content changes (read-only re-checks work)."""
    return write_if_changed(out / MANIFEST, manifest_text(spec, scene, jobs))


def spec_digest(spec: DatasetSpec, scene: SceneConfig, jobs: list[PressJob]) -> str:
    """What tells one spec's dataset from another's (hex, 16 digits): the manifest, and each press's render hash
    (which also counts the content of an indenter's mesh file, the manifest naming only its path)."""
    from .press import render_spec_hash

    digest = hashlib.sha256(manifest_text(spec, scene, jobs).encode())
    for job in jobs:
        digest.update(render_spec_hash(scene, job.press, job.seed).encode())
    return digest.hexdigest()[:16]


@contextlib.contextmanager
def claim_folder(out: Path, digest: str) -> Iterator[None]:
    """Hold ``out`` for the spec of ``digest`` while the block runs; a ConfigError, before anything is written, when
    a live run of another spec holds it.

    Why: two runs of different specs started together into one folder each published presses before either found
    the other's, and left a dataset of two specs. Runs of one spec share the folder (they split its presses); a
    killed run's claim goes stale (core.claims), and ``--overwrite`` does not pass a live run of another spec (it
    re-renders what a finished run left). A folder that cannot hold a claim file (read-only media, disk full) is
    not claimed: nothing can be published there either, and the checks that follow say why in their own words.
    """
    from ..core.claims import claim_shared

    with contextlib.ExitStack() as stack:
        try:
            other = stack.enter_context(claim_shared(out / FOLDER_CLAIM, digest))
        except OSError as exc:
            log.debug("%s: not claimed for this spec (%s)", out, exc.strerror or exc)
            other = None
        if other is not None:
            who = f"process {other.pid} on {other.host}" if other.pid else "another process"
            raise ConfigError(
                f"{out}: a run of a different spec is rendering into it ({who}); wait until it ends, "
                "or render into a new folder"
            )
        yield


# ---------------------------------------------------------------------- internals
def _grid_presses(grid: GridSpec) -> list[PressConfig]:
    combos = itertools.product(grid.indenters, grid.polar_deg, grid.azimuth_deg, grid.depth, grid.spin_deg)
    return [
        PressConfig(indenter=ind, polar_deg=polar, azimuth_deg=az, spin_deg=spin, depth=depth)
        for ind, polar, az, depth, spin in combos
    ]


def _random_presses(spec: RandomSpec, seed: int) -> list[PressConfig]:
    rng = np.random.default_rng(seed)
    u = lambda lo_hi: float(rng.uniform(*lo_hi))  # noqa: E731
    return [
        PressConfig(
            indenter=spec.indenters[int(rng.integers(len(spec.indenters)))],
            polar_deg=u(spec.polar_deg),
            azimuth_deg=u(spec.azimuth_deg),
            spin_deg=u(spec.spin_deg),
            depth=u(spec.depth),
        )
        for _ in range(spec.count)
    ]


def _worker_init(log_level: int, log_file: str | None = None) -> None:
    """A render process: logs like the parent; on SIGTERM (sent by a terminated ``nlips dataset``, or to the whole
    process group) releases its claim and removes its half-written press folder, then exits, as the parent
    does. The handler runs when the current native call (a Mitsuba render) returns; ended with ``os._exit``, as
    an exception raised there could land inside the library."""
    import signal

    configure_worker(log_level, log_file)
    signal.signal(signal.SIGTERM, _worker_terminated)


def _worker_terminated(signum: int, frame: FrameType | None) -> None:
    from ..core import atomic, claims

    claims.release_all()
    atomic.remove_in_progress()
    os._exit(128 + signum)


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
            log.debug("press %s: %s", job.name, status)
            bar.update(1)
        if busy:
            (log.info if not waited else log.debug)(
                "waiting for %d press(es) another process is rendering (taken over if it dies)", len(busy)
            )
            waited = True
            time.sleep(BUSY_POLL_S)
        todo = busy


def _render_job(scene: SceneConfig, job: PressJob, out: Path, overwrite: bool, stale_s: float) -> tuple[str, object]:
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
            if is_complete(scene, job, out):
                return "skipped", None
            clean_interrupted(out, item=job.name)  # a dead owner's half-written folder, if any
            folder = out / job.name
            replace = overwrite
            if is_press_folder(folder):
                if not overwrite and not _same_spec(scene, job, out):
                    return "changed", _changed_error(scene, job, out)
                missing = _missing_files(folder)
                if missing:
                    busy = _live_claim_inside(folder)
                    if busy:
                        return "failed", f"{folder}: {missing[0]} missing, but {busy}; run again when it is done"
                    more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
                    results = _results_inside(folder)
                    log.warning(
                        "%s: %s%s missing; rendering it again%s",
                        folder,
                        ", ".join(missing[:3]),
                        more,
                        f" (its results {', '.join(results)} go with it)" if results else "",
                    )
                    replace = True
            elif folder.exists():
                busy = _live_claim_inside(folder)
                if busy:
                    return "failed", f"{folder}: incomplete (no {META_FILE}), but {busy}; run again when it is done"
                log.warning("%s: incomplete press folder (no %s): removed, rendering it again", folder, META_FILE)
                _remove_incomplete(folder)
            _run_one(scene, job, out, replace)
            return "rendered", None
    except FileExistsError:  # published by a process that lost its claim: the folder is whole
        if is_press_folder(out / job.name) and not overwrite and not _same_spec(scene, job, out):
            return "changed", _changed_error(scene, job, out)
        return "skipped", None
    except OSError as exc:
        return "oserror", (exc.errno, exc.strerror or str(exc), exc.filename or str(out / job.name))
    except Exception as exc:  # reported per press; the other presses go on
        return "failed", f"{type(exc).__name__}: {exc}"


def _run_one(scene: SceneConfig, job: PressJob, out: Path, overwrite: bool = False) -> None:
    from .press import render_press

    render_press(scene, job.press, out / job.name, seed=job.seed, overwrite=overwrite)


def _live_claim_inside(folder: Path) -> str | None:
    """Who works inside ``folder`` now (a live claim there, e.g. a solve's ``.claim-nlips``), or None."""
    from ..core.claims import CLAIM_PREFIX, holder

    if not folder.is_dir():
        return None
    for path in folder.glob(CLAIM_PREFIX + "*"):
        name = path.name[len(CLAIM_PREFIX) :]
        owner = holder(folder / name) if "." not in name else None  # NAME.token, NAME.stale.x: not claims
        if owner is not None:
            return f"process {owner.pid} on {owner.host} holds {path.name} in it"
    return None


def _results_inside(folder: Path) -> list[str]:
    """Names of the result folders inside a press folder (``nlips/``, ``nlipsnet/``, a solve's ``--out``)."""
    return sorted(p.name + "/" for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))


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


def _meta_problem(folder: Path) -> str | None:
    """Why ``folder``'s meta.json cannot be read as JSON (unreadable, not JSON, not an object), or None."""
    path = folder / META_FILE
    try:
        meta = json.loads(path.read_bytes())
    except OSError as exc:
        return f"{path}: cannot be read ({exc.strerror or exc})"
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
        return f"{path}: not valid JSON ({exc})"
    if not isinstance(meta, dict):
        return f"{path}: not a JSON object"
    return None


def _recorded_hash(folder: Path) -> str | None:
    from .press import recorded_spec_hash

    try:
        return recorded_spec_hash(json.loads((folder / "meta.json").read_text())["provenance"])
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def _expected_hash(scene: SceneConfig, job: PressJob) -> str:
    from .press import render_spec_hash

    return render_spec_hash(scene, job.press, job.seed)


def _same_spec(scene: SceneConfig, job: PressJob, out: Path) -> bool:
    """Whether the press folder of ``job`` in ``out`` records this very spec."""
    return _recorded_hash(out / job.name) == _expected_hash(scene, job)


def _missing_files(folder: Path) -> list[str]:
    """Files ``folder``'s meta.json lists that are gone (deleted or lost since it was rendered); [] when whole, or
    when meta.json cannot say (its format is for the commands that load the press to judge)."""
    from ..core.capture import listed_files

    try:
        names = listed_files(json.loads((folder / META_FILE).read_bytes()))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return []
    return [name for name in names if not (folder / name).is_file()]


def is_complete(scene: SceneConfig, job: PressJob, out: Path) -> bool:
    """A whole folder rendered from this very spec: meta.json records the spec, and every file it lists is there."""
    folder = out / job.name
    return is_press_folder(folder) and _same_spec(scene, job, out) and not _missing_files(folder)


def _changed_error(scene: SceneConfig, job: PressJob, out: Path) -> str:
    """The line :func:`check_existing` gives for ``job``'s folder, rendered from another spec (or damaged)."""
    try:
        check_existing(scene, [job], out, overwrite=False)
    except NlipsError as exc:
        return str(exc)
    return f"{out}: {job.name} was rendered meanwhile from a different scene or spec"  # and replaced since


def warn_unlisted(jobs: list[PressJob], out: Path) -> list[str]:
    """Warn about press folders in ``out`` that the spec does not name (left by an earlier, longer spec, or a
    reference the spec no longer asks for): every later command on the folder (solve, calibrate) still takes
    them as part of the dataset. Returns their names."""
    from ..core.capture import is_press_folder

    named = {j.name for j in jobs}
    extra = sorted(p.name for p in out.iterdir() if p.is_dir() and p.name not in named and is_press_folder(p))
    if extra:
        more = f" and {len(extra) - 3} more" if len(extra) > 3 else ""
        log.warning(
            "%s: %s%s are not in this spec (left from an earlier one); later commands on the folder still use "
            "them: remove them, or render into a new folder",
            out,
            ", ".join(extra[:3]),
            more,
        )
    return extra


def check_existing(scene: SceneConfig, jobs: list[PressJob], out: Path, overwrite: bool) -> None:
    """Finished presses made from another spec, or with a damaged meta.json, are an error (or
    re-rendered with ``overwrite``)."""
    if overwrite:
        return
    damaged = [p for p in (_meta_problem(out / j.name) for j in jobs if is_press_folder(out / j.name)) if p]
    if damaged:
        more = f" ({len(damaged) - 1} more press folders are damaged too)" if len(damaged) > 1 else ""
        raise CaptureError(
            f"{damaged[0]}; the press folder is damaged{more}: delete it to render it again, or use --overwrite"
        )
    changed = [j.name for j in jobs if is_press_folder(out / j.name) and not _same_spec(scene, j, out)]
    if changed:
        names = ", ".join(changed[:3]) + (f" and {len(changed) - 3} more" if len(changed) > 3 else "")
        meshes = any(j.press is not None and j.press.indenter.kind == "mesh" for j in jobs if j.name in changed)
        edited = " (or from another version of an indenter's mesh file: its content counts)" if meshes else ""
        raise ConfigError(
            f"{out}: {names} were rendered from a different scene or spec{edited}; render into a new folder, "
            "or use --overwrite to re-render them"
        )
