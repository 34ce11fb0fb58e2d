import numpy as np
import pytest

from nlipscalib.report import Panel, contact_sheet, normals_to_rgb


def test_normal_map_colours_known_answers():
    n = np.array([[[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]])  # toward camera, right, up
    rgb = normals_to_rgb(n, mask=np.array([[True, True, False]]))
    np.testing.assert_allclose(rgb[0, 0], [0.5, 0.5, 1.0])  # facing the camera: blue
    np.testing.assert_allclose(rgb[0, 1], [1.0, 0.5, 0.5])  # facing right: red
    np.testing.assert_allclose(rgb[0, 2], [0.0, 0.0, 0.0])  # masked out


def test_contact_sheet_writes_a_png(tmp_path):
    img = np.random.default_rng(0).random((8, 10))
    path = contact_sheet(
        [("row", [Panel("scalar", img, label="mm"), Panel("rgb", np.zeros((8, 10, 3)))])], tmp_path / "s.png"
    )
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_scalar_map_colours_range_and_missing_values(tmp_path):
    import cv2

    from nlipscalib.report.maps import BAR_WIDTH, NO_VALUE_BGR, scalar_map_png

    values = np.array([[0.0, 10.0, np.nan], [5.0, 20.0, -3.0]])
    img = cv2.imread(str(scalar_map_png(tmp_path / "m.png", values, "gray", "deg", 0, 10)), cv2.IMREAD_COLOR)
    assert img.shape == (2, 3 + BAR_WIDTH, 3)  # the image grid kept, the colour bar beside it
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


def test_live_depth_colours_black_off_the_gel():
    from nlipscalib.report.live import depth_to_rgb

    depth = np.array([[np.nan, 10.0], [10.5, 12.0]], np.float32)
    rgb = depth_to_rgb(depth, reference=np.full((2, 2), 10.0))
    assert rgb.shape == (2, 2, 3) and rgb[0, 0].sum() == 0 and rgb[1, 1].sum() > 0


def test_live_depth_colours_are_the_scalar_maps_colours():
    """The live window's depth had a colour mapping of its own (cv2 viridis on truncated levels) beside the scalar
    maps' (rounded levels): one colour mapping now, report.maps.colour_scalars, black off the gel."""
    from nlipscalib.report.live import depth_to_rgb
    from nlipscalib.report.maps import colour_scalars

    reference = np.full((2, 3), 10.0)
    depth = reference + np.array([[np.nan, 0.25, 0.5], [1.0, 2.5, -1.0]])  # levels 31.9 and 63.75: rounded up
    expected = colour_scalars(depth - reference, 0.0, 2.0, "viridis", no_value=(0, 0, 0))[..., ::-1]
    np.testing.assert_array_equal(depth_to_rgb(depth, reference, span_mm=2.0), expected)
    expected = colour_scalars(depth, 9.0, 12.5, "viridis", no_value=(0, 0, 0))[..., ::-1]  # its own range
    np.testing.assert_array_equal(depth_to_rgb(depth), expected)


def test_live_window_shows_normals_beside_depth_and_q_ends_the_stream(monkeypatch):
    import cv2

    from nlipscalib.device.live import LiveResult, StopLive
    from nlipscalib.report.live import WindowSink, depth_to_rgb

    shown, keys = [], [-1, ord("q")]
    monkeypatch.setattr(cv2, "imshow", lambda name, bgr: shown.append(bgr))
    monkeypatch.setattr(cv2, "waitKey", lambda ms: keys.pop(0))
    normals = np.zeros((4, 5, 3), np.float32)
    normals[..., 2] = -1.0  # facing the camera
    result = LiveResult(normals, np.full((4, 5), 10.5, np.float32))
    sink = WindowSink(StopLive, reference_depth=np.full((4, 5), 10.0))
    sink(0, None, result)
    assert shown[0].shape == (4, 10, 3)
    assert tuple(shown[0][0, 0]) == (255, 127, 127)  # BGR of the camera-facing blue, as the saved normal maps
    np.testing.assert_array_equal(shown[0][:, 5:, ::-1], depth_to_rgb(result.depth, np.full((4, 5), 10.0)))
    with pytest.raises(StopLive):
        sink(1, None, result)
