"""Shared pieces of the experiment definitions: sizes of the twin, indenters, figure helpers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.imageio import read_npz
from ..report import experiments as fig
from ..sim.indenters import IndenterConfig
from .framework import WorkFigure
from .summary import aggregate

SPHERE = IndenterConfig(kind="sphere", size=6.0)
CUBE = IndenterConfig(kind="cube", size=5.0)
SCREW = IndenterConfig(kind="screw", size=4.0, length=10.0)

MAP_ARRAYS = ("true", "estimate", "error")
"""The arrays of an evaluation's error map (maps/*.npz, ``tasks._solve_one``) that a figure draws."""
MAPS_NEED = "the presses' true and NLiPs normal maps (work folder maps/*.npz)"
"""What an error-map figure is drawn from (said when a redraw keeps it)."""

QUICK_TWIN = {"width": 96, "height": 72, "spp": 8, "bounces": 1, "reference_spp": 64}
"""CI size: tiny images, few samples (noisy numbers; they test the plumbing and catch gross regressions); the
undeformed reference at 64 spp, so that LED self-calibration from it is reliable (``TwinConfig.reference_spp``)."""
MEDIUM_TWIN = {"width": 320, "height": 240, "spp": 16, "bounces": 1}
"""What fits a shared 2-core machine in an hour or so."""
FULL_TWIN = {"width": 640, "height": 480, "spp": 16, "bounces": 1}
"""The default twin's full resolution."""


def series_by(
    rows: list[dict],
    category: str,
    series: str,
    metric: str,
    categories: list | None = None,
    labels: list | None = None,
) -> tuple[list, dict[str, tuple[list[float], list[float]]]]:
    """Means and standard deviations of ``metric`` per (series label, category) for bar charts and sweeps."""
    agg = aggregate(rows, (series, category))
    categories = categories or list(dict.fromkeys(r[category] for r in rows))
    labels = labels or list(dict.fromkeys(r[series] for r in rows))
    out = {}
    for label in labels:
        found = {r[category]: r for r in agg if r[series] == label}
        out[str(label)] = (
            [found[c][metric] if c in found else np.nan for c in categories],
            [found[c][metric + "_std"] if c in found else np.nan for c in categories],
        )
    return categories, out


def map_rows(rows: list[dict], out: Path, key: tuple[str, ...], limit: int = 6) -> list:
    """Error-map figure rows: the first evaluation of each distinct ``key`` labels (at most ``limit``), each titled
    with its labels, its press and its contact AAE (``aae_deg``, the number of the report's tables: the sheets
    showed error maps without a number to read them by)."""
    seen, picked = set(), []
    for r in rows:
        name = tuple(r[k] for k in key)
        if name in seen or not r.get("map") or len(picked) >= limit:
            continue
        seen.add(name)
        # a damaged map (a copied or cut-short folder) is one line naming it, not numpy's traceback
        z = read_npz(_map_path(out, r["map"]), MAP_ARRAYS, "damaged or truncated error map", only=MAP_ARRAYS)
        title = ", ".join(str(v) for v in name) + f"\n{r['press']}" + _contact_line(r.get("aae_deg"))
        picked.append((title, z["true"], z["estimate"], z["error"]))
    return picked


def _map_path(out: Path, name: str) -> Path:
    """``out / name``, an evaluation's error map named in results.json; ConfigError unless ``name`` is a path inside
    ``out``: a report folder from elsewhere naming ``/elsewhere/x.npz`` or ``../..`` had it read (docs/formats.md,
    "Files from others")."""
    from ..core.errors import ConfigError

    if not isinstance(name, str) or Path(name).is_absolute() or ".." in Path(name).parts:
        raise ConfigError(f"{out}: an evaluation's error map {name!r} is not a file inside the experiment's folder")
    return Path(out) / name


def _contact_line(aae_deg: float | None) -> str:
    """An error-map row title's last line: the press's contact AAE ("" where the evaluation has none)."""
    return f"\ncontact AAE {aae_deg:.2f} deg" if aae_deg is not None and np.isfinite(aae_deg) else ""


def draw_error_maps(
    rows: list[dict], out: Path, key: tuple[str, ...], figure: WorkFigure, folder: Path, limit: int = 6
) -> list[WorkFigure]:
    """The error-map figure of :func:`map_rows` drawn into ``folder``: ``[figure]``, or [] without any map."""
    maps = map_rows(rows, out, key, limit)
    if not maps:
        return []
    fig.error_maps(maps, Path(folder) / figure.file, title=figure.caption)
    return [figure]
