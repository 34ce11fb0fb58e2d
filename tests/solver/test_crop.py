"""The crop of a solve's mask: its camera (the same lens, shifted) and that camera's rays."""

import dataclasses

import numpy as np

from nlipscalib.core.camera import Camera
from nlipscalib.solver.crop import crop_to_mask


def _fisheye() -> Camera:
    return Camera(width=96, height=72, fx=53.3, fy=53.3, cx=47.5, cy=35.5, model="fisheye", dist=(0.05, -0.01, 0, 0))


def test_a_crop_of_a_camera_with_its_rays_made_takes_their_box_the_same_bits():
    """The whole image's rays (made by the contact search) are the crop's: not unprojected again on the main thread
    (9 ms for the cube press's 336x332 box), and the same bits as the crop camera's own."""
    mask = np.zeros((72, 96), bool)
    mask[11:53, 20:81] = True
    camera = _fisheye()
    camera.rays  # noqa: B018  (made, as a solve's contact search makes them)
    crop, cam = crop_to_mask(mask, camera)
    assert crop == (slice(11, 53), slice(20, 81))
    assert np.shares_memory(vars(cam)["rays"], camera.rays)  # taken, not computed
    fresh = dataclasses.replace(cam)  # the same crop camera, its rays unprojected
    np.testing.assert_array_equal(cam.rays, fresh.rays)
    assert cam.rays.shape == (42, 61, 3)


def test_a_crop_of_a_camera_without_its_rays_leaves_them_to_be_made():
    mask = np.zeros((72, 96), bool)
    mask[5:9, 7:30] = True
    crop, cam = crop_to_mask(mask, _fisheye())
    assert "rays" not in vars(cam)
    np.testing.assert_array_equal(cam.rays, _fisheye().rays[crop])
