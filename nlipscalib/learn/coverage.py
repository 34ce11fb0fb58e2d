"""Coverage of a calibration dataset: which dome regions and normal directions the presses taught.

The image is cut into ``cells x cells`` regions; in each, the contact samples' normals are binned by
how they tilt away from the undeformed surface there: tilt angle rings x tilt azimuth sectors (the
"sphere of directions" per region, relative to the local dome normal, so that every region has the
same bins). A bin is covered when it holds at least ``min_samples`` samples. The next press goes to
the region with the most empty bins, with the indenter kind (among those already pressed) whose
normals best fill exactly those bins.

No pressed kind can fill tilt rings that none of them ever reached: smooth indenters (sphere, cube,
cylinder) tilt the gel by at most ~30 deg, while engraved or embossed detail tilts it by 45-90 deg (the
default twin: 99 % of the contact normals of 50 sphere/cube/cylinder presses within 32 deg; 12 % of a
coin's beyond 45 deg). NLiPsNet maps colour to normal pixel by pixel and extrapolates past what it was
taught: on the twin's Q2 it errs 5 deg on an unseen coin, 1-2 deg on smooth unseen indenters, with true
labels too. So the report also says how steep the taught normals are and, when the steepest rings are
empty everywhere, asks for a press with steep relief.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.atomic import write_json
from ..core.metrics import angular_error_map
from ..core.reconstruction import jsonable
from ..core.tolerances import COVERAGE_GEL_SHARE

if TYPE_CHECKING:  # named in hints only: the dataset module is not needed to measure one
    from collections.abc import Callable

    from ..core.camera import Camera
    from .dataset import CalibrationDataset

TILT_EDGES_DEG = (2.0, 10.0, 25.0, 45.0, 90.0)
"""Tilt rings, degrees from the undeformed normal (below 2 deg counts as undeformed)."""
AZIMUTH_SECTORS = 8
"""Tilt directions per ring (image-plane azimuth of the tilt)."""
STEEP_RELIEF = (
    "an object with steep relief (studs, ridges, embossed or engraved detail, "
    "e.g. a LEGO brick's studs, a knurled cap's side or a coin's face)"
)
"""What the advice asks for when no press reached the steepest tilt rings."""
TAUGHT_PERCENTILE = 99.0
"""``taught_tilt_deg``: this percentile of the contact samples' tilt (a few stray labels do not count)."""


def direction_bins(normals: np.ndarray, ref_normals: np.ndarray) -> np.ndarray:
    """Direction bin of each normal relative to the undeformed normal; -1 when tilted less than 2 deg.

    Parameters
    ----------
    normals, ref_normals : (N, 3) float, unit, camera frame

    Returns
    -------
    (N,) int -- ring * AZIMUTH_SECTORS + sector, or -1
    """
    tilt = tilt_deg(normals, ref_normals)
    ring = np.searchsorted(TILT_EDGES_DEG, tilt, side="right") - 1
    d = normals - ref_normals
    sector = ((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / (2 * np.pi) * AZIMUTH_SECTORS).astype(int) % AZIMUTH_SECTORS
    return np.where(ring >= 0, np.minimum(ring, len(TILT_EDGES_DEG) - 2) * AZIMUTH_SECTORS + sector, -1)


def tilt_deg(normals: np.ndarray, ref_normals: np.ndarray) -> np.ndarray:
    """(N,) float, degrees -- angle of each normal from the undeformed normal at its pixel.

    Parameters
    ----------
    normals, ref_normals : (N, 3) float, unit, camera frame
    """
    return angular_error_map(normals, ref_normals)  # the metric's angle, read as a tilt


def coverage(
    dataset: CalibrationDataset,
    cells: int = 4,
    min_samples: int = 20,
    camera_position: tuple[float, float, float] | None = None,
) -> dict:
    """Coverage of ``dataset`` (CalibrationDataset): counts per (region, direction bin) and the next press.

    ``camera_position``: the camera in the dome frame, mm (``core.sensor_record.camera_position_of`` the
    reference's meta.json); given, the next press is also said as its press direction (polar, azimuth), the way
    the twin (``nlips render --polar --azimuth``) and a lab's indenter stage place a press.

    Returns
    -------
    dict with ``counts`` (cells, cells, B) int (region row, region column, direction bin), ``gel``
    (cells, cells) bool (regions that see the gel), ``covered_fraction``, per-kind direction histograms
    ``kinds``, ``next_press`` (region box in pixels, centre (u, v), press direction or None, indenter kind,
    advice text), ``steep`` (how steep the taught normals are, the advice when the steepest rings are empty:
    :func:`steep_gap`), ``tricolor`` (the presses left out or kept for a tri-colour frame unlike their LED images:
    :func:`tricolor_presses`) and the bin layout (tilt ring edges, sectors).
    """
    ref = dataset.reference()
    H, W = ref["valid"].shape
    n_bins = (len(TILT_EDGES_DEG) - 1) * AZIMUTH_SECTORS
    counts = np.zeros((cells, cells, n_bins), np.int64)
    kinds: dict[str, np.ndarray] = {}
    tilts = np.zeros(181, np.int64)  # contact samples per whole degree of tilt
    for entry in dataset.entries:
        s = dataset.load(entry["name"])
        keep = s["contact"] & (s["source"] == 0)
        u, v = s["pixel"][keep, 0].astype(int), s["pixel"][keep, 1].astype(int)
        normals, ref_normals = s["normal"][keep], ref["normals"][v, u]
        tilts += np.bincount(tilt_deg(normals, ref_normals).astype(int), minlength=181)[:181]
        b = direction_bins(normals, ref_normals)
        ok = b >= 0
        np.add.at(counts, (v[ok] * cells // H, u[ok] * cells // W, b[ok]), 1)
        kind = recorded_kind(entry)
        kinds[kind] = kinds.get(kind, np.zeros(n_bins)) + np.bincount(b[ok], minlength=n_bins)
    gel = _gel_regions(ref["valid"], cells)
    covered = counts >= min_samples
    fraction = float(covered[gel].mean()) if gel.any() else 0.0
    where = None
    if camera_position is not None:
        from ..core.camera import Camera

        camera = Camera.from_dict(dataset.sensor["camera"])
        where = lambda box: region_press_angles(box, ref["depth"], camera, camera_position)  # noqa: E731
    return {
        "cells": cells,
        "min_samples": min_samples,
        "tilt_edges_deg": list(TILT_EDGES_DEG),
        "azimuth_sectors": AZIMUTH_SECTORS,
        "image_size": [W, H],
        "counts": counts,
        "gel": gel,
        "covered_fraction": fraction,
        "kinds": {k: (h / max(h.sum(), 1)).round(4) for k, h in kinds.items()},
        "next_press": _next_press(counts, covered, gel, kinds, ref["valid"], where),
        "steep": steep_gap(covered, gel, tilts),
        "tricolor": tricolor_presses(dataset),
    }


def tricolor_presses(dataset: CalibrationDataset) -> dict:
    """The presses whose tri-colour frame does not hold their LED images' light (``nlips calibrate``'s check,
    :mod:`.dataset_tricolor`): ``left_out`` (names; their regions count as not pressed), ``kept`` (names, kept with
    ``--keep-tricolor-mismatch``), and the ``advice`` line ("" when there are none)."""
    left = [gone["name"] for gone in dataset.tricolor_left_out]
    kept = dataset.tricolor_kept
    advice = []
    if left:
        advice.append(
            f"{_count(left)} left out of the dataset, whose tri-colour frame does not hold its LED images' light "
            f"({_shown(left)}): what they pressed is not covered; capture them again"
        )
    if kept:
        advice.append(
            f"{_count(kept)} in the dataset whose tri-colour frame does not hold its LED images' light, kept with "
            f"--keep-tricolor-mismatch ({_shown(kept)})"
        )
    return {"left_out": left, "kept": kept, "advice": "; ".join(advice)}


def _count(names: list[str]) -> str:
    return f"{len(names)} press{'es' if len(names) != 1 else ''}"


def _shown(names: list[str]) -> str:
    return ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")


def steep_gap(covered: np.ndarray, gel: np.ndarray, tilt_counts: np.ndarray) -> dict:
    """How steep the taught normals are, and whether the steepest tilt rings are empty in every region.

    Parameters
    ----------
    covered : (cells, cells, B) bool -- covered (region, direction bin)s, B = rings x AZIMUTH_SECTORS.
    gel : (cells, cells) bool -- regions that see the gel.
    tilt_counts : (T,) int -- contact samples per whole degree of tilt (index = floor of the tilt in deg).

    Returns
    -------
    dict: ``taught_tilt_deg`` (:data:`TAUGHT_PERCENTILE` of the samples' tilt; None without samples),
    ``untaught_from_deg`` (the lower edge of the first tilt ring that no region covers in any direction, with
    none covered beyond it; None when the steepest ring is covered somewhere) and ``advice`` ("" or the line
    asking for :data:`STEEP_RELIEF`).
    """
    rings = len(TILT_EDGES_DEG) - 1
    ring_covered = (
        covered[gel].reshape(-1, rings, AZIMUTH_SECTORS).any(axis=(0, 2)) if gel.any() else np.zeros(rings, bool)
    )
    reached = np.flatnonzero(ring_covered)
    first_empty = int(reached[-1]) + 1 if reached.size else 0
    total = int(tilt_counts.sum())
    taught = None
    if total:
        cumulative = np.cumsum(tilt_counts)
        taught = float(np.searchsorted(cumulative, TAUGHT_PERCENTILE / 100 * total) + 1)  # upper edge of its degree
    if first_empty >= rings:
        return {"taught_tilt_deg": taught, "untaught_from_deg": None, "advice": ""}
    edge = float(TILT_EDGES_DEG[first_empty])
    within = f"{TAUGHT_PERCENTILE:.0f} % of the contact samples within {taught:.0f} deg" if taught else "no samples"
    advice = (
        f"no press tilts the gel's normals by more than {edge:.0f} deg ({within}); NLiPsNet will extrapolate "
        f"steeper ones (edges, engraved or embossed detail): press {STEEP_RELIEF} too"
    )
    return {"taught_tilt_deg": taught, "untaught_from_deg": edge, "advice": advice}


UNRECORDED_KIND = "object"
"""The indenter kind of presses that record none (captured on a sensor: the operator's object is unnamed)."""
LEGACY_UNRECORDED = "unknown"
"""What datasets built before 2026-12-04 evening recorded for such presses (now null): read as unrecorded too."""


def recorded_kind(entry: dict) -> str:
    """The indenter kind of a dataset entry (index.json ``presses[i].press.indenter``), or :data:`UNRECORDED_KIND`
    for a press that records none (null, or an older dataset's "unknown")."""
    press = entry.get("press")
    kind = press.get("indenter") if isinstance(press, dict) else None
    return kind if isinstance(kind, str) and kind and kind != LEGACY_UNRECORDED else UNRECORDED_KIND


def _with_article(kind: str) -> str:
    """'a sphere', 'an object', 'any indenter'."""
    if kind.startswith("any "):
        return kind
    return f"{'an' if kind[:1].lower() in 'aeiou' else 'a'} {kind}"


def _gel_regions(valid: np.ndarray, cells: int) -> np.ndarray:
    """Regions where at least :data:`~nlipscalib.core.tolerances.COVERAGE_GEL_SHARE` of the pixels see the gel."""
    H, W = valid.shape
    rr = np.arange(H)[:, None] * cells // H
    cc = np.arange(W)[None, :] * cells // W
    frac = np.zeros((cells, cells))
    np.add.at(frac, (np.broadcast_to(rr, valid.shape), np.broadcast_to(cc, valid.shape)), valid)
    return frac / (H * W / cells**2) >= COVERAGE_GEL_SHARE


def region_press_angles(
    box: list[int], depth: np.ndarray, camera: Camera, camera_position: tuple[float, float, float]
) -> tuple[float, float] | None:
    """The press direction ``(polar_deg, azimuth_deg)`` (``core.dome.press_angles``) of the gel pixel nearest the
    centre of an image region's gel pixels (:func:`gel_centre`); None when no pixel of it sees the gel.

    Parameters
    ----------
    box : [u0, v0, u1, v1], pixels, end exclusive
    depth : (H, W) float, mm, camera-frame z of the undeformed gel; NaN off the gel
    camera : core Camera of the sensor
    camera_position : (3,) float, mm, the camera in the dome frame (``p_camera = p_dome - camera_position``)
    """
    from ..core.dome import press_angles

    u0, v0, u1, v1 = box
    v, u = np.nonzero(np.isfinite(depth[v0:v1, u0:u1]))
    if len(u) == 0:
        return None
    centre_u, centre_v = gel_centre(box, np.isfinite(depth))
    nearest = int(np.argmin((u0 + u - centre_u) ** 2 + (v0 + v - centre_v) ** 2))
    row, col = v0 + int(v[nearest]), u0 + int(u[nearest])
    ray = camera.unproject(np.array([col, row], float))
    point = ray * (depth[row, col] / ray[2])  # camera frame, on the gel
    return press_angles(point + np.asarray(camera_position, float))


def gel_centre(box: list[int], valid: np.ndarray) -> tuple[float, float]:
    """The mean (u, v) of an image region's gel pixels, pixels; the box's centre when none sees the gel.

    Where the gel fills the region this is the box's centre; where it does not (a camera that sees beyond the gel:
    black corners, the housing), the next press is placed on the gel the region holds, not on its black corner
    (s32-rimview: "centre u=20, v=14", a pixel off the gel, was advised).

    Parameters
    ----------
    box : [u0, v0, u1, v1], pixels, end exclusive
    valid : (H, W) bool -- the pixels that see the gel
    """
    u0, v0, u1, v1 = box
    v, u = np.nonzero(valid[v0:v1, u0:u1])
    if len(u) == 0:
        return (u0 + u1 - 1) / 2, (v0 + v1 - 1) / 2
    return u0 + float(u.mean()), v0 + float(v.mean())


def _next_press(
    counts: np.ndarray,
    covered: np.ndarray,
    gel: np.ndarray,
    kinds: dict,
    valid: np.ndarray,
    where: Callable[[list[int]], tuple[float, float] | None] | None = None,
) -> dict:
    H, W = valid.shape
    cells = counts.shape[0]
    empty = np.where(gel, (~covered).sum(-1), -1)
    # most empty bins first, then fewest samples
    order = np.lexsort((counts.sum(-1).ravel(), -empty.ravel()))
    r, c = divmod(int(order[0]), cells)
    gap = ~covered[r, c]
    # bins of the gap the kind has ever reached, then how much of its normals fall there
    scores = {k: float((h[gap] > 0).sum() + h[gap].sum() / max(h.sum(), 1)) for k, h in kinds.items()}
    kind = max(scores, key=scores.get) if scores else "any indenter"
    box = [c * W // cells, r * H // cells, (c + 1) * W // cells, (r + 1) * H // cells]
    centre = list(gel_centre(box, valid))
    angles = where(box) if where is not None else None
    # the twin's and an indenter stage's way to place a press, beside the image region
    direction = f"; press direction polar {angles[0]:.0f}°, azimuth {angles[1]:.0f}°" if angles else ""
    advice = (
        f"{_with_article(kind)} in image region u {box[0]}-{box[2] - 1}, v {box[1]}-{box[3] - 1} "
        f"(centre u={centre[0]:.0f}, v={centre[1]:.0f}{direction}): {int(gap.sum())} of {gap.size} direction bins "
        "empty there"
    )
    return {
        "region": [r, c],
        "box_u0_v0_u1_v1": box,
        "centre_uv": centre,
        "polar_deg": None if angles is None else round(angles[0], 1),
        "azimuth_deg": None if angles is None else round(angles[1], 1),
        "indenter": kind,
        "kind_scores": scores,
        "empty_bins": int(gap.sum()),
        "advice": advice,
    }


def write_coverage_json(path: str | Path, cov: dict) -> Path:
    """coverage.json: the dict of :func:`coverage` (arrays as nested lists)."""
    return write_json(path, jsonable(cov))
