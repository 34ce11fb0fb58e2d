"""How many cores and how much memory this process may use, and how many worker processes fit them: the one place
that asks the operating system."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

MEMINFO = Path("/proc/meminfo")
"""Linux's memory table: its ``MemAvailable`` line is what new processes can take without swapping or the
out-of-memory killer (page cache that can be dropped included)."""
PROC_CGROUP = Path("/proc/self/cgroup")
"""This process's control groups, one ``ID:controllers:path`` line a hierarchy (cgroup v2: ``0::path``)."""
CGROUP_ROOT = Path("/sys/fs/cgroup")
"""Where the control groups are mounted: cgroup v2's tree itself, or cgroup v1's one folder per controller
(``memory/``)."""
NO_CGROUP_LIMIT = 2**62
"""cgroup v1 writes "no limit" as a huge count (``PAGE_COUNTER_MAX`` pages, 9223372036854771712 bytes): any limit
at or above this is none."""


def usable_cores(proc_cgroup: Path | None = None, cgroup_root: Path | None = None) -> int:
    """Cores this process may run on: its CPU affinity (``taskset``, a container's cpuset), else all cores, and no
    more than its control group's CPU quota rounded up (:func:`cgroup_cpu_limit`), at least 1.

    Why the quota: a container limited by ``docker run --cpus=2`` or a Kubernetes CPU limit keeps the host's
    affinity (all 64 cores, say) and is throttled to 2 cores' time, so pools sized by the affinity alone run 30
    threads where 2 cores' worth fit. Python 3.13's ``os.process_cpu_count()`` counts the affinity alone (with its
    ``-X cpu_count`` override) and reads no quota either. The paths are :func:`cgroup_memory_room`'s, for tests."""
    try:
        cores = max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # no affinity outside Linux
        cores = os.cpu_count() or 1
    quota = cgroup_cpu_limit(proc_cgroup, cgroup_root)
    return cores if quota is None else max(1, min(cores, quota))


def cgroup_cpu_limit(proc_cgroup: Path | None = None, cgroup_root: Path | None = None) -> int | None:
    """Cores' worth of CPU time this process's control group may use, rounded up (a quota of 1.5 cores: 2), or None
    where no quota is set or none can be read.

    cgroup v2: ``cpu.max`` ("QUOTA PERIOD" in microseconds; "max": no quota); cgroup v1 (a ``cpu`` hierarchy,
    often mounted as ``cpu,cpuacct``): ``cpu.cfs_quota_us`` (-1: no quota) over ``cpu.cfs_period_us``. The group
    and its ancestors are read as for the memory limit (:func:`cgroup_memory_room`) and the smallest quota wins."""
    found = _cgroup_folder("cpu", proc_cgroup, cgroup_root)
    if found is None:
        return None
    mount, group, v1 = found
    limits = [_cpu_quota(folder, v1) for folder in _group_and_ancestors(mount, group)]
    limits = [n for n in limits if n is not None]
    return min(limits) if limits else None


def _cpu_quota(folder: Path, v1: bool) -> int | None:
    """One group's CPU quota in whole cores (rounded up, >= 1), None where it has none or a file is unreadable."""
    try:
        if v1:
            quota = int((folder / "cpu.cfs_quota_us").read_text(encoding="utf-8").strip())
            period = int((folder / "cpu.cfs_period_us").read_text(encoding="utf-8").strip())
        else:
            quota_text, _, period_text = (folder / "cpu.max").read_text(encoding="utf-8").strip().partition(" ")
            if quota_text == "max":
                return None
            quota, period = int(quota_text), int(period_text)
    except (OSError, ValueError):
        return None
    if quota <= 0 or period <= 0:  # v1's -1: no quota
        return None
    return max(1, -(-quota // period))


def available_memory(
    meminfo: Path | None = None, proc_cgroup: Path | None = None, cgroup_root: Path | None = None
) -> int | None:
    """Bytes of memory new processes can take now: the smaller of ``MemAvailable`` (``meminfo``) and the room left
    under this process's cgroup memory limit, or None where neither is known (not Linux, a kernel before 3.14,
    unreadable files): callers then count cores alone, as before.

    Why the cgroup: in a container (Docker, Kubernetes, a SLURM job) ``MemAvailable`` is the host's, far above what
    the container may take, and the out-of-memory killer ends workers at the cgroup's limit instead.

    Why not psutil: it is not a dependency, its ``virtual_memory().available`` reads this same line on Linux, and it
    does not read cgroups. The paths (None: :data:`MEMINFO`, :data:`PROC_CGROUP`, :data:`CGROUP_ROOT`, looked up at
    the call so that tests can point them at fake files) are for tests."""
    meminfo_reading = _meminfo_available(MEMINFO if meminfo is None else meminfo)
    cgroup_reading = cgroup_memory_room(proc_cgroup, cgroup_root)
    readings = [m for m in (meminfo_reading, cgroup_reading) if m is not None]
    return min(readings) if readings else None


def _meminfo_available(meminfo: Path) -> int | None:
    """``MemAvailable`` of ``meminfo`` in bytes, or None where the file or the line is missing."""
    try:
        text = meminfo.read_text(encoding="utf-8")
    except OSError:
        return None
    for line in text.splitlines():
        name, _, value = line.partition(":")
        if name == "MemAvailable":
            parts = value.split()
            if parts and parts[0].isdigit():
                return int(parts[0]) * 1024 if len(parts) > 1 and parts[1] == "kB" else int(parts[0])
    return None


def cgroup_memory_room(proc_cgroup: Path | None = None, cgroup_root: Path | None = None) -> int | None:
    """Bytes this process's control group may still take before its memory limit, or None where no limit is set
    or none can be read (no cgroups, no memory controller, unreadable files).

    cgroup v2 (``0::path``): ``memory.max`` ("max": no limit) minus ``memory.current``; cgroup v1 (a ``memory``
    hierarchy; it wins on hybrid systems, where v2 holds no memory controller): ``memory.limit_in_bytes`` (a huge
    count: no limit) minus ``memory.usage_in_bytes``. The usage counts page cache, which the kernel drops before
    it kills, so the file cache it could drop first (``inactive_file`` of ``memory.stat``, as ``docker stats``
    subtracts) is not counted: the same idea as ``MemAvailable``. The group's ancestors are read too, up to the
    mount's root (a Kubernetes pod's limit sits above its containers'), and the least room wins; this also reads
    the limit where the group's own folder is missing (Docker on cgroup v1 without a cgroup namespace: the file
    names the host's path, the mount is the container's own group)."""
    found = _cgroup_folder("memory", proc_cgroup, cgroup_root)
    if found is None:
        return None
    mount, group, v1 = found
    limit_file, usage_file = (
        ("memory.limit_in_bytes", "memory.usage_in_bytes") if v1 else ("memory.max", "memory.current")
    )
    rooms = [_room(folder, limit_file, usage_file) for folder in _group_and_ancestors(mount, group)]
    rooms = [r for r in rooms if r is not None]
    return min(rooms) if rooms else None


def _cgroup_folder(
    controller: str, proc_cgroup: Path | None = None, cgroup_root: Path | None = None
) -> tuple[Path, str, bool] | None:
    """Where ``controller``'s limits of this process's group are: (the hierarchy's mount, the group's path in it,
    whether it is cgroup v1), or None where ``proc_cgroup`` is unreadable or lists no hierarchy for it.

    A cgroup v1 hierarchy holding ``controller`` wins over v2's (hybrid systems, where v2 holds no such
    controller); it is mounted as ``CGROUP_ROOT/controller`` or under the hierarchy's own name (``cpu,cpuacct``).
    The paths (None: :data:`PROC_CGROUP`, :data:`CGROUP_ROOT`, looked up at the call) are for tests."""
    proc_cgroup = PROC_CGROUP if proc_cgroup is None else proc_cgroup
    cgroup_root = CGROUP_ROOT if cgroup_root is None else cgroup_root
    try:
        lines = proc_cgroup.read_text(encoding="utf-8").splitlines()
    except OSError:
        return None
    v1 = v2 = None
    for line in lines:
        hierarchy, _, rest = line.partition(":")
        controllers, _, path = rest.partition(":")
        if controller in controllers.split(","):
            v1 = (controllers, path)
        elif hierarchy == "0" and controllers == "":
            v2 = path
    if v1 is not None:
        controllers, path = v1
        mount = cgroup_root / controller
        if not mount.is_dir() and (cgroup_root / controllers).is_dir():
            mount = cgroup_root / controllers
        return mount, path, True
    if v2 is not None:
        return cgroup_root, v2, False
    return None


def _group_and_ancestors(mount: Path, group: str) -> list[Path]:
    """The folders of ``group`` and of its ancestors under ``mount``, up to the mount's root (a Kubernetes pod's
    limit sits above its containers'); a missing folder is listed too (its files read as no limit)."""
    folder = mount / group.strip("/")
    folders = [folder]
    while folder != mount and mount in folder.parents:
        folder = folder.parent
        folders.append(folder)
    return folders


def _room(folder: Path, limit_file: str, usage_file: str) -> int | None:
    """Limit minus usage of one group's ``folder`` (>= 0), None where it has no limit or a file is unreadable."""
    try:
        limit_text = (folder / limit_file).read_text(encoding="utf-8").strip()
        if limit_text == "max":
            return None
        limit = int(limit_text)
        usage = int((folder / usage_file).read_text(encoding="utf-8").strip())
    except (OSError, ValueError):
        return None
    if limit >= NO_CGROUP_LIMIT:
        return None
    return max(0, limit - max(0, usage - _inactive_file(folder)))


def _inactive_file(folder: Path) -> int:
    """Bytes of file cache the kernel can drop first (``inactive_file`` of ``memory.stat``), 0 where unknown."""
    try:
        text = (folder / "memory.stat").read_text(encoding="utf-8")
    except OSError:
        return 0
    for line in text.splitlines():
        name, _, value = line.partition(" ")
        if name == "inactive_file" and value.strip().isdigit():
            return int(value)
    return 0


@dataclass(frozen=True)
class WorkerMemory:
    """Peak resident memory of one worker process as a line in the image's pixels: ``base + per_pixel * W * H``."""

    job: str
    """What the worker does, for the log line (e.g. "solve, auto ROI")."""
    base_bytes: int
    """Bytes at no pixels: the interpreter and the libraries it imports (NumPy, SciPy, Mitsuba)."""
    per_pixel_bytes: int
    """Bytes per pixel of the camera's image (W x H)."""

    def estimate(self, width: int, height: int) -> int:
        """Peak bytes of one worker on ``width`` x ``height`` images."""
        return self.base_bytes + self.per_pixel_bytes * int(width) * int(height)


# Peak RSS (GNU time's %M) of one command at each size, the default twin (2 spp, one bounce), a cold disk cache; a
# pool's worker holds about the same (a 4-press `nlips calibrate` on 2 workers at 1280x960: ~1.9 GB each,
# benchmarks/RESULTS.md s24-hires). Least squares over 160x120, 320x240, 640x480 and 1280x960, rounded up;
# benchmarks/RESULTS.md (s24-mem) has the table.
SOLVE_ROI_MEMORY = WorkerMemory("solve, auto ROI", 150 * 2**20, 1_400)
"""One press solved with ``--roi auto`` (``nlips calibrate``'s workers, ``nlips solve --roi auto``). Measured peak
RSS: 160x120 0.15 GB, 320x240 0.26, 640x480 0.60 (the 16-spp bench presses: sphere 0.51, cube 0.73: the ROI grows
with the contact), 1280x960 1.85 GB. The model: 0.18, 0.26, 0.59, 1.88 GB."""
SOLVE_WHOLE_MEMORY = WorkerMemory("solve, whole frame", 150 * 2**20, 5_400)
"""One press solved on the whole frame (``nlips solve`` without ``--roi``). Measured peak RSS: 160x120 0.20 GB,
320x240 0.56, 640x480 1.72, 1280x960 6.2-6.6 GB (the finest level's operators and normal matrices; 4.4-4.5 GB
with the disk cache warm: its entries are mapped, not copied). The model: 0.26, 0.57, 1.82, 6.79 GB."""
RENDER_MEMORY = WorkerMemory("render", 380 * 2**20, 1_950)
"""One press rendered by Mitsuba (``nlips dataset``'s workers; ``nlips render``). Measured peak RSS: 160x120
0.40 GB, 320x240 0.5, 640x480 1.08, 1280x960 2.7-2.8 GB. The model: 0.44, 0.55, 1.00, 2.79 GB."""
MEMORY_HEADROOM = 0.9
"""Share of the available memory the workers are planned to take: the rest is the command's own process (its pool,
progress bar, results; 0.2-0.6 GB) and what other programs take meanwhile."""


SOLVE_THREADS = 2
"""Threads one press's solve uses well: its per-LED whole-frame steps and the solver's pixel chunks and row-block
products on :mod:`nlipscalib.solver.threads` nearly halve their wall time on 2 threads (benchmarks/RESULTS.md), the
GIL-bound rest does not shrink. A folder of presses (``nlips solve FOLDER``) therefore runs one worker per this many
cores by default (:func:`solve_workers_default`): one on a 2-core machine, where a second process also pays its
start-up and imports again."""


def solve_workers_default(cores: int | None = None) -> int:
    """Worker processes a command solving presses (``nlips solve FOLDER``, ``nlips calibrate``, ``nlips demo``)
    starts when ``--workers`` is not given: one per :data:`SOLVE_THREADS` usable cores (``cores``; None:
    :func:`usable_cores`), at least 1; the pool starts no more than there are presses, and :func:`worker_count`
    lowers it to what memory holds (:func:`solve_worker_count` does both)."""
    return max(1, (usable_cores() if cores is None else cores) // SOLVE_THREADS)


def solve_worker_count(requested: int | None, memory: WorkerMemory, width: int, height: int) -> int:
    """Solver processes of every command that solves presses in a pool (``nlips solve FOLDER``, ``nlips
    calibrate``, ``nlips demo``): ``requested`` (the user's ``--workers``; 0 or None: not given), else
    :func:`solve_workers_default` lowered to what memory holds (:func:`worker_count`).

    Why one function: ``calibrate`` started one solver per core and ``demo`` one per core (at most 3) where
    ``solve FOLDER`` started one per two cores, for the same work; a press's solve already runs on two cores'
    threads, and the pool shares the cores out as threads (:func:`threads_per_worker`), so a second process per
    two cores adds its start-up and imports for little (benchmarks/RESULTS.md, s31-walkleft).

    Parameters
    ----------
    requested : the user's ``--workers`` (None or 0: the default)
    memory : one solver's peak memory model (:data:`SOLVE_ROI_MEMORY`, :data:`SOLVE_WHOLE_MEMORY`)
    width, height : the presses' image size, pixels

    Returns
    -------
    int >= 1
    """
    return worker_count(requested, solve_workers_default(), memory, width, height)


def threads_per_worker(workers: int, cores: int | None = None) -> int:
    """Threads each of ``workers`` processes solving side by side may use: the usable cores (``cores``; None:
    :func:`usable_cores`) shared out, at least 1 (2 workers on 8 cores: 4 threads each; on 2 cores: 1)."""
    return max(1, (usable_cores() if cores is None else cores) // max(1, workers))


def worker_count(
    requested: int | None,
    default: int,
    memory: WorkerMemory,
    width: int,
    height: int,
    available: int | None = None,
) -> int:
    """The number of worker processes to start: ``requested`` when given, else ``default`` (a count from the cores)
    lowered to what the available memory holds.

    Parameters
    ----------
    requested : the user's ``--workers`` (None or 0: not given); respected, with a warning when that many workers
        likely need more memory than is available
    default : workers from the cores alone (e.g. one per core), >= 1
    memory : one worker's peak memory model (:data:`SOLVE_ROI_MEMORY`, :data:`SOLVE_WHOLE_MEMORY`,
        :data:`RENDER_MEMORY`)
    width, height : the images' size, pixels
    available : bytes of memory available (None: :func:`available_memory`, read now; unknown: cores alone)

    Returns
    -------
    int >= 1. When memory lowers the default, one INFO line says so and how to override it (``--workers``).
    """
    if available is None:
        available = available_memory()
    each = memory.estimate(width, height)
    if requested:
        if available is not None and requested > 1 and requested * each > available:
            log.warning(
                "--workers %d: each %s worker may take ~%s at %dx%d, %s in all, and %s is available: "
                "the out-of-memory killer may end one (fewer --workers needs less memory)",
                requested,
                memory.job,
                _gb(each),
                width,
                height,
                _gb(requested * each),
                _gb(available),
            )
        return requested
    default = max(1, default)
    if available is None:
        return default
    fits = max(1, int(available * MEMORY_HEADROOM // each))
    if fits < default:
        log.info(
            "%d worker%s instead of %d: each %s worker may take ~%s at %dx%d and %s is available "
            "(--workers N overrides)",
            fits,
            "s" if fits > 1 else "",
            default,
            memory.job,
            _gb(each),
            width,
            height,
            _gb(available),
        )
        return fits
    return default


def _gb(n: int) -> str:
    """Bytes as a short text in GB (10**9: what ``free -g`` and the README's tables say)."""
    return f"{n / 1e9:.1f} GB"
