from pathlib import Path

import numpy as np
import pytest

from nlipscalib.report import Panel, contact_sheet, normals_to_rgb
from nlipscalib.report.figures import NO_VALUE_GREY


def test_normal_map_colours_known_answers():
    n = np.array([[[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]])  # toward camera, right, up
    rgb = normals_to_rgb(n, mask=np.array([[True, True, False]]))
    np.testing.assert_allclose(rgb[0, 0], [0.5, 0.5, 1.0])  # facing the camera: blue
    np.testing.assert_allclose(rgb[0, 1], [1.0, 0.5, 0.5])  # facing right: red
    np.testing.assert_allclose(rgb[0, 2], [NO_VALUE_GREY] * 3)  # masked out: the grey of every "no value"
    assert (normals_to_rgb(np.full((1, 1, 3), np.nan)) == NO_VALUE_GREY).all()  # NaN too, not mid grey


def test_off_gel_pixels_are_one_grey_in_the_normal_and_error_panels_of_a_sheet(tmp_path):
    """q3's error-map sheets drew off-gel pixels black in the normal panels and grey in the error panel beside
    them (and black is a small error in the error colour map): every panel now draws them NO_VALUE_GREY."""
    import cv2

    from nlipscalib.report.experiments import error_maps
    from nlipscalib.report.maps import NO_VALUE_BGR

    h, w = 40, 40
    normals = np.zeros((h, w, 3))
    normals[..., 2] = -1.0
    error = np.full((h, w), 3.0)
    error[:, : w // 2] = np.nan  # the left half off the gel
    path = error_maps([("press", normals, normals, error)], tmp_path / "maps.png")
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    grey = np.all(np.abs(img.astype(int) - NO_VALUE_BGR) <= 1, axis=-1)  # matplotlib rounds 0.85 * 255 down
    black = np.all(img == 0, axis=-1)
    # the three panels' left halves: grey, each a sizeable patch; and no black patch where they are
    columns = np.flatnonzero(grey.sum(axis=0) > 20)
    assert len(columns) > 3 * 20 and np.ptp(columns) > img.shape[1] // 2, len(columns)
    assert black[:, columns].sum() < 0.01 * grey[:, columns].sum()


def test_contact_sheet_writes_a_png(tmp_path):
    img = np.random.default_rng(0).random((8, 10))
    path = contact_sheet(
        [("row", [Panel("scalar", img, label="mm"), Panel("rgb", np.zeros((8, 10, 3)))])], tmp_path / "s.png"
    )
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("shape", [(332, 336), (480, 640), (40, 120)])
def test_contact_sheet_panels_are_drawn_at_one_size_with_tight_gaps(shape):
    """The solve summary's normals panel (no colour bar) was drawn larger than its neighbours, and a square
    region of interest left wide gaps between panels (fixed 3.2 x 2.7 in cells): every image of a sheet is now
    drawn at one size, whatever its panel holds, and the gaps between them are the colour bars' room only."""
    from nlipscalib.report.figures import BAR_ROOM_IN, PANEL_WIDTH_IN, sheet_figure

    rng = np.random.default_rng(0)
    values = rng.random(shape)
    panels = [
        Panel("normals", rng.random(shape + (3,))),
        Panel("depth", values, label="indentation, mm"),
        Panel("mask", (values > 0.5).astype(float), "gray", legend=("no", "yes")),
        Panel("angular error\nAAE 0.45 deg, contact 0.42 deg", values * 2, "inferno", "deg", 0.0, 1.0),
    ]
    fig = sheet_figure([("press", panels), ("other", panels[:2])], caption="key", title="title")
    fig.canvas.draw()
    boxes = [ax.get_window_extent() for ax in fig.axes if ax.images and ax.get_label() != "<colorbar>"]
    assert len(boxes) == 6
    sizes = {(round(b.width), round(b.height)) for b in boxes}
    assert len(sizes) == 1, sizes  # one size for all, normal maps and masks as scalar maps
    ((width, height),) = sizes
    assert abs(width / height - shape[1] / shape[0]) < 0.02  # the image fills its axes: no gap inside them
    gaps = [b.x0 - a.x1 for a, b in zip(boxes[:3], boxes[1:4])]
    assert max(gaps) < (BAR_ROOM_IN + 0.5) * fig.dpi, gaps  # a colour bar's room, not a field of white
    assert width > 0.7 * PANEL_WIDTH_IN * fig.dpi


def test_scalar_map_colours_range_and_missing_values(tmp_path):
    import cv2

    from nlipscalib.report.maps import BAR_WIDTH, NO_VALUE_BGR, bar_min_height, scalar_map_png

    values = np.array([[0.0, 10.0, np.nan], [5.0, 20.0, -3.0]])
    img = cv2.imread(str(scalar_map_png(tmp_path / "m.png", values, "gray", "deg", 0, 10)), cv2.IMREAD_COLOR)
    # the image grid kept from the top-left corner, the colour bar beside it, white rows below for its text
    assert img.shape == (bar_min_height("deg"), 3 + BAR_WIDTH, 3) and np.all(img[2:, :3] == 255)
    assert tuple(img[0, 0]) == (0, 0, 0) and tuple(img[0, 1]) == (255, 255, 255)  # vmin black, vmax white
    assert tuple(img[1, 0]) in ((128, 128, 128), (127, 127, 127))  # half way
    assert tuple(img[1, 1]) == (255, 255, 255) and tuple(img[1, 2]) == (0, 0, 0)  # clipped to the range
    assert tuple(img[0, 2]) == NO_VALUE_BGR  # NaN: grey, not the colour of zero


def test_normal_map_png_matches_normals_to_rgb(tmp_path):
    import cv2

    from nlipscalib.report.maps import normal_map_png

    n = np.array([[[0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]])
    img = cv2.imread(str(normal_map_png(tmp_path / "n.png", n)), cv2.IMREAD_COLOR)[..., ::-1]
    np.testing.assert_array_equal(img, np.round(normals_to_rgb(n) * 255))


def test_figure_maps_are_written_losslessly_with_the_captures_fast_png_settings(tmp_path):
    """A solve's maps (noisy residual and error maps among them) were deflated at level 1 with libpng choosing a
    filter per row: ~2.5x the encoding CPU of the captures' fixed SUB filter and run-length deflate at about the same
    size (cube1's auto ROI: 25 -> 10 ms per solve, benchmarks/RESULTS.md, s37-cubefast)."""
    import cv2

    from nlipscalib.report.maps import normal_map_png, scalar_map_png
    from tests.core.test_imageio import _png_row_filters

    rng = np.random.default_rng(0)
    values = rng.normal(0.0, 1.0, (40, 50))
    values[:5] = np.nan
    normals = np.dstack([rng.normal(0, 0.2, (40, 50)), rng.normal(0, 0.2, (40, 50)), -np.ones((40, 50))])
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    for path in (
        scalar_map_png(tmp_path / "r.png", values, "magma", "a.u."),
        normal_map_png(tmp_path / "n.png", normals),
    ):
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if hasattr(cv2, "IMWRITE_PNG_FILTER"):
            assert _png_row_filters(path.read_bytes(), img.shape[1] * 3) == {1}  # PNG filter type 1: SUB
    # lossless: the normal map's pixels are its colours exactly
    img = cv2.imread(str(tmp_path / "n.png"), cv2.IMREAD_COLOR)[..., ::-1]
    np.testing.assert_array_equal(img, np.round(normals_to_rgb(normals) * 255))


def _png(rgb: np.ndarray) -> bytes:
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="PNG")
    return buf.getvalue()


def test_report_png_palette_only_where_it_is_faithful():
    import io

    from PIL import Image

    from nlipscalib.report.experiments import PALETTE_MAX_ERROR, _palette_png

    # a smooth normal map has far more than 256 colours: a palette would posterise it into patches
    y, x = np.mgrid[0:200, 0:200] / 199.0
    smooth = (np.stack([x, y, 1 - 0.5 * (x + y)], -1) * 255).astype(np.uint8)
    kept = Image.open(io.BytesIO(_palette_png(_png(smooth))))
    assert kept.mode == "RGB"
    assert np.abs(np.asarray(kept, np.int16) - smooth).max() == 0
    # a chart of a few flat colours becomes a palette PNG with the same pixels
    chart = np.full((60, 80, 3), 255, np.uint8)
    chart[10:50, 10:30] = (31, 119, 180)
    chart[20:50, 40:60] = (255, 127, 14)
    small = Image.open(io.BytesIO(_palette_png(_png(chart))))
    assert small.mode == "P"
    assert np.abs(np.asarray(small.convert("RGB"), np.int16) - chart).max() <= PALETTE_MAX_ERROR


def test_error_colour_bar_fits_the_errors_shown():
    from nlipscalib.report.experiments import error_scale

    rng = np.random.default_rng(1)
    assert error_scale([rng.uniform(0, 0.9, (20, 20)), np.full((3, 3), np.nan)]) == 1.0
    assert error_scale([rng.uniform(0, 1.6, (50, 50))]) == 2.0  # sub-degree maps no longer look black
    assert error_scale([rng.uniform(0, 14.0, (50, 50))]) == 20.0
    assert error_scale([np.full((4, 4), 90.0)]) == 45.0 and error_scale([np.full((2, 2), np.nan)]) == 1.0


def test_an_experiment_chart_legend_covers_no_bar(tmp_path, monkeypatch):
    """Five methods on two test splits, as the quick Q2 report draws them: the legend hid the tallest bars."""
    from nlipscalib.report import experiments

    drawn = {}
    save = experiments._save

    def keep(fig, path):
        fig.canvas.draw()
        ax = fig.axes[0]
        legend = ax.get_legend().get_window_extent()
        drawn["overlaps"] = [p for p in ax.patches if p.get_window_extent().overlaps(legend)]
        return save(fig, path)

    monkeypatch.setattr(experiments, "_save", keep)
    heights = {"net": [2.4, 4.8], "upper": [2.5, 4.8], "lut": [7.4, 8.8], "none": [11.2, 10.5], "nlips": [1.0, 2.2]}
    series = {label: (h, [0.0, 0.0]) for label, h in heights.items()}
    path = experiments.grouped_bars(["seen", "unseen"], series, "AAE (deg)", tmp_path / "bars.png", {"paper": 3.3})
    assert path.is_file() and drawn["overlaps"] == []


def _reconstruction(h=6, w=8, depth=15.0, method="nlips"):
    from nlipscalib.core.reconstruction import Reconstruction

    normals = np.zeros((h, w, 3), np.float32)
    normals[..., 2] = -1.0
    return Reconstruction(
        depth=np.full((h, w), depth, np.float32),
        points=np.zeros((h, w, 3), np.float32),
        normals=normals,
        albedo=np.ones((h, w, 3), np.float32),
        residual=np.full((h, w), 0.001, np.float32),
        confidence=np.ones((h, w), np.float32),
        usable_leds=np.full((h, w), 12, np.int16),
        mask=np.ones((h, w), bool),
        reconstructed=np.ones((h, w), bool),
        report={"method": method},
    )


def _down_tilt_coverage(cells=1):
    """A coverage dict whose only filled bins hold tilts toward the image's bottom (+v, camera +y)."""
    from nlipscalib.learn.coverage import AZIMUTH_SECTORS, TILT_EDGES_DEG, direction_bins

    ref = np.tile([[0.0, 0.0, -1.0]], (4, 1))  # the undeformed normal faces the camera
    tilt = np.radians([5.0, 15.0, 30.0, 50.0])  # one sample in each ring
    d = np.array([0.3, 1.0]) / np.hypot(0.3, 1.0)  # toward the image's bottom, a little to its right
    tilted = np.stack([np.sin(tilt) * d[0], np.sin(tilt) * d[1], -np.cos(tilt)], axis=1)
    counts = np.zeros((cells, cells, (len(TILT_EDGES_DEG) - 1) * AZIMUTH_SECTORS), int)
    counts[..., direction_bins(tilted, ref)] = 100
    return {
        "cells": cells,
        "min_samples": 20,
        "tilt_edges_deg": list(TILT_EDGES_DEG),
        "azimuth_sectors": AZIMUTH_SECTORS,
        "counts": counts,
        "gel": np.ones((cells, cells), bool),
        "covered_fraction": 0.1,
        "next_press": {"region": [0, 0], "indenter": "sphere", "centre_uv": [10, 10]},
    }


def test_coverage_plots_are_oriented_like_the_image(tmp_path, monkeypatch):
    """A tilt toward the image's bottom is drawn below the plot's centre (matplotlib's default polar axes,
    counter-clockwise with y up, drew it at the top)."""
    from nlipscalib.report import learn

    drawn = {}
    save = learn._save

    def keep(fig, path):
        fig.canvas.draw()
        ax = fig.axes[0]
        rgba = np.asarray(fig.canvas.buffer_rgba())
        box = ax.get_window_extent()
        top = rgba.shape[0] - int(box.y1)  # display y counts from the bottom, image rows from the top
        crop = rgba[top : top + int(box.height), int(box.x0) : int(box.x1), :3].astype(int)
        drawn["filled"] = np.argwhere((crop[..., 0] > 200) & (crop[..., 1] > 200) & (crop[..., 2] < 100))  # yellow
        drawn["centre"] = np.array(crop.shape[:2]) / 2
        return save(fig, path)

    monkeypatch.setattr(learn, "_save", keep)
    learn.coverage_figure(_down_tilt_coverage(), tmp_path / "coverage.png")
    row, col = drawn["filled"].mean(axis=0) - drawn["centre"]
    assert len(drawn["filled"]) > 100
    assert row > 0.15 * drawn["centre"][0]  # below the centre: toward the image's bottom
    assert col > 0  # and a little to its right, as the tilt


def test_depth_figures_show_the_indentation_when_the_undeformed_surface_is_known():
    from nlipscalib.report.reconstruction import depth_view

    rec = _reconstruction(depth=15.0)
    depth = rec.depth.copy()
    depth[2:4, 3:5] -= 0.8  # pressed 0.8 mm in, toward the camera
    rec = dataclasses_replace(rec, depth=depth)
    reference = np.full(depth.shape, 15.0)
    box = (slice(None), slice(None))
    values, label, vmin = depth_view(rec, reference, box)
    assert label == "indentation, mm" and vmin == 0.0
    np.testing.assert_allclose(values[2, 3], 0.8, atol=1e-5) and np.testing.assert_allclose(values[0, 0], 0.0)
    values, label, vmin = depth_view(rec, None, box)  # no undeformed surface: camera z, said so
    assert label == "camera z, mm" and vmin is None and values[0, 0] == 15.0


def dataclasses_replace(obj, **changes):
    import dataclasses

    return dataclasses.replace(obj, **changes)


def test_summary_names_press_and_method_and_error_maps_share_one_colour_map(tmp_path, monkeypatch):
    from nlipscalib.core.capture import GroundTruth
    from nlipscalib.report import figures, write_reconstruction_figures

    sheets = {}
    monkeypatch.setattr(figures, "contact_sheet", lambda rows, path, **kw: sheets.update(rows=rows, **kw) or path)
    rec = _reconstruction(method="nlipsnet")
    gt = GroundTruth(rec.depth, rec.points, rec.normals, rec.reconstructed, rec.reconstructed)
    write_reconstruction_figures(tmp_path, rec, gt, "full", reference_depth=rec.depth + 0.1, name="press_0002")
    assert sheets["title"] == "press_0002, NLiPsNet"
    assert sheets["caption"] == figures.NORMALS_KEY  # the normal colours explained
    panels = sheets["rows"][0][1]
    assert panels[1].label == "indentation, mm" and panels[2].label == "linear intensity"
    assert panels[3].cmap == figures.ERROR_CMAP


def test_a_truth_read_at_first_use_draws_the_same_error_map(tmp_path):
    """``nlips solve`` passes its press's truth as ``lambda: press.ground_truth`` (read on the figures' pool beside
    the other maps): the same files and error.png as the truth itself; a press without one writes no error.png."""
    from nlipscalib.core.capture import GroundTruth
    from nlipscalib.report import write_reconstruction_figures

    rec = _reconstruction()
    tilted = rec.normals.copy()
    tilted[:3] = [0.0, np.sin(0.1), -np.cos(0.1)]
    gt = GroundTruth(rec.depth, rec.points, tilted, rec.reconstructed, rec.reconstructed)
    given = write_reconstruction_figures(tmp_path / "given", rec, gt)
    read = write_reconstruction_figures(tmp_path / "read", rec, lambda: gt)
    assert (
        [p.name for p in given] == [p.name for p in read] == ["normals.png", "depth.png", "residual.png", "error.png"]
    )
    for a, b in zip(given, read):
        assert a.read_bytes() == b.read_bytes()
    none = write_reconstruction_figures(tmp_path / "none", rec, lambda: None)
    assert [p.name for p in none] == ["normals.png", "depth.png", "residual.png"]
    assert not (tmp_path / "none" / "error.png").exists()


def _text_columns(strip: np.ndarray) -> np.ndarray:
    """Columns of a colour-bar strip (BGR) that hold dark text pixels, right of the gradient."""
    from nlipscalib.report.maps import RAMP_COLS

    dark = (strip.max(axis=-1) < 120)[:, RAMP_COLS[1] :]
    return np.nonzero(dark.any(axis=0))[0] + RAMP_COLS[1]


def test_colour_bar_text_fits_on_short_and_tall_maps(tmp_path):
    import cv2

    from nlipscalib.report.maps import BAR_WIDTH, bar_min_height, scalar_map_png

    rng = np.random.default_rng(2)
    # a 40-px error map (a small ROI): the bar had no numbers and no unit
    short = rng.uniform(0, 14, (40, 30))
    img = cv2.imread(str(scalar_map_png(tmp_path / "e.png", short, "inferno", "deg", 0, 10)), cv2.IMREAD_COLOR)
    assert img.shape[0] == bar_min_height("deg") >= 40  # white rows under the map, the map's grid kept
    assert np.all(img[40:, :30] == 255)
    strip = img[:, 30:]
    assert len(_text_columns(strip[:30])) > 10  # the range beside the gradient ("10+", "0")
    assert (strip[-12:].max(axis=-1) < 120).any()  # the unit under it
    # a 480-px residual map with 7-character numbers: they ran past the strip's right edge
    tall = rng.uniform(0.00204, 0.00596, (480, 40))
    img = cv2.imread(str(scalar_map_png(tmp_path / "r.png", tall, "magma", "linear intensity")), cv2.IMREAD_COLOR)
    columns = _text_columns(img[:, 40:])
    assert len(columns) > 10 and columns.max() < BAR_WIDTH - 1


def test_colour_bar_numbers_are_compact():
    from nlipscalib.report.maps import _fmt

    assert _fmt(1.234e-5) == "1.23e-5" and _fmt(0.00596) == "0.00596" and _fmt(17.94) == "17.9" and _fmt(10) == "10"


def test_saturated_error_colours_are_marked(tmp_path):
    import cv2

    from nlipscalib.report.figures import Panel, _extend
    from nlipscalib.report.maps import scalar_map_png

    err = np.array([[1.0, 25.0], [np.nan, 3.0]])
    assert _extend(Panel("e", err, vmin=0, vmax=10)) == "max" and _extend(Panel("e", err, vmin=0, vmax=30)) == "neither"
    assert _extend(Panel("e", err)) == "neither"  # the data's own range saturates nothing
    size = (60, 60)
    over = cv2.imread(str(scalar_map_png(tmp_path / "o.png", np.resize(err, size), "inferno", "deg", 0, 10)))
    within = cv2.imread(str(scalar_map_png(tmp_path / "w.png", np.resize(err, size), "inferno", "deg", 0, 30)))
    assert _text_columns(over[:14, 60:]).max() > _text_columns(within[:14, 60:]).max()  # "10+" is wider than "30"


def test_bar_chart_marks_missing_values_and_draws_no_unmeasured_error_bars(tmp_path, monkeypatch):
    from nlipscalib.report import experiments

    drawn = {}
    save = experiments._save

    def keep(fig, path):
        ax = fig.axes[0]
        drawn["texts"] = [(t.get_text().strip(), t.get_position()[0]) for t in ax.texts]
        drawn["error_bars"] = [c for c in ax.containers if c.__class__.__name__ == "ErrorbarContainer"]
        return save(fig, path)

    monkeypatch.setattr(experiments, "_save", keep)
    series = {"lut": ([np.nan, 7.0], [0.0, 0.0]), "nlips": ([1.0, np.nan], [0.0, 0.0])}
    experiments.grouped_bars(["seen", "unseen"], series, "AAE (deg)", tmp_path / "bars.png")
    assert [text for text, _ in drawn["texts"]] == ["n/a", "n/a"]
    assert drawn["texts"][0][1] < 0.5 < drawn["texts"][1][1]  # the "seen" slot of lut, the "unseen" of nlips
    assert drawn["error_bars"] == []  # no spread measured: no +-0 caps


def test_error_map_sheets_are_readable_and_small(tmp_path):
    from PIL import Image

    from nlipscalib.report.experiments import error_maps
    from nlipscalib.report.figures import PANEL_WIDTH_IN

    rng = np.random.default_rng(3)
    n = np.zeros((48, 64, 3))
    n[..., 2] = -1.0
    rows = [(f"press {i}", n, n, rng.uniform(0, 4, (48, 64))) for i in range(2)]
    path = error_maps(rows, tmp_path / "maps.png")
    # 3 images of PANEL_WIDTH_IN at >= 100 dpi (60 dpi: 576 px in all, unreadable ticks)
    assert Image.open(path).size[0] >= 3 * PANEL_WIDTH_IN * 100
    assert path.stat().st_size < 150_000


def test_demo_sheet_error_panel_fits_small_errors_and_prints_the_aae():
    from nlipscalib.cli.demo import _error_panel
    from nlipscalib.report.figures import ERROR_CMAP

    err = np.random.default_rng(4).uniform(0, 1.2, (8, 8))
    err[0, 0] = np.nan  # not scored
    contact = np.zeros((8, 8), bool)
    contact[4:] = True
    panel = _error_panel(err, contact)
    assert panel.vmax == 2.0 and panel.cmap == ERROR_CMAP  # not a fixed 10: half-degree errors are not black
    # the table's AAE roi and AAE contact, worded as the solve's summary words them
    assert panel.title == f"angular error\nAAE {np.nanmean(err):.2f} deg, contact {err[4:].mean():.2f} deg"


def test_demo_sheet_contact_mask_is_named_in_a_legend_not_a_colour_bar():
    """A binary mask drawn with a continuous 0-1 colour bar (figure audit, defect 11): two named colours instead."""
    from types import SimpleNamespace

    from matplotlib.figure import Figure

    from nlipscalib.cli.demo import _panels
    from nlipscalib.report.figures import _draw

    contact = np.zeros((6, 8), bool)
    contact[2:4, 3:5] = True
    normals = np.zeros((6, 8, 3))
    normals[..., 2] = -1.0
    gt = SimpleNamespace(normals=normals, valid=np.ones((6, 8), bool), contact=contact)
    img = np.ones((6, 8, 3))
    press = SimpleNamespace(ground_truth=gt, tricolor=img, led_images=[img], linear=lambda x: x)
    mask = _panels(press, None)[3]
    fig = Figure()
    ax = fig.subplots()
    _draw(fig, ax, mask)
    assert [a for a in fig.axes if a.get_visible()] == [ax]  # no colour bar (its room only: see the layout test)
    keys = ax.get_legend()
    assert [t.get_text() for t in keys.get_texts()] == ["no contact", "contact"]
    colours = [tuple(h.get_facecolor()[:3]) for h in keys.legend_handles]
    assert colours == [(0.0, 0.0, 0.0), (1.0, 1.0, 1.0)]  # the mask's own colours: black = no contact


def test_nlipsnet_sheet_shows_the_object_as_the_demo_does(tmp_path, monkeypatch):
    """The tri-colour image in the display gamma of the demo sheet, not linearly scaled (figure audit, defect 11)."""
    from nlipscalib.report import display_image, experiments

    sheets = []
    draw = experiments.contact_sheet
    monkeypatch.setattr(
        experiments, "contact_sheet", lambda rows, path, **kw: sheets.append(rows) or draw(rows, path, **kw)
    )
    rng = np.random.default_rng(5)
    n = np.zeros((6, 8, 3))
    n[..., 2] = -1.0
    rgb = rng.uniform(0, 0.3, (6, 8, 3))
    experiments.nlipsnet_maps(
        [("press", {"rgb": rgb, "true": n, "estimate": n, "error": np.ones((6, 8))})], tmp_path / "m.png"
    )
    np.testing.assert_allclose(sheets[0][0][1][0].image, display_image(rgb))


def _drawn_sheets(monkeypatch) -> list:
    """The map sheets the reporting module draws, kept as figures instead of being saved (appended as drawn)."""
    from nlipscalib.report import experiments, figures

    sheets = []
    monkeypatch.setattr(figures, "save_png", lambda fig, path, dpi: sheets.append(fig) or Path(path))
    monkeypatch.setattr(experiments, "write_bytes", lambda path, data: Path(path))
    monkeypatch.setattr(experiments.Path, "read_bytes", lambda self: b"")
    monkeypatch.setattr(experiments, "_palette_png", lambda png: png)
    return sheets


def _flat_normals(h: int = 6, w: int = 8) -> np.ndarray:
    """(h, w, 3) normals all facing the camera (-z)."""
    n = np.zeros((h, w, 3))
    n[..., 2] = -1.0
    return n


def test_nlipsnet_sheet_titles_each_press_with_its_contact_aae(tmp_path, monkeypatch):
    """Q2's sheet showed each press without its score: the predicted normals' title says its contact AAE against the
    NLiPs labels, the error's against the truth, as the report's tables give them (read back from the drawn axes)."""
    from nlipscalib.report import experiments

    sheets = _drawn_sheets(monkeypatch)
    n = _flat_normals()
    view = {"rgb": n, "true": n, "estimate": n, "error": np.full((6, 8), 0.4)}
    scores = [
        {"aae_vs_nlips_deg": 0.803, "aae_vs_true_deg": 0.754},
        {"aae_vs_nlips_deg": 12.345, "aae_vs_true_deg": float("nan")},  # no contact with a true normal
    ]
    experiments.nlipsnet_maps([("seen: sphere", view), ("unseen: coin", view)], tmp_path / "n.png", scores=scores)
    experiments.nlipsnet_maps([("seen: sphere", view)], tmp_path / "m.png")  # no scores given: none printed
    titles = [[ax.get_title() for ax in fig.axes if ax.get_title()] for fig in sheets]
    row = ["object (tri-colour image)", "ground-truth normals"]
    assert titles[0] == [
        *row,
        "NLiPsNet normals\ncontact AAE vs labels 0.80 deg",
        "angular error vs truth\ncontact AAE 0.75 deg",
        *row,
        "NLiPsNet normals\ncontact AAE vs labels 12.35 deg",
        "angular error vs truth",
    ]
    assert titles[1] == [*row, "NLiPsNet normals", "angular error vs truth"]
    with pytest.raises(ValueError, match="1 scores for 2 rows"):
        experiments.nlipsnet_maps([("a", view), ("b", view)], tmp_path / "x.png", scores=scores[:1])


def test_live_depth_colours_black_off_the_gel():
    from nlipscalib.report.live import depth_to_rgb

    depth = np.array([[np.nan, 10.0], [9.5, 8.0]], np.float32)
    rgb = depth_to_rgb(depth, reference=np.full((2, 2), 10.0))
    assert rgb.shape == (2, 2, 3) and rgb[0, 0].sum() == 0 and rgb[1, 1].sum() > 0


def test_live_depth_colours_are_the_scalar_maps_colours():
    """The live window's depth had a colour mapping of its own (cv2 viridis on truncated levels) beside the scalar
    maps' (rounded levels): one colour mapping now, report.maps.colour_scalars, black off the gel."""
    from nlipscalib.report.live import depth_to_rgb
    from nlipscalib.report.maps import colour_scalars

    reference = np.full((2, 3), 10.0)
    depth = reference - np.array([[np.nan, 0.25, 0.5], [1.0, 2.5, -1.0]])  # levels 31.9 and 63.75: rounded up
    expected = colour_scalars(reference - depth, 0.0, 2.0, "viridis", no_value=(0, 0, 0))[..., ::-1]
    np.testing.assert_array_equal(depth_to_rgb(depth, reference, span_mm=2.0), expected)
    expected = colour_scalars(depth, 7.5, 11.0, "viridis", no_value=(0, 0, 0))[..., ::-1]  # its own range
    np.testing.assert_array_equal(depth_to_rgb(depth), expected)


def test_live_depth_shows_a_press_toward_the_camera():
    # inside the dome a press moves the gel toward the camera (depth below the reference): it was clipped to 0
    from nlipscalib.report.live import depth_to_rgb

    reference = np.full((1, 3), 15.0)
    rgb = depth_to_rgb(reference - np.array([[0.0, 1.0, 2.0]]), reference, span_mm=2.0)
    assert len({tuple(c) for c in rgb[0]}) == 3  # three indentations, three colours


def test_live_window_shows_normals_beside_depth_and_q_ends_the_stream(monkeypatch):
    import cv2

    from nlipscalib.device.live import LiveResult, StopLive
    from nlipscalib.report.live import WindowSink, depth_to_rgb
    from nlipscalib.report.maps import BAR_WIDTH

    shown, keys = [], [-1, ord("q")]
    monkeypatch.setattr(cv2, "imshow", lambda name, bgr: shown.append(bgr))
    monkeypatch.setattr(cv2, "waitKey", lambda ms: keys.pop(0))
    normals = np.zeros((4, 5, 3), np.float32)
    normals[..., 2] = -1.0  # facing the camera
    result = LiveResult(normals, np.full((4, 5), 9.5, np.float32))
    sink = WindowSink(StopLive, reference_depth=np.full((4, 5), 10.0))
    sink(0, None, result)
    assert shown[0].shape == (4, 10 + BAR_WIDTH, 3)  # normals, depth and the depth's colour bar
    assert tuple(shown[0][0, 0]) == (255, 127, 127)  # BGR of the camera-facing blue, as the saved normal maps
    np.testing.assert_array_equal(shown[0][:, 5:10, ::-1], depth_to_rgb(result.depth, np.full((4, 5), 10.0)))
    with pytest.raises(StopLive):
        sink(1, None, result)


def test_live_depth_colour_bar_names_the_unit_and_marks_the_ends_beyond_its_range(monkeypatch):
    """The live window showed depth colours without a scale: the maps' colour bar now stands at its right."""
    from nlipscalib.report import live
    from nlipscalib.report.maps import BAR_WIDTH

    drawn = []
    bar = live.colour_bar
    monkeypatch.setattr(live, "colour_bar", lambda *a: drawn.append(a) or bar(*a))
    reference = np.full((60, 4), 10.0)
    rgb, strip = live.depth_bar_rgb(reference - np.linspace(-0.5, 3.0, 240).reshape(60, 4), reference, span_mm=2.0)
    assert rgb.shape == (60, 4, 3) and strip.shape == (60, BAR_WIDTH, 3) and strip.dtype == np.uint8
    assert drawn[-1][1:] == ("viridis", 0.0, 2.0, "indentation, mm", True, True)  # "2+" and "<=0"
    live.depth_bar_rgb(reference - 1.0, reference)
    assert drawn[-1][-2:] == (False, False)
    live.depth_bar_rgb(np.linspace(8.0, 9.0, 240).reshape(60, 4))  # no reference: its own range, nothing beyond
    assert drawn[-1][1:] == ("viridis", 8.0, 9.0, "camera z, mm", False, False)


def test_training_curve_ticks_whole_epochs(tmp_path, monkeypatch):
    import matplotlib.figure

    from nlipscalib.report.learn import training_curve

    ticks = []
    save = matplotlib.figure.Figure.savefig

    def savefig(fig, *args, **kwargs):
        ticks.extend(t for ax in fig.axes for t in ax.get_xticks() if ax.get_xlim()[0] <= t <= ax.get_xlim()[1])
        return save(fig, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", savefig)
    history = [
        {"epoch": e, "train_loss": 1.0 / (e + 1), "val_aae_deg": 2.0 - 0.05 * e, "val_contact_aae_deg": 2.1 - 0.05 * e}
        for e in range(18)
    ]
    training_curve(history, tmp_path / "curve.png")
    assert ticks and all(float(t).is_integer() for t in ticks)


def test_the_colour_bar_marks_clipped_values_only_on_a_fixed_scale(tmp_path, monkeypatch):
    # the default range is the 1st-99th percentile: 1 % lies above it by definition, so "+" would be on every bar
    from nlipscalib.report import maps

    marked = []
    bar = maps.colour_bar
    monkeypatch.setattr(maps, "colour_bar", lambda *a, **k: marked.append(a[-1]) or bar(*a, **k))
    values = np.linspace(0.0, 20.0, 64 * 64).reshape(64, 64)
    maps.scalar_map_png(tmp_path / "auto.png", values, "inferno", "deg")
    maps.scalar_map_png(tmp_path / "fixed.png", values, "inferno", "deg", vmin=0.0, vmax=10.0)
    assert marked == [False, True]


def test_a_sweeps_highest_point_is_drawn_whole_below_the_frame(tmp_path, monkeypatch):
    """Points that barely differ (the quick noise study: 1.13 and 1.11 deg) had the y axis end at the highest one,
    its marker cut in half by the frame (the axis started at 0 with matplotlib's top of a 5 % data-range margin)."""
    from nlipscalib.report import experiments

    limits = {}
    save = experiments._save

    def keep(fig, path):
        limits["y"] = fig.axes[0].get_ylim()
        return save(fig, path)

    monkeypatch.setattr(experiments, "_save", keep)
    experiments.sweep({"AAE": ([0.0, 1.0], [1.13, 1.11], [0.0, 0.0])}, "noise", "AAE (deg)", tmp_path / "s.png")
    assert limits["y"][0] == 0 and limits["y"][1] >= 1.13 * 1.05
    experiments.sweep({"AAE": ([0.0, 1.0], [1.0, 2.0], [0.0, 0.5])}, "x", "AAE (deg)", tmp_path / "e.png")
    assert limits["y"][0] == 0 and limits["y"][1] >= 2.5 * 1.05  # the error bar's top too


def test_values_below_a_fixed_bottom_are_marked(tmp_path):
    """The reference press's indentation is -0.01 to -0.24 mm everywhere (the solve behind the undeformed surface):
    on a 0-based scale it drew as a uniform "0" with nothing saying so. The matplotlib bar now gets an arrow at
    its bottom, the OpenCV bar's bottom number reads "<=0"."""
    import cv2

    from nlipscalib.report.figures import Panel, _extend
    from nlipscalib.report.maps import scalar_map_png

    dent = np.array([[-0.2, 1.5], [np.nan, 0.5]])
    assert _extend(Panel("d", dent, vmin=0.0, vmax=1.0)) == "both"
    assert _extend(Panel("d", dent, vmin=-0.5, vmax=1.0)) == "max"
    assert _extend(Panel("d", dent, vmin=0.0, vmax=2.0)) == "min"
    size = (60, 60)
    under = cv2.imread(str(scalar_map_png(tmp_path / "u.png", np.resize(dent, size), label="mm", vmin=0.0)))
    within = cv2.imread(str(scalar_map_png(tmp_path / "w.png", np.resize(np.abs(dent), size), label="mm", vmin=0.0)))
    rows = slice(28, 46)  # the bottom number's line (baseline at 43 on a 60-row map), above the unit's line
    assert _text_columns(under[rows, 60:]).max() > _text_columns(within[rows, 60:]).max()  # "<=0" is wider than "0"


def test_summary_error_panel_gives_the_contact_aae_and_fits_its_colour_range_to_the_errors(tmp_path, monkeypatch):
    """coin1's summary printed "AAE 3.40 deg" (every scored pixel of the box) while its contact AAE, the number
    `nlips eval --region contact` and every report quote, is 4.64: the title now gives both. Its colour range is
    error.png's fitted one (error_scale), not a fixed 0-10 deg that drew sphere1's half-degree errors black."""
    import cv2

    from nlipscalib.core.capture import GroundTruth
    from nlipscalib.core.metrics import aae
    from nlipscalib.report import figures, write_reconstruction_figures
    from nlipscalib.report.figures import error_scale

    sheets = {}
    monkeypatch.setattr(figures, "contact_sheet", lambda rows, path, **kw: sheets.update(rows=rows, **kw) or path)
    rec = _reconstruction()
    truth_normals = rec.normals.copy()
    tilt = np.radians(np.linspace(0.1, 0.9, rec.normals.shape[1]))  # 0.1 deg on the left to 0.9 on the right
    truth_normals[...] = np.stack([np.sin(tilt), 0 * tilt, -np.cos(tilt)], axis=-1)[None]
    contact = np.zeros(rec.mask.shape, bool)
    contact[:, -2:] = True  # the two rightmost columns: the largest errors
    gt = GroundTruth(rec.depth, rec.points, truth_normals, rec.reconstructed, contact)
    written = write_reconstruction_figures(tmp_path, rec, gt, "full")
    error = sheets["rows"][0][1][3]
    everywhere, in_contact = aae(rec.normals, truth_normals), aae(rec.normals, truth_normals, contact)
    assert error.title == f"angular error\nAAE {everywhere:.2f} deg, contact {in_contact:.2f} deg"
    assert in_contact > everywhere + 0.2  # two different numbers, each named
    assert (error.vmin, error.vmax) == (0.0, error_scale([error.image])) == (0.0, 1.0)
    png = cv2.imread(str(next(p for p in written if p.name == "error.png")))
    # errors of 0.1-0.9 deg are not drawn black on error.png either
    assert png[: rec.mask.shape[0], : rec.mask.shape[1]].max() > 100
    gt_no_contact = GroundTruth(rec.depth, rec.points, truth_normals, rec.reconstructed, np.zeros_like(contact))
    write_reconstruction_figures(tmp_path / "flat", rec, gt_no_contact, "full")
    assert sheets["rows"][0][1][3].title.endswith(", no contact")


def test_training_curve_title_gives_the_best_epochs_contact_aae_as_train_prints_it():
    from nlipscalib.report.learn import best_epoch_title

    best = {"epoch": 1, "train_loss": 0.004, "val_aae_deg": 1.7241, "val_contact_aae_deg": 1.6789}
    assert best_epoch_title(best) == "best epoch 2: 1.72 deg (contact 1.68 deg)"
    assert best_epoch_title(best | {"val_contact_aae_deg": float("nan")}).endswith("(no contact samples)")


def test_map_sheets_fit_each_rows_error_colour_range(tmp_path, monkeypatch):
    """Q2's sheet drew every row on 0-20 deg (set by a coin's edges): the sphere's half-degree errors were black.
    Each row now gets its own error_scale (its own colour bar), unless the caller fixes one."""
    from nlipscalib.report import experiments

    sheets = []
    monkeypatch.setattr(experiments, "contact_sheet", lambda rows, path, **kw: sheets.append(rows) or Path(path))
    monkeypatch.setattr(experiments, "write_bytes", lambda path, data: Path(path))
    monkeypatch.setattr(experiments.Path, "read_bytes", lambda self: b"")
    monkeypatch.setattr(experiments, "_palette_png", lambda png: png)
    n = np.zeros((6, 8, 3))
    n[..., 2] = -1.0
    small, large = np.full((6, 8), 0.4), np.full((6, 8), 30.0)
    experiments.error_maps([("sphere", n, n, small), ("coin", n, n, large)], tmp_path / "e.png")
    experiments.nlipsnet_maps(
        [(name, {"rgb": n, "true": n, "estimate": n, "error": e}) for name, e in (("sphere", small), ("coin", large))],
        tmp_path / "n.png",
    )
    experiments.error_maps([("sphere", n, n, small), ("coin", n, n, large)], tmp_path / "f.png", vmax=10.0)
    tops = [[row[1][-1].vmax for row in sheet] for sheet in sheets]
    assert tops == [[1.0, 45.0], [1.0, 45.0], [10.0, 10.0]]


def test_contact_sheet_panels_keep_the_images_orientation(tmp_path):
    """A sheet's panel shows the camera image as it is: its top-left corner at the top left (not flipped up-down, as
    matplotlib's origin="lower" would, nor transposed)."""
    from PIL import Image

    rgb = np.zeros((20, 40, 3))
    rgb[:10, :20] = [1.0, 0.0, 0.0]  # top-left quarter red, the rest black
    path = contact_sheet([("", [Panel("quarter", rgb)])], tmp_path / "o.png")
    img = np.asarray(Image.open(path).convert("RGB")).astype(int)
    red = (img[..., 0] > 200) & (img[..., 1] < 60) & (img[..., 2] < 60)
    dark = img.sum(axis=-1) < 60
    rows, cols = np.nonzero(red)
    top, left, height, width = rows.min(), cols.min(), rows.max() - rows.min() + 1, cols.max() - cols.min() + 1
    assert abs(width / height - 2.0) < 0.1  # the 20 x 10 quarter, not transposed
    # the rest of the image (black) lies below and right of the red quarter, the white page above and left of it
    assert dark[top + height + height // 2, left + width // 2] and dark[top + height // 2, left + width + width // 2]
    assert img[top - 3, left + width // 2].min() > 200 and img[top + height // 2, left - 3].min() > 200


def test_figures_leave_a_notebooks_pyplot_alone(tmp_path):
    """A Jupyter notebook's pyplot (its backend, the user's open figures) is not touched by our figures.

    Seen in a real kernel (s27-jupyter): after ``solve_folder(..., figures="full")`` or ``training_curve``, which
    called ``matplotlib.use("Agg")``, the notebook's inline backend was gone, so every later ``plt.show()`` of the
    user's showed nothing; and a figure made with ``plt.figure()`` was shown under the cell besides being saved.
    A non-interactive backend other than Agg stands in for the notebook's inline one (no kernel here)."""
    import matplotlib
    import matplotlib.pyplot as plt

    from nlipscalib.report import experiments
    from nlipscalib.report.learn import coverage_figure, training_curve

    before = matplotlib.get_backend()
    plt.switch_backend("svg")
    try:
        users = plt.figure()
        contact_sheet([("row", [Panel("scalar", np.ones((8, 10)), label="mm")])], tmp_path / "sheet.png")
        epochs = [{"epoch": e, "train_loss": 0.1, "val_aae_deg": 2.0, "val_contact_aae_deg": 2.5} for e in range(2)]
        training_curve(epochs, tmp_path / "curve.png")
        coverage_figure(_down_tilt_coverage(), tmp_path / "coverage.png")
        experiments.grouped_bars(["seen"], {"nlips": ([1.0], [0.0])}, "AAE (deg)", tmp_path / "bars.png")
        assert matplotlib.get_backend() == "svg"
        assert plt.get_fignums() == [users.number]  # the user's figure kept, none of ours left for pyplot to show
    finally:
        plt.close("all")
        plt.switch_backend(before)
    assert all((tmp_path / name).read_bytes()[:4] == b"\x89PNG" for name in ("sheet.png", "curve.png", "bars.png"))


def _smallest_text_px(fig, dpi: float) -> float:
    """The smallest text drawn on ``fig`` saved at ``dpi``, pixels tall (font size in points x dpi / 72); asserts
    that every text drawn lies inside the figure (a label running off its edge is cut in the PNG)."""
    from matplotlib.text import Text

    drawn = []
    draw = Text.draw

    def record(text, renderer):  # only what is drawn: tick labels beyond the axes' limits are made, not drawn
        if text.get_visible() and text.get_text().strip():
            drawn.append((text, text.get_window_extent(renderer)))
        return draw(text, renderer)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(Text, "draw", record)
        fig.canvas.draw()
    frame = fig.bbox.padded(1.0)  # a pixel of rounding
    outside = [
        t.get_text() for t, box in drawn if not (frame.contains(box.x0, box.y0) and frame.contains(box.x1, box.y1))
    ]
    assert outside == []
    return min(t.get_fontsize() for t, _ in drawn) * dpi / 72


def _kept_figures(monkeypatch, module) -> list:
    """The figures ``module._save(fig, path)`` is given, in order (saved as usual)."""
    kept = []
    save = module._save
    monkeypatch.setattr(module, "_save", lambda fig, path: kept.append(fig) or save(fig, path))
    return kept


def test_every_figure_text_is_readable_at_its_saved_dpi(tmp_path, monkeypatch):
    """The experiment charts were saved at 80 dpi: their 7-pt legends (the methods' names) were 7.8 px tall."""
    from nlipscalib.report import experiments, learn
    from nlipscalib.report.figures import MIN_TEXT_PX, SHEET_DPI, sheet_figure

    charts, curves = _kept_figures(monkeypatch, experiments), _kept_figures(monkeypatch, learn)
    series = {"NLiPsNet (NLiPs labels)": ([2.4, 4.8], [0.1, 0.2]), "lookup table": ([7.4, float("nan")], [0, 0])}
    experiments.grouped_bars(["seen", "unseen"], series, "AAE (°)", tmp_path / "b.png", {"paper": 3.3}, title="t")
    sweeps = {"design LEDs": ([0.0, 5.0], [0.99, 1.13], [0.0, 0.0])}
    experiments.sweep(sweeps, "LED axis error (°)", "AAE (°)", tmp_path / "s.png", title="t")
    history = [
        {"epoch": e, "train_loss": 0.1 / (e + 1), "val_aae_deg": 3.0, "val_contact_aae_deg": 3.1} for e in range(4)
    ]
    learn.training_curve(history, tmp_path / "c.png", val_presses=["sphere"])
    learn.training_curve(
        history, tmp_path / "c.png", val_presses=[f"sphere-p{i}.1-a15.2-d1.05-86cb5640ea" for i in range(3)]
    )
    for ylabel in ("AAE in the contact (°)", experiments.MABSE_LABEL):  # the labels Q1 and the ablation draw
        experiments.sweep({"twin": ([3, 12, 24], [0.0097, 0.0081, 0.0062], [0.0] * 3)}, "LEDs", ylabel, tmp_path / "m")
    names = ["no bounce, uncorrected", "1 bounce, uncorrected", "1 bounce, reference + dent corrected"]
    experiments.sweep(
        {"AAE": (names, [0.7, 8.1, 1.0], [0.0] * 3)}, "render", "AAE (°)", tmp_path / "i", categorical=True
    )
    learn.coverage_figure(_down_tilt_coverage(cells=4), tmp_path / "cov.png")  # `nlips calibrate`'s 4 x 4
    for fig in charts:
        assert _smallest_text_px(fig, experiments.DPI) >= MIN_TEXT_PX
    for fig in curves:
        assert _smallest_text_px(fig, learn.DPI) >= MIN_TEXT_PX
    n = np.zeros((12, 16, 3))
    n[..., 2] = -1.0
    err = np.full((12, 16), 0.5)
    rows = [("sphere", [Panel("normals", normals_to_rgb(n)), Panel("error", err, "inferno", "deg", 0.0, 1.0)])]
    assert _smallest_text_px(sheet_figure(rows, "caption", "title"), SHEET_DPI) >= MIN_TEXT_PX
    assert _smallest_text_px(sheet_figure(rows, "caption", "title"), experiments.DPI) >= MIN_TEXT_PX


def test_three_line_row_titles_stay_inside_the_sheet_and_off_the_images():
    """Q1's and Q3's rows are titled in three lines (labels, press, contact AAE): in a fixed 0.5 in margin they
    touched the sheet's left edge and the first image."""
    from nlipscalib.report.figures import sheet_figure

    n = np.zeros((40, 40, 3))
    n[..., 2] = -1.0
    title = "sphere, calibrated\nsphere-p15-a30-d1\ncontact AAE 0.96 deg"
    fig = sheet_figure([(title, [Panel("true normals", normals_to_rgb(n))])])
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    text = next(t for t in fig.texts if t.get_text() == title).get_window_extent(renderer)
    image = fig.axes[0].get_window_extent(renderer)
    assert text.x0 >= 0 and text.x1 <= image.x0


def test_experiment_figures_are_titled_with_their_report_caption(tmp_path, monkeypatch):
    """A chart or sheet opened alone (not in report.md) said nothing of what it shows: each is titled with the
    caption report.md gives it. MabsE's axis says what it measures."""
    from nlipscalib.experiments.q1 import Q1
    from nlipscalib.report import experiments

    charts = _kept_figures(monkeypatch, experiments)
    rows = [
        {"indenter": kind, "leds": leds, "aae_deg": 1.0, "mabse": 0.01, "error": None}
        for kind in ("sphere", "cube")
        for leds in ("true", "calibrated")
    ]
    figs = Q1().figures(None, rows, [], tmp_path)
    assert [fig.axes[0].get_title() for fig in charts] == [caption for caption, _ in figs]
    assert charts[1].axes[0].get_ylabel() == experiments.MABSE_LABEL == "MabsE in the contact (unitless)"
    sheets = _drawn_sheets(monkeypatch)
    n = _flat_normals()
    experiments.error_maps([("sphere", n, n, np.full((6, 8), 0.4))], tmp_path / "e.png", title="Q1 maps")
    view = {"rgb": n, "true": n, "estimate": n, "error": np.full((6, 8), 0.4)}
    experiments.nlipsnet_maps([("seen: sphere", view)], tmp_path / "n.png", title="Q2 maps")
    assert [[t.get_text() for t in fig.texts if t.get_text().startswith("Q")] for fig in sheets] == [
        ["Q1 maps"],
        ["Q2 maps"],
    ]


def test_a_categorical_sweep_draws_no_line_between_its_settings(tmp_path, monkeypatch):
    """The interreflection study's settings (no bounce, 1 bounce uncorrected, corrected...) have no order: a line
    through them drew a trend."""
    from nlipscalib.report import experiments

    charts = _kept_figures(monkeypatch, experiments)
    series = {"AAE": (["no bounce", "1 bounce", "corrected"], [0.6, 8.1, 1.0], [0.0, 0.0, 0.0])}
    experiments.sweep(series, "render / correction", "AAE (°)", tmp_path / "c.png", categorical=True)
    experiments.sweep({"AAE": ([0.0, 1.0], [0.9, 1.0], [0.0, 0.0])}, "noise", "AAE (°)", tmp_path / "n.png")
    styles = [[line.get_linestyle() for line in fig.axes[0].lines] for fig in charts]
    assert styles[0] and all(s == "None" for s in styles[0])
    assert "-" in styles[1]


def test_every_error_panel_has_one_colour_map_and_unit(monkeypatch):
    """The demo's and the experiments' sheets labelled their error colour bars "degrees", the summary and
    error.png "deg": one helper draws them all now."""
    from nlipscalib.cli.demo import _error_panel
    from nlipscalib.report import experiments
    from nlipscalib.report.figures import ERROR_CMAP, ERROR_UNIT, error_panel

    sheets = []
    monkeypatch.setattr(experiments, "contact_sheet", lambda rows, path, **kw: sheets.append(rows) or Path(path))
    monkeypatch.setattr(experiments, "write_bytes", lambda path, data: Path(path))
    monkeypatch.setattr(experiments.Path, "read_bytes", lambda self: b"")
    monkeypatch.setattr(experiments, "_palette_png", lambda png: png)
    err = np.full((6, 8), 0.4)
    n = np.zeros((6, 8, 3))
    n[..., 2] = -1.0
    experiments.error_maps([("sphere", n, n, err)], "e.png")
    experiments.nlipsnet_maps([("sphere", {"rgb": n, "true": n, "estimate": n, "error": err})], "n.png")
    panels = [_error_panel(err), error_panel("angular error", err)] + [rows[0][1][-1] for rows in sheets]
    assert [(p.cmap, p.label, p.vmin, p.vmax) for p in panels] == [(ERROR_CMAP, ERROR_UNIT, 0.0, 1.0)] * 4


def test_training_curve_names_its_validation_presses(tmp_path, monkeypatch):
    """`nlips train` prints "validation AAE 3.60 deg ... on sphere"; its curve said "NLiPsNet 64,64,64" only."""
    from nlipscalib.report import learn

    curves = _kept_figures(monkeypatch, learn)
    history = [{"epoch": 0, "train_loss": 0.1, "val_aae_deg": 3.6, "val_contact_aae_deg": 3.96}]
    learn.training_curve(history, tmp_path / "c.png", "NLiPsNet 64,64,64", ["sphere"])
    assert curves[0]._suptitle.get_text() == "NLiPsNet 64,64,64, validation press sphere"
    assert learn.validation_line(["a", "b"]) == ", validation presses a, b"
    assert learn.validation_line([f"p{i}" for i in range(10)]) == ", validation presses " + ", ".join(
        f"p{i}" for i in range(10)
    )
    long = ["sphere-p12.1-a15.2-d1.05-86cb5640ea-584aae", "cube-p9.4-a287.5-d1.18-86cb5640ea-df01e4"]
    assert learn.validation_line(long) == ", 2 validation presses"  # names this long would run off the figure
    assert learn.validation_line([]) == ""


def test_a_summary_of_a_region_says_where_it_lies_in_the_image(tmp_path, monkeypatch):
    """A `--roi auto` summary showed a crop without axes or a word of which part of the capture it was."""
    from nlipscalib.report import figures, write_reconstruction_figures
    from nlipscalib.report.reconstruction import box_words

    sheets = {}
    monkeypatch.setattr(figures, "contact_sheet", lambda rows, path, **kw: sheets.update(rows=rows, **kw) or path)
    rec = _reconstruction(h=12, w=16)
    rec.mask[:] = False
    rec.mask[3:9, 5:12] = True
    write_reconstruction_figures(tmp_path, rec, None, "full", name="sphere")
    assert sheets["title"] == "sphere, NLiPs, pixels u 5-11, v 3-8"
    assert box_words((slice(None), slice(None)), (12, 16)) == ""


def test_the_response_figures_key_shows_its_measured_points_large_enough_to_see(tmp_path, monkeypatch):
    """The cloud's 2-pt dots were as small in the legend: "measured (green)" stood beside an invisible key."""
    from nlipscalib.report import camera_response
    from nlipscalib.report.figures import MIN_TEXT_PX

    figures = []
    save = camera_response.save_png
    monkeypatch.setattr(camera_response, "save_png", lambda fig, path, dpi: figures.append(fig) or save(fig, path, dpi))
    codes = np.arange(256.0)
    linear = (codes / 255) ** 2.2
    camera_response.response_figure(linear, np.stack([linear] * 3, 1), (codes, linear), tmp_path / "r.png", "cam")
    ax = figures[0].axes[0]
    key = next(h for h in ax.get_legend().legend_handles if hasattr(h, "get_sizes"))
    assert key.get_sizes()[0] >= 8 * ax.collections[0].get_sizes()[0]
    assert _smallest_text_px(figures[0], camera_response.DPI) >= MIN_TEXT_PX


def test_a_narrow_sheets_title_and_caption_are_wrapped_inside_it():
    """An image frame's summary (`nlips infer FRAME --figures full`: normals and depth, no truth) is two panels wide:
    the normal-colour key under it was cut at both edges."""
    from nlipscalib.report.figures import MIN_TEXT_PX, NORMALS_KEY, SHEET_DPI, sheet_figure

    n = np.zeros((120, 160, 3))
    n[..., 2] = -1.0
    panels = [Panel("normals", normals_to_rgb(n)), Panel("indentation", np.ones((120, 160)), label="mm")]
    title = "a frame with a long name, NLiPsNet, pixels u 100-159, v 0-119, and more words than fit"
    fig = sheet_figure([("", panels)], NORMALS_KEY, title)
    assert _smallest_text_px(fig, SHEET_DPI) >= MIN_TEXT_PX  # every text inside the figure
    texts = {t.get_text().replace("\n", " "): t for t in fig.texts}
    assert set(texts) == {NORMALS_KEY, title} and all("\n" in t.get_text() for t in texts.values())
    renderer = fig.canvas.get_renderer()
    images = [ax.get_window_extent(renderer) for ax in fig.axes]
    headings = [ax.title.get_window_extent(renderer) for ax in fig.axes if ax.get_title()]
    assert texts[title].get_window_extent(renderer).y0 >= max(b.y1 for b in images + headings)  # over the panels
    assert texts[NORMALS_KEY].get_window_extent(renderer).y1 <= min(b.y0 for b in images)  # under them


@pytest.mark.parametrize("cells", [1, 2, 4])
def test_the_coverage_header_fits_any_grid_over_its_plots(tmp_path, monkeypatch, cells):
    """`nlips calibrate` draws 4 x 4 regions; ``learn.coverage(cells=2)``'s 5.4-in figure cut its header's three long
    lines (where to press next, the steep-normals advice, how to read a plot) at both edges."""
    from nlipscalib.report import learn
    from nlipscalib.report.figures import MIN_TEXT_PX

    figures = _kept_figures(monkeypatch, learn)
    cov = _down_tilt_coverage(cells=cells)
    cov["next_press"].update(polar_deg=12.3, azimuth_deg=-135.0)
    cov["steep"] = {"taught_tilt_deg": 31.0, "untaught_from_deg": 38.0}
    learn.coverage_figure(cov, tmp_path / "cov.png")
    fig = figures[0]
    assert _smallest_text_px(fig, learn.DPI) >= MIN_TEXT_PX  # every text inside the figure
    renderer = fig.canvas.get_renderer()
    header = fig._suptitle.get_window_extent(renderer)
    assert "steep relief" in fig._suptitle.get_text()
    assert header.y0 >= max(ax.title.get_window_extent(renderer).y1 for ax in fig.axes if ax.get_title())
    bar = fig.axes[-1].get_window_extent(renderer)
    assert bar.y1 <= header.y0  # the colour bar beside the plots, not the header


def test_the_training_curves_aae_axis_starts_at_zero_as_every_aae_chart(tmp_path, monkeypatch):
    """From the curve's own low (3.6 deg) the late epochs' 0.1-deg gains filled the axis; the experiment charts'
    AAE axes start at 0."""
    from nlipscalib.report import learn

    figures = _kept_figures(monkeypatch, learn)
    history = [
        {"epoch": e, "train_loss": 0.1 / (e + 1), "val_aae_deg": 4.0 + 6 / (e + 1), "val_contact_aae_deg": 5.0}
        for e in range(12)
    ]
    learn.training_curve(history, tmp_path / "curve.png")
    bottom, top = figures[0].axes[1].get_ylim()
    assert bottom == 0.0
    assert 10.0 < top <= 10.0 * 1.1  # the first epoch's 10 deg drawn whole, a little below the frame
