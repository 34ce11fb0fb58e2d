import numpy as np
import pytest

from nlipscalib.core.metrics import aae, angular_error_map, depth_rmse, mabse
from nlipscalib.errors import ShapeError


def test_metrics_values():
    gt = np.zeros((2, 2, 3))
    gt[..., 2] = -1
    est = gt.copy()
    a = np.radians(10)
    est[0, 0] = [np.sin(a), 0, -np.cos(a)]
    assert aae(gt, gt) == 0
    assert aae(est, gt) == pytest.approx(2.5, abs=1e-9)
    assert aae(est, gt, np.array([[True, False], [False, False]])) == pytest.approx(10, abs=1e-9)
    assert mabse(est, gt) == pytest.approx((np.sin(a) + 1 - np.cos(a)) / 12)
    assert angular_error_map(est, gt)[0, 0] == pytest.approx(10)
    assert depth_rmse(np.array([1.0, 2.0, np.nan]), np.array([1.0, 4.0, 3.0])) == pytest.approx(np.sqrt(2))


def test_metrics_shape_errors():
    with pytest.raises(ShapeError):
        aae(np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(ShapeError):
        mabse(np.zeros((2, 3)), np.zeros((2, 3)), np.ones(3, bool))
