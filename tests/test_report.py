import numpy as np

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
