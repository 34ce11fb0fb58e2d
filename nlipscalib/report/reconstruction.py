"""Figures of one reconstruction (NLiPs or NLiPsNet): the PNGs written next to result.npz.

Two levels:

- ``"maps"`` (default of ``nlips solve``): normals.png, depth.png, residual.png and, with ground truth,
  error.png, as plain PNGs over the solved box at the image's resolution (OpenCV, milliseconds;
  :mod:`.maps`).
- ``"full"``: the maps plus summary.png, a matplotlib contact sheet with titles and colour bars
  (about a second, most of it importing matplotlib).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from ..cpus import usable_cores

FIGURE_LEVELS = ("none", "maps", "full")
"""Accepted values of ``figures`` (``True`` means "maps", ``False`` means "none")."""
ERROR_RANGE_DEG = (0.0, 10.0)
"""Colour range of angular error maps, degrees: the same in every figure so they compare."""
NORMALS_PNG, SUMMARY_PNG = "normals.png", "summary.png"
"""The normal map (written at every level but "none") and the "full" level's summary sheet."""


def figure_level(figures) -> str:
    """Normalise a ``figures`` argument (bool or one of :data:`FIGURE_LEVELS`) to a level name."""
    if figures is True:
        return "maps"
    if figures is False or figures is None:
        return "none"
    if figures not in FIGURE_LEVELS:
        from ..errors import ConfigError

        raise ConfigError(f"figures must be one of {FIGURE_LEVELS} (or True/False), got {figures!r}")
    return figures


def figures_missing(folder: str | Path, level) -> bool:
    """True when ``folder`` lacks figures that ``level`` writes (e.g. a result solved with --no-figures).

    Parameters
    ----------
    folder : a reconstruction folder
    level : "none", "maps" or "full" (or a bool)
    """
    needed = {"none": (), "maps": (NORMALS_PNG,), "full": (NORMALS_PNG, SUMMARY_PNG)}[figure_level(level)]
    return any(not (Path(folder) / name).is_file() for name in needed)


def write_reconstruction_figures(folder: str | Path, rec, ground_truth=None, level="maps") -> list[Path]:
    """Write the figures of ``rec`` into ``folder``; returns the files written.

    Parameters
    ----------
    folder : output folder (usually the reconstruction's temporary folder, so figures appear with it)
    rec : Reconstruction -- maps over the full (H, W) image, camera frame
    ground_truth : GroundTruth or None -- adds error.png (angular error, degrees)
    level : "none", "maps" or "full" (or a bool), see the module docstring
    """
    from .maps import normal_map_png, scalar_map_png

    level = figure_level(level)
    if level == "none":
        return []
    folder = Path(folder)
    box = solved_box(rec)
    shown = rec.reconstructed[box]
    err = error_map(rec, ground_truth, box)
    jobs = [
        (normal_map_png, folder / NORMALS_PNG, rec.normals[box], shown),
        (scalar_map_png, folder / "depth.png", _masked(rec.depth[box], shown), "viridis", "mm"),
        (scalar_map_png, folder / "residual.png", _masked(rec.residual[box], shown), "magma", "lin."),
    ]
    if err is not None:
        jobs.append((scalar_map_png, folder / "error.png", err, "jet", "deg", *ERROR_RANGE_DEG))
    # PNG encoding releases the GIL: the maps are written side by side
    with ThreadPoolExecutor(max_workers=min(len(jobs), usable_cores())) as pool:
        written = list(pool.map(lambda job: job[0](*job[1:]), jobs))
    if level == "full":
        written.append(_summary(folder / SUMMARY_PNG, rec, box, err))
    return written


def solved_box(rec) -> tuple[slice, slice]:
    """(rows, cols) slices of the bounding box of the solved pixels (``rec.mask``; the whole image if none).

    Figures show this box: a region-of-interest result is drawn at full resolution without a field of
    empty pixels around it (and costs a fraction of a full-frame map to write); ``report.json``'s
    ``roi`` gives its place in the image.
    """
    rows, cols = np.nonzero(rec.mask)
    if rows.size == 0:
        return slice(None), slice(None)
    return slice(int(rows.min()), int(rows.max()) + 1), slice(int(cols.min()), int(cols.max()) + 1)


def error_map(rec, ground_truth, box=(slice(None), slice(None))) -> np.ndarray | None:
    """Angular error, degrees, where reconstructed and valid in the truth (NaN elsewhere).

    Returns (h, w) float64 over ``box`` ((rows, cols) slices; default the whole (H, W) image), or None
    without ground truth.
    """
    if ground_truth is None:
        return None
    from ..core.metrics import angular_error_map

    m = rec.reconstructed[box] & ground_truth.valid[box]
    return np.where(m, angular_error_map(rec.normals[box], ground_truth.normals[box]), np.nan)


def _masked(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    return np.where(mask, values, np.nan)


def _summary(path: Path, rec, box, err) -> Path:
    """One matplotlib sheet of the result over the solved box."""
    from .figures import Panel, contact_sheet, normals_to_rgb

    shown = rec.reconstructed[box]
    panels = [
        Panel("normals", normals_to_rgb(rec.normals[box], shown)),
        Panel("depth", _masked(rec.depth[box], shown), "viridis", "mm"),
        Panel("RMS residual", _masked(rec.residual[box], shown), "magma", "linear intensity"),
    ]
    if err is not None:
        title = f"angular error, AAE {np.nanmean(err):.2f} deg"  # err is NaN off the scored pixels
        panels.append(Panel(title, err, "jet", "deg", *ERROR_RANGE_DEG))
    return contact_sheet([("", panels)], path, dpi=150)
