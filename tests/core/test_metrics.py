import numpy as np
import pytest

from nlipscalib.core.errors import ShapeError
from nlipscalib.core.metrics import aae, angle_deg, angular_error_map, depth_rmse, mabse


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


def _turned(n: np.ndarray, rad: float) -> np.ndarray:
    """(N, 3) unit vectors ``n`` ((N, 3) unit, in the x-z plane) turned by ``rad`` about y."""
    c, s = np.cos(rad), np.sin(rad)
    return np.stack([c * n[:, 0] + s * n[:, 2], n[:, 1], -s * n[:, 0] + c * n[:, 2]], -1)


def test_angle_is_exact_near_0_and_180_deg():
    """arccos of a rounded cosine kept ~8 digits at 1e-7 rad; atan2 of sine and cosine keeps them all."""
    n = np.array([[0.0, 0.0, -1.0], [0.6, 0.0, -0.8]])
    for rad in (1e-7, 1e-4, 0.3):
        np.testing.assert_allclose(angular_error_map(_turned(n, rad), n), np.degrees(rad), rtol=1e-9)
        np.testing.assert_allclose(angle_deg(_turned(n, np.pi - rad), n), 180 - np.degrees(rad), rtol=1e-12)
    assert angle_deg([0.0, 0.0, 1.0], [0.0, 0.0, -1.0 - 1e-15]) == 180.0  # a cosine past -1 is no NaN


def test_angle_of_float32_unit_normals_is_their_angle():
    """A float32 unit vector's length is off by ~1e-7: arccos read that as ~0.02 deg at 0 deg."""
    n = (np.random.default_rng(2).normal(size=(1000, 3)) * [0.3, 0.3, 1]).astype(np.float32)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    assert np.abs(angular_error_map(n, n)).max() < 1e-9
    assert aae(n, n) < 1e-9


def test_angle_ignores_lengths_and_is_nan_without_a_direction():
    a = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 0.5], [0.0, 0.0, 0.0], [np.nan, 0.0, 1.0], [0.0, np.inf, 1.0]])
    b = np.array([[0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    got = angular_error_map(a, b)
    np.testing.assert_allclose(got[:2], [45.0, 0.0], atol=1e-12)
    assert np.isnan(got[2:]).all()
    assert aae(a, b, np.array([True, True, False, True, True])) == pytest.approx(22.5)  # non-finite pixels skipped
    with pytest.raises(ShapeError):
        angle_deg(np.zeros((2, 3)), np.zeros((2, 2)))


def test_evaluate_without_ground_truth_or_of_another_size_is_one_clear_error():
    """`evaluate(rec, press.ground_truth)` of a real capture (no ground truth: None) failed on "'NoneType' object has
    no attribute 'valid'"; a result of another image size on NumPy's broadcasting error."""
    from types import SimpleNamespace

    from nlipscalib.core.errors import CaptureError
    from nlipscalib.core.metrics import evaluate

    result = SimpleNamespace(normals=np.zeros((4, 5, 3)), depth=np.zeros((4, 5)), reconstructed=np.ones((4, 5), bool))
    with pytest.raises(CaptureError, match=r"no ground truth \(None\): a real capture carries none"):
        evaluate(result, None)
    truth = SimpleNamespace(valid=np.ones((6, 5), bool), contact=np.zeros((6, 5), bool))
    with pytest.raises(ShapeError, match=r"result of a \(4, 5\) image, the ground truth's is \(6, 5\)"):
        evaluate(result, truth)
