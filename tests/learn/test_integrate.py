"""Depth from normals on the dome: exact normals of a known indentation give back its depth."""

import numpy as np
import pytest
from scipy import ndimage

from nlipscalib.core import load_press
from nlipscalib.learn.integrate import RayGeometry, integrate_on_dome


def _dent(press, normals, method="auto"):
    gt, ref = press.ground_truth, press.reference
    geo = RayGeometry.from_reference(press.camera.rays, ref.depth.astype(np.float64))
    unknown = ndimage.binary_dilation(gt.contact, iterations=2) & gt.valid
    depth, points = integrate_on_dome(normals, unknown, geo, method)
    ref_range = np.exp(geo.log_range)
    dent = ref_range - np.linalg.norm(points, axis=-1)  # displacement into the gel along the ray, mm
    true_dent = ref_range - np.linalg.norm(gt.points, axis=-1)
    return dent, true_dent, unknown, depth


@pytest.mark.parametrize("method", ["box", "sparse"])
def test_exact_normals_of_a_sphere_press_recover_its_depth_within_5_percent(twin_presses, method):
    press = load_press(twin_presses / "press_a")
    dent, true_dent, unknown, depth = _dent(press, press.ground_truth.normals, method)
    assert true_dent[unknown].max() > 0.8  # a real dent (1.3 mm press)
    assert abs(dent[unknown].max() - true_dent[unknown].max()) <= 0.05 * true_dent[unknown].max()
    # and everywhere in the dent, not only at the deepest point
    err = np.abs(dent[unknown] - true_dent[unknown])
    assert err.mean() <= 0.05 * true_dent[unknown].max()
    # outside the solved pixels the depth is the undeformed reference's
    solved = unknown.copy()
    if method == "box":  # the box around the changed pixels that the solver integrates over
        from nlipscalib.learn.integrate import _box

        solved[_box(unknown, press.ground_truth.valid)] = True
    outside = press.ground_truth.valid & ~solved
    np.testing.assert_allclose(depth[outside], press.reference.depth[outside], rtol=1e-5)


@pytest.mark.parametrize("method", ["box", "sparse"])
def test_reference_normals_give_the_undeformed_dome(twin_presses, method):
    press = load_press(twin_presses / "press_a")
    dent, _, unknown, _ = _dent(press, press.reference.normals, method)
    assert np.abs(dent[unknown]).max() < 0.02  # mm: the dome's own normals integrate to the dome


@pytest.mark.parametrize("method", ["box", "sparse"])
def test_grazing_or_back_facing_normals_give_a_finite_surface(twin_presses, method):
    # an untrained network or a frame of another sensor predicts any direction
    press = load_press(twin_presses / "press_a")
    rays = press.camera.rays
    grazing = np.cross(rays, [1.0, 0.0, 0.0])  # n . d = 0 on every ray
    grazing /= np.linalg.norm(grazing, axis=-1, keepdims=True)
    for normals in (grazing, rays):  # along the ray: faces away
        _, _, unknown, depth = _dent(press, normals, method)
        assert np.isfinite(depth[unknown]).all()
