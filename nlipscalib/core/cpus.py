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


def usable_cores() -> int:
    """Cores this process may run on: its CPU affinity (a container's or ``taskset``'s limit), else all cores."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # no affinity outside Linux
        return os.cpu_count() or 1


def available_memory(meminfo: Path = MEMINFO) -> int | None:
    """Bytes of memory new processes can take now (``MemAvailable`` of ``meminfo``), or None where unknown
    (not Linux, a kernel before 3.14, an unreadable file): callers then count cores alone, as before.

    Why not psutil: it is not a dependency, and its ``virtual_memory().available`` reads this same line on Linux."""
    try:
        text = meminfo.read_text()
    except OSError:
        return None
    for line in text.splitlines():
        name, _, value = line.partition(":")
        if name == "MemAvailable":
            parts = value.split()
            if parts and parts[0].isdigit():
                return int(parts[0]) * 1024 if len(parts) > 1 and parts[1] == "kB" else int(parts[0])
    return None


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
