import numpy as np
import pytest

from nlipscalib.core.imageio import read_npz, save_npz
from nlipscalib.errors import CaptureError
from tests.core.test_reconstruction import _spoil_deflated_member


def test_a_damaged_deflated_array_is_one_error_naming_the_file(tmp_path):
    path = save_npz(tmp_path / "a.npz", {"a": np.zeros((40, 50), np.float32)}, compress=True)
    _spoil_deflated_member(path, "a.npy")  # zlib fails ("invalid block type") before the zip CRC check
    with pytest.raises(CaptureError, match=r"a\.npz: damaged or truncated \.npz \(compressed data damaged: ") as caught:
        read_npz(path)
    assert str(path) in str(caught.value)
