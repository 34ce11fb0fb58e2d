"""Figures of the experiment reports (``nlips experiment``): bar charts, sweeps, error maps. Small PNGs."""

from __future__ import annotations

import io
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.atomic import write_bytes
from .figures import (
    NORMALS_KEY,
    Panel,
    axis_from_zero,
    contact_sheet,
    display_image,
    error_panel,
    error_scale,
    new_figure,
    normals_to_rgb,
    png_bytes,
)

if TYPE_CHECKING:  # named in hints only: matplotlib is imported where a figure is drawn
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

DPI = 100
"""Resolution of every report figure, charts and map sheets: their smallest text, 7 pt (legends, colour-bar
numbers), is then 9.7 px tall (:data:`.figures.MIN_TEXT_PX`). The charts were saved at 80 dpi to keep the committed
PNGs small, their legends 7.8 px tall and unreadable; the palette PNG keeps them small (a chart ~10 kB)."""
TITLE_PT = 9
"""Font size of a chart's title (the caption report.md gives it), points."""
MABSE_LABEL = "MabsE in the contact (unitless)"
"""The y axis of the MabsE charts: MabsE, the mean absolute error of the unit normals' components (core.metrics),
has no unit, which the bare "MabsE in the contact" did not say (naming the components ran off a 3.2-in axis)."""


def _save(fig: Figure, path: str | Path) -> Path:
    fig.tight_layout()
    return write_bytes(path, _palette_png(png_bytes(fig, DPI)))


PALETTE_MAX_ERROR = 3.0
"""Largest 99th-percentile colour error (8-bit levels) a 256-colour palette may add to a figure."""


def _palette_png(png: bytes) -> bytes:
    """The same picture as a 256-colour palette PNG when that is faithful, else the RGB PNG (Pillow).

    Charts and noisy error maps shrink several times as palettes, but smooth normal maps posterise
    into patches that look like mesh facets (seen in the first full Q3 report), so a palette whose
    99th-percentile colour error exceeds ``PALETTE_MAX_ERROR`` levels is not used."""
    from PIL import Image

    rgb = Image.open(io.BytesIO(png)).convert("RGB")
    pal = rgb.quantize(256)
    err = np.abs(np.asarray(pal.convert("RGB"), np.int16) - np.asarray(rgb, np.int16)).max(axis=-1)
    img = pal if np.percentile(err, 99) <= PALETTE_MAX_ERROR else rgb
    buf = io.BytesIO()
    img.save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def _figure(width: float = 5.0, height: float = 3.2) -> tuple[Figure, Axes]:
    fig = new_figure(figsize=(width, height))
    return fig, fig.subplots()


LEGEND_WIDTH_IN = 2.3
"""Width (inches) added to a chart for its legend, which stands right of the axes."""


def _legend_outside(fig: Figure, ax: Axes) -> None:
    """The legend right of the axes: inside, matplotlib's best place still covered the tallest bars of a chart of
    five methods (the first quick Q2 report hid the lookup table's and the undeformed dome's bars)."""
    width, height = fig.get_size_inches()
    fig.set_size_inches(width + LEGEND_WIDTH_IN, height)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)


def grouped_bars(
    categories: list[str],
    series: dict[str, tuple[list[float], list[float]]],
    ylabel: str,
    path: str | Path,
    lines: dict[str, float] | None = None,
    title: str = "",
) -> Path:
    """Bars of ``series`` (label -> (means, standard deviations) per category) with horizontal reference lines.

    Parameters
    ----------
    categories : group names on the x axis
    series : label -> (means, stds), each of len(categories); a NaN mean is marked "n/a", a std of 0 or NaN
        draws no error bar
    lines : label -> value drawn as a dashed horizontal line (e.g. the paper's real-sensor number)
    title : what the chart shows (report.md's caption of it), over the axes: the PNG opened alone says it too
    """
    fig, ax = _figure(max(4.0, 1.1 * len(categories) + 2), 3.2)
    x = np.arange(len(categories))
    width = 0.8 / max(len(series), 1)
    for i, (label, (mean, std)) in enumerate(series.items()):
        xpos = x + (i - (len(series) - 1) / 2) * width
        mean, std = np.asarray(mean, float), np.asarray(std, float)
        missing = ~np.isfinite(mean)
        # no error bar where no spread was measured (one sample, or none given): a zero-length cap reads as +-0
        spread = np.where(np.isfinite(std) & (std > 0) & ~missing, std, 0.0)
        bars = ax.bar(
            xpos, np.where(missing, 0.0, mean), width, yerr=spread if spread.any() else None, label=label, capsize=2
        )
        for pos in xpos[missing]:  # an empty slot would read as 0: say that there is no value
            colour = bars.patches[0].get_facecolor()
            ax.text(pos, 0, " n/a", rotation=90, ha="center", va="bottom", fontsize=7, color=colour)
    for j, (label, value) in enumerate((lines or {}).items()):
        ax.axhline(value, ls="--", lw=1, color=f"C{len(series) + j}", label=label)
    ax.set_xticks(x, categories, fontsize=8)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=TITLE_PT)
    _legend_outside(fig, ax)
    return _save(fig, path)


def sweep(
    series: dict[str, tuple[list, list[float], list[float]]],
    xlabel: str,
    ylabel: str,
    path: str | Path,
    paper: dict[str, tuple[list, list[float]]] | None = None,
    categorical: bool = False,
    title: str = "",
) -> Path:
    """Curves of a parameter sweep: label -> (x values, means, standard deviations); paper points as markers.

    ``categorical``: x values are names (placed at 0, 1, 2...). ``title``: what the chart shows (report.md's
    caption of it), over the axes.
    """
    fig, ax = _figure()
    ticks = None
    for label, (x, mean, std) in series.items():
        xs = np.arange(len(x)) if categorical else np.asarray(x, float)
        ticks = x if categorical else ticks
        # names have no order: markers alone (a line between "1 bounce, uncorrected" and "reference-corrected"
        # drew a trend between unrelated settings)
        ax.errorbar(xs, mean, yerr=std, marker="o", ms=4, capsize=2, label=label, ls="none" if categorical else "-")
    for label, (x, y) in (paper or {}).items():
        ax.plot(np.asarray(x, float), y, "k*", ms=9, label=label)
    if ticks is not None:
        ax.set_xticks(np.arange(len(ticks)), [str(t) for t in ticks], fontsize=8, rotation=15)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=TITLE_PT)
    axis_from_zero(ax)
    _legend_outside(fig, ax)
    return _save(fig, path)


def error_maps(
    rows: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]],
    path: str | Path,
    vmax: float | None = None,
    title: str = "",
) -> Path:
    """One row per press: true normals, estimated normals, angular error (degrees, colour bar).

    Parameters
    ----------
    rows : (title, true (h, w, 3) float, estimate (h, w, 3) float, error (h, w) float degrees); NaN = not solved
    vmax : upper end of every error colour bar, degrees (None: each row's :func:`error_scale`, see
        :func:`row_error_scale`)
    title : what the sheet shows (report.md's caption of it), over the grid
    """
    sheet = []
    for row_title, true, est, err in rows:
        shown = np.isfinite(err)
        sheet.append(
            (
                row_title,
                [
                    Panel("true normals", normals_to_rgb(true, shown)),
                    Panel("NLiPs normals", normals_to_rgb(est, shown)),
                    error_panel("angular error", err, row_error_scale(err, vmax)),
                ],
            )
        )
    contact_sheet(sheet, path, dpi=DPI, caption=NORMALS_KEY, title=title)
    return write_bytes(path, _palette_png(Path(path).read_bytes()))


def nlipsnet_maps(
    rows: list[tuple[str, dict[str, np.ndarray]]],
    path: str | Path,
    vmax: float | None = None,
    method: str = "NLiPsNet",
    title: str = "",
    scores: list[dict] | None = None,
) -> Path:
    """The paper's NLiPsNet figure: per press, the object, true normals, predicted normals, angular error.

    Parameters
    ----------
    rows : (title, {"rgb": (h, w, 3) linear tri-colour image, "true": (h, w, 3) unit normals,
        "estimate": (h, w, 3) unit normals, "error": (h, w) degrees}); NaN = off the gel
    vmax : upper end of every error colour bar, degrees (None: each row's :func:`error_scale`, see
        :func:`row_error_scale`)
    title : what the sheet shows (report.md's caption of it), over the grid
    scores : per row, the press's contact AAE (degrees) as the report's tables hold it: ``aae_vs_nlips_deg`` in the
        predicted normals' title, ``aae_vs_true_deg`` in the error's (None, NaN or missing: not printed); None: no
        scores
    """
    if scores is not None and len(scores) != len(rows):
        raise ValueError(f"nlipsnet_maps: {len(scores)} scores for {len(rows)} rows")
    sheet = []
    for i, (row_title, v) in enumerate(rows):
        shown = np.isfinite(v["error"])
        score = scores[i] if scores else {}
        sheet.append(
            (
                row_title,
                [
                    Panel("object (tri-colour image)", display_image(v["rgb"])),  # as the demo shows it
                    Panel("ground-truth normals", normals_to_rgb(v["true"], shown)),
                    Panel(
                        f"{method} normals" + _aae_line(score.get("aae_vs_nlips_deg"), " vs labels"),
                        normals_to_rgb(v["estimate"], shown),
                    ),
                    error_panel(
                        "angular error vs truth" + _aae_line(score.get("aae_vs_true_deg")),
                        v["error"],
                        row_error_scale(v["error"], vmax),
                    ),
                ],
            )
        )
    contact_sheet(sheet, path, dpi=DPI, caption=NORMALS_KEY, title=title)
    return write_bytes(path, _palette_png(Path(path).read_bytes()))


def _aae_line(aae_deg: float | None, against: str = "") -> str:
    """A panel title's second line: a press's contact AAE ("" where it has none: no contact sample scored).

    Why in the titles: the sheet showed each press's maps without its number, and the error map alone (every pixel
    of the crop, against the truth) does not tell the contact's AAE the report's tables give."""
    if aae_deg is None or not np.isfinite(aae_deg):
        return ""
    return f"\ncontact AAE{against} {aae_deg:.2f} deg"


def row_error_scale(error: np.ndarray, vmax: float | None = None) -> float:
    """The error colour bar's upper end of one row of a map sheet, degrees: ``vmax`` where given, else the row's own
    :func:`error_scale`. Why not one range for the sheet: a coin's 20-45 deg edges set it, and the sphere's and
    the cube's half-degree errors beside it were black squares (Q2's sheet: 0-20 deg on every row); each row has
    its own colour bar, as the demo's sheet (cli/demo.py) does.

    Parameters
    ----------
    error : (h, w) float, degrees, NaN = not scored
    """
    return error_scale([error]) if vmax is None else vmax
