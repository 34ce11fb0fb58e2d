"""The indirect term at the outline of a view that sees past the gel (issue 6, s35-wideedge): its light upsampled
from patches must not blend in the patches off the gel."""

import numpy as np
from scipy import ndimage

from nlipscalib.core.camera import depth_to_points
from nlipscalib.solver import radiosity
from nlipscalib.solver.indirect import IndirectModel, Surface, surface_indirect

from .test_smoothness import _wide_dome


def test_at_the_gels_outline_the_indirect_light_is_the_gather_at_each_pixel():
    """Known answer: exact geometry of a 130 deg view down to a dome's base (black corners), 4 px patches. The term
    (:func:`surface_indirect`: gathered at the patches, upsampled) against the same emitters gathered at each pixel's
    own point and normal: within 2 % at the outer two pixels (0.1-0.3 %), as inside (0.5 %). Plain bilinear
    upsampling blended in the empty patches beyond the outline: the outer pixel 8 % low in median, up to 33 %."""
    _, camera, leds, depth, normals = _wide_dome(0.0, 12.0)
    valid = np.isfinite(depth)
    size, albedo = 4, 0.25
    model = IndirectModel((1.0,) * 3, (albedo,) * 3, 0.5, 1, True, "exact", None, (albedo,) * 3)
    term = surface_indirect(model, camera, leds, depth, normals, np.full(depth.shape + (3,), albedo), valid, size)
    surf = Surface(camera, leds, depth, normals, size)
    emitted = albedo * surf.shading[:, surf.keep]
    points = depth_to_points(np.where(valid, depth, 0.0), camera.rays)[valid]
    exact = albedo * radiosity.gather(points, normals[valid], surf.emitters(), emitted)
    ratio = term[:, valid].sum(axis=(0, 2)) / exact.sum(axis=(0, 2))  # per pixel, over the LEDs
    distance = ndimage.distance_transform_edt(valid)[valid]
    outer, inside = ratio[distance <= 2], ratio[distance > 4]
    assert abs(np.median(inside) - 1) < 0.01
    assert np.abs(outer - 1).max() < 0.02, (outer.min(), outer.max())


def test_a_receiver_boxs_light_is_the_whole_frames_cut_to_it():
    """A box of receivers (an auto ROI, the outer loop's focus) reads the light the whole frame's gather gives its
    pixels (to rounding), its corners too: the patches a receiver's bilinear weights reach are gathered, the diagonal
    ones included (by the cross they were left unset, and their 0 was blended into the corner pixels)."""
    _, camera, leds, depth, normals = _wide_dome(0.0, 12.0)
    valid = np.isfinite(depth)
    albedo = np.full(depth.shape + (3,), 0.25)
    model = IndirectModel((1.0,) * 3, (0.25,) * 3, 0.5, 1, True, "exact", None, (0.25,) * 3)
    whole = surface_indirect(model, camera, leds, depth, normals, albedo, valid, 4)
    box = np.zeros_like(valid)
    box[17:31, 21:43] = True  # inside the gel; its corner pixels lie beyond their patches' centres
    assert (box <= valid).all()
    part = surface_indirect(model, camera, leds, depth, normals, albedo, box, 4)
    np.testing.assert_allclose(part[:, box], whole[:, box], rtol=1e-5)  # the gathers' sums in another order
