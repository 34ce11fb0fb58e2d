"""Pictures people look at: normal maps, error maps with colour bars, contact sheets (matplotlib)."""

from __future__ import annotations

import dataclasses
import io
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.atomic import write_bytes

if TYPE_CHECKING:  # named in hints only: matplotlib is imported where a figure is drawn
    from matplotlib.axes import Axes
    from matplotlib.colors import Colormap
    from matplotlib.figure import Figure

ERROR_CMAP = "inferno"
"""Colour map of angular error in every figure (OpenCV maps, summaries, the demo and experiment sheets), so the
same error looks the same everywhere; dark = small error."""
NORMALS_KEY = (
    "normal colours: RGB = ((n_x, -n_y, -n_z) + 1) / 2, camera frame: red = right, green = up, blue = toward the camera"
)
"""Caption of sheets that show normal maps (:func:`normals_to_rgb`'s convention, docs/conventions.md)."""
NO_VALUE_GREY = 0.85
"""Grey level (0 black, 1 white) of pixels without a value (off the gel, not solved, NaN) in every figure: normal
maps, scalar panels and the OpenCV maps alike. Not black: in the error colour map black is a small error, and q3's
sheets drew off-gel pixels black in the normal panels beside grey in the error panel."""
ERROR_SCALES_DEG = (1.0, 2.0, 5.0, 10.0, 20.0, 45.0)
"""Upper ends the angular-error colour bar chooses from (:func:`error_scale`)."""
ERROR_UNIT = "deg"
"""Unit label of every angular-error colour bar (the OpenCV error.png's, the sheets'), as the AAE titles write it:
the sheets said "degrees" beside a summary's and error.png's "deg"."""
MIN_TEXT_PX = 9.0
"""Smallest text a saved figure may hold, pixels tall (font size in points x dpi / 72). The experiment charts,
saved at 80 dpi, had 7-pt legends 7.8 px tall: the method names could not be read."""


def new_figure(**kwargs: object) -> Figure:
    """A matplotlib figure of the package's own, outside pyplot (``kwargs``: :class:`matplotlib.figure.Figure`'s,
    e.g. ``figsize``), on an Agg canvas (``fig.canvas.draw()``, ``buffer_rgba()``, ``savefig``).

    Why not pyplot: its figures and backend are the whole process's. In a Jupyter notebook each of our figures
    made with ``plt.figure()`` was also shown under the cell (the inline backend shows every open pyplot figure
    at the end of a cell), and ``matplotlib.use("Agg")``, called to draw files on a machine without a display,
    switched the notebook's own backend: every figure the user had open was closed and their later
    ``plt.show()`` showed nothing ("FigureCanvasAgg is non-interactive, and thus cannot be shown"). A figure
    made here is the caller's alone: shown only where it is displayed, and freed with its last reference (no
    ``plt.close``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(**kwargs)
    FigureCanvasAgg(fig)  # the canvas attaches itself to the figure
    return fig


def error_scale(errors: Iterable[np.ndarray]) -> float:
    """The colour bar's upper end for angular error maps: the smallest of ``ERROR_SCALES_DEG`` at or above
    the 99th percentile of all their finite values (a fixed 20 deg shows half-degree errors as black).

    Parameters
    ----------
    errors : iterable of (h, w) float arrays, degrees, NaN = no value
    """
    values = np.concatenate([np.asarray(e, float)[np.isfinite(e)].ravel() for e in errors] or [np.zeros(0)])
    top = float(np.percentile(values, 99)) if values.size else 0.0
    return next((v for v in ERROR_SCALES_DEG if v >= top), ERROR_SCALES_DEG[-1])


def normals_to_rgb(normals: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Normal map as an image, in the usual normal-map colours: a surface facing the camera is blue.

    Parameters
    ----------
    normals : (H, W, 3) float, unit, camera frame (toward the camera, docs/conventions.md)
    mask : (H, W) bool, optional -- pixels outside are shown :data:`NO_VALUE_GREY`, as are NaN normals

    Returns
    -------
    rgb : (H, W, 3) float in [0, 1], RGB = ((n_x, -n_y, -n_z) + 1) / 2 -- x right, y up, z toward the viewer
    """
    n = np.nan_to_num(normals)
    rgb = np.clip((np.stack([n[..., 0], -n[..., 1], -n[..., 2]], axis=-1) + 1.0) / 2.0, 0.0, 1.0)
    missing = ~np.isfinite(normals).all(axis=-1)
    if mask is not None:
        missing |= ~mask
    rgb[missing] = NO_VALUE_GREY
    return rgb


def display_image(linear: np.ndarray, percentile: float = 99.5) -> np.ndarray:
    """Linear (H, W, 3) image scaled to [0, 1] with a mild gamma, for viewing only."""
    img = np.clip(np.nan_to_num(linear), 0.0, None)
    top = np.percentile(img, percentile) or 1.0
    return np.clip(img / top, 0.0, 1.0) ** (1 / 2.2)


@dataclasses.dataclass
class Panel:
    """One picture of a contact sheet."""

    title: str
    image: np.ndarray
    """(H, W, 3) RGB in [0, 1], or (H, W) scalar shown with ``cmap`` and a colour bar."""
    cmap: str = "viridis"
    label: str = ""
    """Colour bar label (scalar panels)."""
    vmin: float | None = None
    vmax: float | None = None
    legend: tuple[str, ...] = ()
    """Names of the values 0, 1, ... of a categorical scalar panel (a mask: ("no contact", "contact")): drawn
    as a legend of its colours instead of a colour bar, whose continuous 0-1 scale means nothing there."""


def error_panel(title: str, error: np.ndarray, vmax: float | None = None) -> Panel:
    """The angular-error panel of every sheet (demo, summary, experiment maps): :data:`ERROR_CMAP` from 0 to ``vmax``
    (None: :func:`error_scale` of ``error``), its colour bar in :data:`ERROR_UNIT`.

    Parameters
    ----------
    title : the panel's title (its AAE, where the caller prints one)
    error : (h, w) float, degrees, NaN = not scored (drawn :data:`NO_VALUE_GREY`)
    vmax : upper end of the colour bar, degrees
    """
    top = error_scale([error]) if vmax is None else vmax
    return Panel(title, error, cmap=ERROR_CMAP, label=ERROR_UNIT, vmin=0.0, vmax=top)


def png_bytes(fig: Figure, dpi: int) -> bytes:
    """``fig`` encoded as a PNG at ``dpi`` (every figure of the package is saved through here)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def save_png(fig: Figure, path: str | Path, dpi: int) -> Path:
    """Write ``fig`` to ``path`` as a PNG at ``dpi``, atomically; returns ``path``."""
    return write_bytes(path, png_bytes(fig, dpi))


ZERO_AXIS_HEADROOM = 0.06
"""Room above the highest point or error bar of an axis drawn from 0 (:func:`axis_from_zero`), as a share of the
axis."""


def axis_from_zero(ax: Axes) -> None:
    """The y axis from 0 to a little above the highest point drawn (error bars and paper markers included): every
    error (AAE, MabsE) axis of report/ -- the experiment sweeps, the training curve's validation AAE -- starts at 0,
    so a glance does not overstate a small gain. Call it before drawing lines that span the axis (``axvline``).

    Why not ``set_ylim(bottom=0)``: it kept matplotlib's top, whose margin is 5 % of the data's own range: on points
    that barely differ (quick studies: noise 1.13 and 1.11 deg) the highest marker sat on the frame, cut in half.

    Parameters
    ----------
    ax : the axes, its data drawn
    """
    top = float(ax.dataLim.y1)
    if np.isfinite(top) and top > 0:
        ax.set_ylim(0, top * (1 + ZERO_AXIS_HEADROOM))
    else:
        ax.set_ylim(bottom=0)


SHEET_DPI = 110
"""Default resolution of a contact sheet (its 7-pt colour-bar numbers are 10.7 px tall, :data:`MIN_TEXT_PX`)."""


def contact_sheet(
    rows: list[tuple[str, list[Panel]]], path: str | Path, dpi: int = SHEET_DPI, caption: str = "", title: str = ""
) -> Path:
    """Save a grid of panels (one row per press) as a PNG, atomically.

    Parameters
    ----------
    rows : list of (row title, panels)
    path : output .png
    caption : one line under the grid, e.g. :data:`NORMALS_KEY` on sheets with normal maps
    title : one line over the grid
    """
    return save_png(sheet_figure(rows, caption, title), path, dpi)


PANEL_WIDTH_IN = 2.2
"""Width of one panel's image on a contact sheet, inches (its height follows the images' aspect ratio)."""
BAR_PAD_IN, BAR_WIDTH_IN = 0.08, 0.12
"""Gap between a panel's image and its colour bar, and the bar's width, inches."""
BAR_ROOM_IN = 0.95
"""Width from a panel's image to the next column's, inches, in a column with colour bars: the bar, its ticks and its
label (a column without one, normal maps: :data:`GAP_IN`)."""
GAP_IN = 0.2
"""Width from a panel's image to the next column's in a column without colour bars, inches."""
TITLE_ROOM_IN = 0.42
"""Height over each row's images for their titles (two lines at 9 pt), inches."""
LEGEND_ROOM_IN = 0.3
"""Height under a row's images for a categorical panel's legend (one line at 7 pt), inches."""
ROW_TITLE_LINE_IN, ROW_TITLE_PAD_IN = 0.18, 0.14
"""Width left of the first column per line of the row titles (10 pt, turned), and the margins beside them, inches:
a fixed 0.5 in held two lines; the experiments' three-line titles ("sphere, true", the press, its contact AAE)
touched the sheet's edge and the images."""
SHEET_TITLE_IN, CAPTION_IN, MARGIN_IN = 0.3, 0.35, 0.1
"""Heights of the sheet's title line and caption line, and the margin where there is none, inches."""
TITLE_PT, CAPTION_PT = 10, 8
"""Font sizes of a sheet's title and caption, points."""
LINE_SPACING = 1.2
"""Height of a line of text in font sizes (matplotlib's own spacing): the room a wrapped title or caption adds."""


def sheet_figure(rows: list[tuple[str, list[Panel]]], caption: str = "", title: str = "") -> Figure:
    """The figure :func:`contact_sheet` saves: one row per entry of ``rows``, every panel's image at one size.

    The panels are placed in inches, not by a layout engine: the figure's size follows the images' aspect ratio (a
    fixed 3.2 x 2.7 in cell left wide gaps beside a square region of interest), each image is
    :data:`PANEL_WIDTH_IN` wide, a colour bar beside it in its own axes (matplotlib's colour bars take their room
    from the image's axes: a normal map, without one, was drawn larger than its neighbours), and no layout pass
    costs a draw (matplotlib's constrained layout took ~0.18 s of CPU more per summary).

    Parameters
    ----------
    rows : list of (row title, panels)
    caption : one line under the grid
    title : one line over the grid
    """
    ncols = max(len(p) for _, p in rows)
    aspect = max((p.image.shape[0] / p.image.shape[1] for _, panels in rows for p in panels), default=1.0)
    image_w, image_h = PANEL_WIDTH_IN, PANEL_WIDTH_IN * aspect
    left = row_title_width(row_title for row_title, _ in rows)
    legends = [LEGEND_ROOM_IN if any(p.legend for p in panels) else 0.0 for _, panels in rows]
    barred = [any(c < len(panels) and _has_bar(panels[c]) for _, panels in rows) for c in range(ncols)]
    columns = np.cumsum([left] + [image_w + (BAR_ROOM_IN if bar else GAP_IN) for bar in barred])  # left edges
    width = columns[-1] + MARGIN_IN
    # a two-panel sheet (an image frame's summary: normals, depth) is narrower than the normal-colour key: it was cut
    # at both edges. The title and the caption are broken into lines that fit, and the sheet grows to hold them
    title, caption = (
        wrap_text(title, TITLE_PT, width - 2 * MARGIN_IN),
        wrap_text(caption, CAPTION_PT, width - 2 * MARGIN_IN),
    )
    title_in = SHEET_TITLE_IN + title.count("\n") * TITLE_PT * LINE_SPACING / 72 if title else MARGIN_IN
    caption_in = CAPTION_IN + caption.count("\n") * CAPTION_PT * LINE_SPACING / 72 if caption else MARGIN_IN
    height = title_in + sum(TITLE_ROOM_IN + image_h + legend for legend in legends) + caption_in
    fig = new_figure(figsize=(width, height))

    def box(x: float, y: float, w: float, h: float) -> tuple[float, float, float, float]:
        return x / width, y / height, w / width, h / height  # inches from the bottom left -> figure fractions

    top = height - title_in
    for (row_title, panels), legend in zip(rows, legends):
        bottom = top - TITLE_ROOM_IN - image_h
        for c, panel in enumerate(panels):
            x = float(columns[c])
            ax = fig.add_axes(box(x, bottom, image_w, image_h))
            ax.set_axis_off()
            bar = _has_bar(panel)
            cax = fig.add_axes(box(x + image_w + BAR_PAD_IN, bottom, BAR_WIDTH_IN, image_h)) if bar else None
            _draw(fig, ax, panel, cax)
        if row_title:
            fig.text(
                left / 2 / width, (bottom + image_h / 2) / height, row_title, rotation=90, va="center", ha="center"
            )
        top = bottom - legend
    if title:
        fig.text(0.5, 1 - title_in / 2 / height, title, ha="center", va="center", fontsize=TITLE_PT)
    if caption:
        fig.text(0.5, caption_in / 2 / height, caption, ha="center", va="center", fontsize=CAPTION_PT)
    return fig


WIDEST_GLYPH_EM = 1.0
"""Advance of the widest character of matplotlib's default font (DejaVu Sans: "W", "@", "—" <= 1 em), in font
sizes: a text of n characters is at most n em wide, and one that fits so is not measured (~2-7 ms a text)."""
WRAP_SAFETY = 0.95
"""Share of the room a wrapped line may fill: :func:`wrap_text` spreads the text's measured width evenly over its
characters, and a line of wider ones may come out a little wider than that."""


def wrap_text(text: str, size_pt: float, width_in: float) -> str:
    """``text`` broken at spaces into lines that fit ``width_in`` in matplotlib's default font at ``size_pt``.

    A text that fits however wide its characters (:data:`WIDEST_GLYPH_EM`) is returned as it is; another is measured
    once by the Agg renderer, and one wider than the room is broken by :mod:`textwrap` at the characters per line
    its mean character width allows (measuring word by word cost ~0.1 s a sheet on a loaded machine).

    Parameters
    ----------
    text : one line ("" stays "")
    size_pt : font size, points
    width_in : the room, inches
    """
    import textwrap

    from matplotlib.backends.backend_agg import RendererAgg
    from matplotlib.font_manager import FontProperties

    if len(text) * WIDEST_GLYPH_EM * size_pt / 72 <= width_in:  # fits even in the widest characters
        return text
    # at 72 dpi a pixel is a point
    wide = RendererAgg(1, 1, 72).get_text_width_height_descent(text, FontProperties(size=size_pt), ismath=False)[0]
    if wide / 72 <= width_in:
        return text
    return "\n".join(textwrap.wrap(text, max(1, int(len(text) * width_in * 72 * WRAP_SAFETY / wide))))


def row_title_width(titles: Iterable[str]) -> float:
    """Width left of a sheet's first column, inches: room for the longest row title's lines (:data:`MARGIN_IN`
    without titles)."""
    lines = max((len(t.splitlines()) for t in titles if t), default=0)
    return lines * ROW_TITLE_LINE_IN + ROW_TITLE_PAD_IN if lines else MARGIN_IN


def _has_bar(panel: Panel) -> bool:
    """Whether ``panel`` is drawn with a colour bar: a scalar map, not an RGB image nor a categorical one."""
    return panel.image.ndim == 2 and not panel.legend


def _draw(fig: Figure, ax: Axes, panel: Panel, cax: Axes | None = None) -> None:
    """Draw ``panel`` into ``ax``; a scalar panel's colour bar into ``cax`` (None: room taken from ``ax``)."""
    ax.set_title(panel.title, fontsize=9)
    if panel.image.ndim == 3:
        ax.imshow(panel.image)
        return
    import matplotlib

    # pixels without a value (NaN) in light grey, not the colour of zero
    cmap = matplotlib.colormaps[panel.cmap].with_extremes(bad=str(NO_VALUE_GREY))
    if panel.legend:
        _draw_categories(ax, panel, cmap)
        return
    im = ax.imshow(panel.image, cmap=cmap, vmin=panel.vmin, vmax=panel.vmax)
    room = {"cax": cax} if cax is not None else {"ax": ax, "fraction": 0.046, "pad": 0.03}
    bar = fig.colorbar(im, extend=_extend(panel), **room)
    bar.ax.tick_params(labelsize=7)
    if panel.label:
        bar.set_label(panel.label, fontsize=8)


def _draw_categories(ax: Axes, panel: Panel, cmap: Colormap) -> None:
    """A categorical panel: value i in the colour of i on a 0..n-1 scale (fixed, so a mask with no contact
    pixel is not drawn in the contact colour), named in a legend under the image."""
    from matplotlib.patches import Patch

    top = max(len(panel.legend) - 1, 1)
    ax.imshow(panel.image, cmap=cmap, vmin=0, vmax=top)
    keys = [Patch(facecolor=cmap(i / top), edgecolor="0.4", label=name) for i, name in enumerate(panel.legend)]
    ax.legend(handles=keys, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=len(keys), fontsize=7, frameon=False)


def _extend(panel: Panel) -> str:
    """The colour bar's arrows ("neither", "min", "max" or "both"): an arrow at each end beyond which a scalar panel
    has values (a percentile range, or a fixed one): they show in that end's colour, so 25 deg does not read as 10
    (the OpenCV maps write "10+"), nor an indentation of -0.2 mm (a result behind the undeformed surface) as 0
    (the OpenCV maps write "<=0")."""
    values = panel.image[np.isfinite(panel.image)]
    over = panel.vmax is not None and bool(np.any(values > panel.vmax))
    under = panel.vmin is not None and bool(np.any(values < panel.vmin))
    return {(False, False): "neither", (False, True): "max", (True, False): "min", (True, True): "both"}[(under, over)]
