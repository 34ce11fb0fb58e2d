"""Figures of one reconstruction (NLiPs or NLiPsNet): the PNGs written next to result.npz.

Two levels:

- ``"maps"`` (default of ``nlips solve`` and ``nlips infer``): normals.png, depth.png, residual.png (a result
  with a residual: NLiPs', not NLiPsNet's) and, with ground truth, error.png, as plain PNGs over the solved box at
  the image's resolution (OpenCV, milliseconds; :mod:`.maps`).
- ``"full"``: the maps plus summary.png, a matplotlib contact sheet with titles and colour bars
  (about a second, most of it importing matplotlib).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.cpus import usable_cores
from ..core.errors import CaptureError

if TYPE_CHECKING:  # named in hints only
    from ..core.reconstruction import Reconstruction
    from ..core.surface_files import GroundTruth

log = logging.getLogger(__name__)

FIGURE_LEVELS = ("none", "maps", "full")
"""Accepted values of ``figures`` (``True`` means "maps", ``False`` means "none")."""
RESIDUAL_UNIT = "linear intensity"
"""Unit of the residual maps: linear image units, the sensor's full range = 1 (``Press.linear``)."""
METHOD_NAMES = {"nlips": "NLiPs", "nlipsnet": "NLiPsNet", "lut": "lookup table"}
"""How the summary's title names the method of ``report.json``'s ``method``."""
NORMALS_PNG, DEPTH_PNG, SUMMARY_PNG = "normals.png", "depth.png", "summary.png"
"""The normal and depth maps (written at every level but "none") and the "full" level's summary sheet."""
RESIDUAL_PNG, ERROR_PNG = "residual.png", "error.png"
"""The maps drawn for some results only: the residual (a result with one: NLiPs') and the angular error (a press
with ground truth)."""
OPTIONAL_PNGS = (RESIDUAL_PNG, ERROR_PNG)
""":data:`RESIDUAL_PNG` and :data:`ERROR_PNG`: their absence says nothing of a result's figures being whole."""


def figure_level(figures: bool | str | None) -> str:
    """Normalise a ``figures`` argument (bool or one of :data:`FIGURE_LEVELS`) to a level name."""
    if figures is True:
        return "maps"
    if figures is False or figures is None:
        return "none"
    if figures not in FIGURE_LEVELS:
        from ..core.errors import ConfigError

        raise ConfigError(f"figures must be one of {FIGURE_LEVELS} (or True/False), got {figures!r}")
    return figures


def figures_missing(folder: str | Path, level: bool | str | None) -> bool:
    """True when ``folder`` lacks figures that ``level`` writes (e.g. a result solved with --no-figures), or holds
    one of them empty or cut short (:func:`figures_problem`).

    Parameters
    ----------
    folder : a reconstruction folder
    level : "none", "maps" or "full" (or a bool)
    """
    return figures_problem(folder, level) is not None


def figures_problem(folder: str | Path, level: bool | str | None) -> str | None:
    """What is wrong with the figures ``level`` writes in ``folder``, in words ("depth.png cut short (no PNG end
    chunk)", "normals.png missing"), or None when they are all there and whole; they are then drawn again
    (milliseconds), the result kept.

    Why torn ones: figures are written atomically but not synced, like every output, so a power cut soon after a
    solve can leave depth.png empty or cut short beside a whole result; it was kept at every run. Each figure is
    judged by the bytes at its ends (core.file_checks: ~10-20 us a file). residual.png and error.png are not
    drawn for every result (NLiPsNet's has no residual; a capture no ground truth): only a torn one counts.

    Parameters
    ----------
    folder : a reconstruction folder
    level : "none", "maps" or "full" (or a bool)
    """
    from ..core.file_checks import MISSING, file_problem

    level = figure_level(level)
    if level == "none":
        return None
    needed = (NORMALS_PNG, DEPTH_PNG) + ((SUMMARY_PNG,) if level == "full" else ())
    for name in needed + OPTIONAL_PNGS:
        problem = file_problem(Path(folder) / name)
        if problem is not None and (name in needed or problem != MISSING):
            return f"{name} {problem}"
    return None


def write_reconstruction_figures(
    folder: str | Path,
    rec: Reconstruction,
    ground_truth: GroundTruth | Callable[[], GroundTruth | None] | None = None,
    level: bool | str | None = "maps",
    reference_depth: np.ndarray | None = None,
    name: str = "",
) -> list[Path]:
    """Write the figures of ``rec`` into ``folder``; returns the files written.

    Parameters
    ----------
    folder : output folder (usually the reconstruction's temporary folder, so figures appear with it)
    rec : Reconstruction -- maps over the full (H, W) image, camera frame
    ground_truth : GroundTruth or None -- adds error.png (angular error, degrees); or a function returning one
        (a press's truth read at its first use, ``lambda: press.ground_truth``): it is then called on the figures'
        thread pool, beside the other maps' encoding (reading a 640x480 gt.npz inflates ~7 MB, ~0.05 s); a
        damaged truth (CaptureError) is one warning naming the file, and no error.png
    level : "none", "maps" or "full" (or a bool), see the module docstring
    reference_depth : (H, W) float, mm, camera z of the undeformed surface (the press's reference.npz), or None --
        depth.png then shows the indentation (:func:`depth_view`), else camera z
    name : the press's name, for the summary's title
    """
    from .figures import ERROR_CMAP, ERROR_UNIT, error_scale
    from .maps import normal_map_png, scalar_map_png

    level = figure_level(level)
    if level == "none":
        return []
    folder = Path(folder)
    box = solved_box(rec)
    shown = rec.reconstructed[box]
    depth, depth_label, depth_min = depth_view(rec, reference_depth, box)

    def error_png() -> tuple[Path | None, tuple | None]:
        try:  # the truth's arrays are read at their first use (GroundTruth.load), here
            truth = ground_truth() if callable(ground_truth) else ground_truth
            err = error_map(rec, truth, box)
            contact = truth.contact[box] if err is not None else None
        except CaptureError as exc:  # the result needs no truth: a damaged one costs error.png only
            log.warning("%s: the ground truth is damaged; the error figure (error.png) is skipped", exc)
            return None, None
        if err is None:
            return None, None
        top = error_scale([err])  # ~6 ms at 640x480: once, for error.png and the summary alike
        return scalar_map_png(folder / ERROR_PNG, err, ERROR_CMAP, ERROR_UNIT, 0.0, top), (err, contact, top)

    residual = _masked(rec.residual[box], shown)
    # NLiPs' fit leaves a residual per solved pixel; NLiPsNet's result (`nlips infer`) has none (all NaN): a grey
    # residual.png with a meaningless colour bar would only mislead
    residual = residual if np.isfinite(residual).any() else None
    jobs = [
        (error_png,),  # first: its truth's reading is the longest job
        (normal_map_png, folder / NORMALS_PNG, rec.normals[box], shown),
        (scalar_map_png, folder / DEPTH_PNG, depth, "viridis", depth_label, depth_min),
    ]
    if residual is not None:
        jobs.append((scalar_map_png, folder / RESIDUAL_PNG, residual, "magma", RESIDUAL_UNIT))
    # PNG encoding and the truth's inflating release the GIL: the maps are written side by side
    with ThreadPoolExecutor(max_workers=min(len(jobs), usable_cores())) as pool:
        (error_path, error), *written = pool.map(lambda job: job[0](*job[1:]), jobs)
    if error_path is not None:
        written.append(error_path)
    if level == "full":
        method = METHOD_NAMES.get(rec.report.get("method"), "")
        title = ", ".join(filter(None, [name, method, box_words(box, rec.mask.shape)]))
        view = (depth, depth_label, depth_min)
        written.append(_summary(folder / SUMMARY_PNG, rec, box, error, view, residual, title))
    return written


def depth_view(
    rec: Reconstruction, reference_depth: np.ndarray | None, box: tuple[slice, slice]
) -> tuple[np.ndarray, str, float | None]:
    """The depth map a figure shows over ``box``, its unit label and the lower end of its colour range.

    With the undeformed surface known, the indentation: how far the gel was pushed in from it, toward the
    camera (``reference_depth - depth``, mm, >= 0 in the contact), from 0 up: in camera z the dome's own
    curvature (a few mm across a region) takes the colour range and a 1 mm press is a faint ghost. Without
    it, camera z itself, labelled so.

    Parameters
    ----------
    rec : Reconstruction
    reference_depth : (H, W) float, mm, camera z of the undeformed surface, or None
    box : (rows, cols) slices

    Returns
    -------
    values : (h, w) float, mm, NaN where not reconstructed
    label : unit label of the colour bar
    vmin : 0 for the indentation, None (the maps' percentile rule) for camera z
    """
    shown = rec.reconstructed[box]
    if reference_depth is None:
        return _masked(rec.depth[box], shown), "camera z, mm", None
    return _masked(reference_depth[box] - rec.depth[box], shown), "indentation, mm", 0.0


def solved_box(rec: Reconstruction) -> tuple[slice, slice]:
    """(rows, cols) slices of the bounding box of the solved pixels (``rec.mask``; the whole image if none).

    Figures show this box: a region-of-interest result is drawn at full resolution without a field of
    empty pixels around it (and costs a fraction of a full-frame map to write); ``report.json``'s
    ``roi`` gives its place in the image.
    """
    rows, cols = np.nonzero(rec.mask)
    if rows.size == 0:
        return slice(None), slice(None)
    return slice(int(rows.min()), int(rows.max()) + 1), slice(int(cols.min()), int(cols.max()) + 1)


def box_words(box: tuple[slice, slice], shape: tuple[int, ...]) -> str:
    """Where a summary's box lies in the image, for its title ("pixels u 47-112, v 27-91", first and last pixel
    counted from 0, as ``--roi``'s x0 y0), or "" for the whole image: the panels carry no axes, and a
    ``--roi auto`` crop did not say which part of the capture it shows.

    Parameters
    ----------
    box : (rows, cols) slices, :func:`solved_box`
    shape : (H, W, ...) of the image
    """
    rows, cols = (range(*s.indices(n)) for s, n in zip(box, shape[:2]))
    if len(rows) == shape[0] and len(cols) == shape[1]:
        return ""
    return f"pixels u {cols[0]}-{cols[-1]}, v {rows[0]}-{rows[-1]}"


def error_map(
    rec: Reconstruction, ground_truth: GroundTruth | None, box: tuple[slice, slice] = (slice(None), slice(None))
) -> np.ndarray | None:
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


def _summary(
    path: Path,
    rec: Reconstruction,
    box: tuple[slice, slice],
    error: tuple[np.ndarray, np.ndarray, float] | None,
    depth_view: tuple,
    residual: np.ndarray | None,
    title: str,
) -> Path:
    """One matplotlib sheet of the result over the solved box, titled with the press and the method.

    ``residual``: the RMS residual over ``box`` (NaN off the solved pixels), or None for a result without one.
    ``error``: the angular error map over ``box`` (degrees, NaN off the scored pixels), the truth's contact mask
    over ``box`` and error.png's colour bar top (degrees, :func:`.figures.error_scale`), or None without ground
    truth.
    """
    from .figures import NORMALS_KEY, Panel, contact_sheet, error_panel, normals_to_rgb
    from .maps import colour_range

    shown = rec.reconstructed[box]
    depth, depth_label, depth_min = depth_view
    panels = [
        Panel("normals", normals_to_rgb(rec.normals[box], shown)),
        # the maps' colour range rule, so depth.png and this panel show the same scale
        Panel(depth_label.split(",")[0], depth, "viridis", depth_label, *colour_range(depth, depth_min)),
    ]
    if residual is not None:
        panels.append(Panel("RMS residual", residual, "magma", RESIDUAL_UNIT, *colour_range(residual)))
    if error is not None:
        err, contact, top = error  # error.png's colour range, so the two show the same scale
        panels.append(error_panel(error_title(err, contact), err, top))
    return contact_sheet([("", panels)], path, dpi=150, caption=NORMALS_KEY, title=title)


def error_title(err: np.ndarray, contact: np.ndarray | None) -> str:
    """The summary's error panel title: the AAE over every scored pixel and over the truth's contact region, as
    ``nlips eval --region all`` and ``--region contact`` print them.

    Why both: the AAE of the solved box alone read as the press's number (coin1: 3.40 deg printed, while its
    contact AAE, the figure every report quotes, is 4.64 deg).

    Parameters
    ----------
    err : (h, w) float, degrees, NaN off the scored pixels
    contact : (h, w) bool, the truth's contact region, or None
    """
    title = f"angular error\nAAE {np.nanmean(err):.2f} deg"
    in_contact = err[contact & np.isfinite(err)] if contact is not None else err[:0]
    return title + (f", contact {in_contact.mean():.2f} deg" if in_contact.size else ", no contact")
