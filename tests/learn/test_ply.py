"""learn.ply.write_ply: what it writes, and the errors an API caller sees."""

import errno

import numpy as np
import pytest

from nlipscalib.core.errors import ShapeError
from nlipscalib.learn.ply import write_ply


def test_points_and_normals_of_other_shapes_name_both(tmp_path):
    """Normals of another shape than the points were refused naming the points' shape alone (both (H, W, 3)-like)."""
    points = np.zeros((4, 5, 3), np.float32)
    with pytest.raises(ShapeError, match=r"got points \(4, 5, 3\), normals \(3, 5, 3\)"):
        write_ply(tmp_path / "a.ply", points, np.zeros((3, 5, 3)))
    with pytest.raises(ShapeError, match=r"got points \(4, 5\)$"):
        write_ply(tmp_path / "a.ply", points[..., 0])
    assert list(tmp_path.iterdir()) == []


def test_a_folder_for_the_file_is_named_not_the_writes_temporary(tmp_path):
    """A folder given for the file failed naming the write's temporary file ("out/.tmp-api~host~pid~... -> out/api")."""
    with pytest.raises(IsADirectoryError, match="a folder; give the path of the .ply file to write") as raised:
        write_ply(tmp_path, np.zeros((4, 5, 3), np.float32))
    assert raised.value.errno == errno.EISDIR and raised.value.filename == str(tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_the_finite_points_are_written_with_their_normals(tmp_path):
    points = np.arange(60, dtype=np.float32).reshape(4, 5, 3)
    points[0, 0] = np.nan
    path = write_ply(tmp_path / "sub" / "a.ply", points, points)
    data = path.read_bytes()
    header, body = data.split(b"end_header\n")
    assert b"element vertex 19" in header and b"property float nz" in header
    vertices = np.frombuffer(body, "<f4").reshape(19, 6)
    np.testing.assert_array_equal(vertices[:, :3], points.reshape(-1, 3)[1:])
