"""Depth from normals on the dome: exact normals of a known indentation give back its depth."""

import numpy as np
import pytest
from scipy import ndimage

from nlipscalib.core import load_press
from nlipscalib.learn.integrate import integrate_on_dome
from nlipscalib.learn.integrate_geometry import RayGeometry


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
        from nlipscalib.learn.integrate_regions import _box

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


def _sphere_pressed_into_the_dome(design, polar, azimuth, radius, depth):
    """Exact depth and normals of a sphere (radius mm) pressed ``depth`` mm into the undeformed dome at
    (polar, azimuth) deg: the nearer of the dome and the sphere along every ray (ray-sphere intersection)."""
    from nlipscalib.core.dome import dome_surface_point, reference_surface

    rays = design.camera_model().rays
    ref = reference_surface(design)
    apex, inward = dome_surface_point(design.dome, polar, azimuth)
    centre = apex - np.asarray(design.camera.position) + inward * (depth - radius)
    b = rays @ centre
    disc = b * b - (centre @ centre - radius**2)
    ref_range = ref.depth / rays[..., 2]
    with np.errstate(invalid="ignore"):
        near = b - np.sqrt(disc)
    hit = np.isfinite(ref.depth) & (disc > 0) & (near > 0) & (near < ref_range)
    points = np.where(hit, near, ref_range)[..., None] * rays
    normals = np.where(hit[..., None], (points - centre) / radius, ref.normals)
    return ref, rays, hit, points, normals


@pytest.mark.parametrize(("polar", "azimuth", "radius", "depth"), [(0, 0, 4.0, 1.0), (30, 90, 7.0, 2.0)])
def test_a_wide_contact_at_full_size_keeps_its_depth_on_either_path(polar, azimuth, radius, depth):
    # 7,000-24,000 px contacts at 640x480, the second reaching the image border (where "auto" takes an edge
    # box): a pull toward the undeformed dome on every unknown made them 4-14 % too shallow
    from nlipscalib.core.sensor import SensorDesign

    ref, rays, hit, points, normals = _sphere_pressed_into_the_dome(SensorDesign(), polar, azimuth, radius, depth)
    unknown = ndimage.binary_dilation(hit, iterations=3) & np.isfinite(ref.depth)
    geo = RayGeometry.from_reference(rays, ref.depth.astype(np.float64))
    true_dent = ref.depth - points[..., 2]
    for method in ("auto", "sparse"):
        got, _ = integrate_on_dome(normals, unknown, geo, method)
        dent = ref.depth - got
        assert dent[unknown].max() == pytest.approx(true_dent[unknown].max(), rel=0.01), method
        assert np.abs(dent - true_dent)[unknown].mean() < 0.01 * true_dent.max(), method


def test_a_region_touching_no_known_pixel_is_held_at_the_reference_level():
    # every pixel unknown: the Poisson equation fixes the shape only; the anchor sets the level
    from nlipscalib.core.sensor import SensorDesign

    ref, rays, _, _, _ = _sphere_pressed_into_the_dome(SensorDesign(), 0, 0, 4.0, 1.0)
    on_gel = np.isfinite(ref.depth)
    geo = RayGeometry.from_reference(rays, ref.depth.astype(np.float64))
    got, _ = integrate_on_dome(ref.normals, on_gel, geo, "sparse")
    assert np.abs(got - ref.depth)[on_gel].max() < 0.05  # mm


def _dome_and_sphere():
    from nlipscalib.core.sensor import SensorDesign

    ref, rays, hit, points, normals = _sphere_pressed_into_the_dome(SensorDesign(), 0, 0, 4.0, 1.0)
    on_gel = np.isfinite(ref.depth)
    geo = RayGeometry.from_reference(rays, ref.depth.astype(np.float64))
    contact = ndimage.binary_dilation(hit, iterations=3) & on_gel
    return ref, geo, on_gel, contact, normals


def _pixels(bounds, unknown):
    """The changed pixels inside the bounds ((rows, cols) slices)."""
    out = np.zeros_like(unknown)
    for crop in bounds:
        out[crop] |= unknown[crop]
    return out


def test_noise_specks_at_the_border_leave_the_contact_to_its_box():
    # 2-spp frames at 1280x960 flag a few small regions at the image border: the one box around all changed
    # pixels then touched the border, and the whole contact went to SuperLU (0.4-0.7 s a frame)
    from nlipscalib.learn.integrate_regions import _box, _regions

    ref, geo, on_gel, contact, normals = _dome_and_sphere()
    assert on_gel.all()  # the gel fills the default image: every border pixel is on it
    specks = np.zeros_like(contact)
    specks[0:4, 0:5] = specks[-3:, 300:306] = specks[200:206, -4:] = True
    assert not (ndimage.binary_dilation(specks, iterations=2) & contact).any()
    boxes, edge_boxes, sparse = _regions(contact | specks, on_gel, "auto")
    assert boxes == [_box(contact, on_gel)]  # the contact's own box, as without the specks
    assert sorted(edges for _, edges in edge_boxes) == [(-1, -1), (0, 1), (1, 0)] and sparse == []  # one each
    np.testing.assert_array_equal(_pixels([box for box, _ in edge_boxes], contact | specks), specks)
    # and the depth: the contact's as if alone, the specks' the dome's (their normals are the dome's)
    got, _ = integrate_on_dome(normals, contact | specks, geo)
    alone, _ = integrate_on_dome(normals, contact, geo)
    np.testing.assert_array_equal(got[boxes[0]], alone[boxes[0]])
    assert np.abs(got - ref.depth)[specks].max() < 0.05  # mm


def test_regions_whose_bounds_overlap_are_solved_together():
    from nlipscalib.learn.integrate_regions import BOTH_SIDES, _regions

    on_gel = np.ones((60, 80), bool)
    near = np.zeros_like(on_gel)
    near[20:25, 20:25] = near[20:25, 26:30] = True  # one column apart: their rings share pixels
    boxes, edge_boxes, sparse = _regions(near, on_gel, "auto")
    assert sparse == edge_boxes == [] and len(boxes) == 1  # the common box applies
    # beside a region across the whole width (natural sides at both ends of a row: a cosine box), their bounds
    # overlap its, so all three take its box
    touching = near.copy()
    touching[26:29, :] = True
    boxes, edge_boxes, sparse = _regions(touching, on_gel, "auto")
    assert boxes == sparse == [] and [edges for _, edges in edge_boxes] == [(0, BOTH_SIDES)]
    np.testing.assert_array_equal(_pixels([edge_boxes[0][0]], touching), touching)
    # far from it: the two keep their box, the band has its own
    apart = near.copy()
    apart[50:53, :] = True
    boxes, edge_boxes, sparse = _regions(apart, on_gel, "auto")
    assert len(boxes) == 1 and near[boxes[0]].sum() == near.sum() and sparse == []
    np.testing.assert_array_equal(_pixels([edge_boxes[0][0]], apart), apart & ~near)
    # a region across both axes: no fixed pixel in its box, the sparse path (its bounds hold the others)
    crossed = apart.copy()
    crossed[:, 70:72] = True
    boxes, edge_boxes, sparse = _regions(crossed, on_gel, "auto")
    assert boxes == edge_boxes == [] and len(sparse) == 1
    np.testing.assert_array_equal(_pixels(sparse, crossed), crossed)
    # a region at the image border beside them: one edge box for all three
    at_border = near.copy()
    at_border[20:25, 0:19] = True
    boxes, edge_boxes, sparse = _regions(at_border, on_gel, "auto")
    assert boxes == sparse == [] and [edges for _, edges in edge_boxes] == [(0, -1)]
    np.testing.assert_array_equal(_pixels([edge_boxes[0][0]], at_border), at_border)


@pytest.mark.parametrize(
    ("polar", "azimuth", "edges"), [(35, 90, (1, 0)), (50, 180, (0, -1)), (50, 0, (0, 1)), (55, 35, (1, 1))]
)
def test_exact_normals_of_a_contact_at_the_image_border_give_its_depth_in_an_edge_box(polar, azimuth, edges):
    # a press at the edge of the view: its box passes the image border, where the least-squares problem has
    # no pixel pair (a natural side); the edge box mirrors it there instead of leaving it to SuperLU
    from nlipscalib.core.sensor import SensorDesign
    from nlipscalib.learn.integrate_regions import _regions

    ref, rays, hit, points, normals = _sphere_pressed_into_the_dome(SensorDesign(), polar, azimuth, 7.0, 2.0)
    on_gel = np.isfinite(ref.depth)
    unknown = ndimage.binary_dilation(hit, iterations=3) & on_gel
    boxes, edge_boxes, sparse = _regions(unknown, on_gel, "auto")
    assert boxes == sparse == [] and [e for _, e in edge_boxes] == [edges]
    geo = RayGeometry.from_reference(rays, ref.depth.astype(np.float64))
    got, _ = integrate_on_dome(normals, unknown, geo)
    dent, true_dent = ref.depth - got, ref.depth - points[..., 2]
    assert true_dent[unknown].max() > 1.4  # mm: a real dent, 0.7-1 mm deep at the border
    assert (true_dent[unknown] > 0.5)[_at_border(unknown)[unknown]].any()
    assert dent[unknown].max() == pytest.approx(true_dent[unknown].max(), rel=0.05)
    assert np.abs(dent - true_dent)[unknown].mean() < 0.05 * true_dent.max()
    # the solved pixels beyond the contact keep the dome
    box = edge_boxes[0][0]
    in_box = np.zeros_like(unknown)
    in_box[box] = True
    assert np.abs(dent)[in_box & ~ndimage.binary_dilation(unknown, iterations=2)].max() < 0.02  # mm


def _at_border(mask):
    border = np.zeros_like(mask)
    border[[0, -1], :] = border[:, [0, -1]] = True
    return mask & border


def _solved_in_box(shape, rows, cols):
    """(H, W) bool: the pixels a box (or edge box) over ``rows``, ``cols`` solves: all but its ring, except where
    that ring lies on the image border (there the box has no ring: a natural side)."""
    inner = np.zeros(shape, bool)
    inner[rows, cols] = True
    H, W = shape
    for side, at_edge in ((np.s_[rows.start, :], rows.start == 0), (np.s_[rows.stop - 1, :], rows.stop == H)):
        inner[side] &= at_edge  # the ring off the border is the reference's, fixed
    for side, at_edge in ((np.s_[:, cols.start], cols.start == 0), (np.s_[:, cols.stop - 1], cols.stop == W)):
        inner[side] &= at_edge
    return inner


@pytest.mark.parametrize(("polar", "azimuth"), [(35, 90), (55, 35)])
def test_an_edge_box_solves_the_sparse_paths_equations_on_its_pixels(polar, azimuth):
    # the sparse path's equations at the image border have no pair across it: an edge box must solve exactly
    # them over its pixels (every pixel in it unknown but its ring off the border), up to float32 rounding
    from nlipscalib.core.sensor import SensorDesign
    from nlipscalib.learn.integrate_regions import _regions

    ref, rays, hit, _, normals = _sphere_pressed_into_the_dome(SensorDesign(), polar, azimuth, 7.0, 2.0)
    on_gel = np.isfinite(ref.depth)
    unknown = ndimage.binary_dilation(hit, iterations=3) & on_gel
    geo = RayGeometry.from_reference(rays, ref.depth.astype(np.float64))
    (((rows, cols), edges),) = _regions(unknown, on_gel, "auto")[1]
    inner = _solved_in_box(unknown.shape, rows, cols)
    assert _at_border(inner).sum() > 100
    box, _ = integrate_on_dome(normals, unknown, geo)
    sparse, _ = integrate_on_dome(normals, inner, geo, "sparse")
    np.testing.assert_allclose(box[inner], sparse[inner], atol=5e-4)  # mm; the dent is 2 mm
    # a Dirichlet side at the border (the reference held there) would be a different surface
    assert np.abs(box - ref.depth)[_at_border(inner)].max() > 0.1


def test_the_sparse_path_solves_separate_regions_as_if_each_were_alone():
    # the split into regions rests on this: no equation joins two 4-connected regions
    from nlipscalib.learn.integrate_sparse import _solve_sparse

    _, geo, on_gel, contact, normals = _dome_and_sphere()
    speck = np.zeros_like(contact)
    speck[0:6, 0:6] = True
    both = _solve_sparse(normals, contact | speck, on_gel, geo)
    order = np.flatnonzero(contact | speck)
    in_contact = np.isin(order, np.flatnonzero(contact))
    np.testing.assert_allclose(both[in_contact], _solve_sparse(normals, contact, on_gel, geo), rtol=1e-12)
    np.testing.assert_allclose(both[~in_contact], _solve_sparse(normals, speck, on_gel, geo), rtol=1e-12)


def _cylinder_pressed_into_the_gel(design, radius, depth, along):
    """Exact depth and normals of a cylinder (radius mm, its axis ``along``, camera frame) pressed ``depth`` mm
    into the undeformed gel at its apex: the nearer of the gel and the cylinder along every ray."""
    from nlipscalib.core.dome import dome_surface_point, reference_surface

    rays = design.camera_model().rays
    ref = reference_surface(design)
    apex, inward = dome_surface_point(design.dome, 0, 0)
    axis = np.asarray(along, float) - (np.asarray(along, float) @ inward) * inward
    axis /= np.linalg.norm(axis)
    centre = apex - np.asarray(design.camera.position) + inward * (depth - radius)

    def across(v):  # the part of v across the axis
        return v - (v @ axis)[..., None] * axis

    ray_across, centre_across = across(rays), across(centre[None])[0]
    a, b = (ray_across * ray_across).sum(-1), ray_across @ centre_across
    disc = b * b - a * (centre_across @ centre_across - radius**2)
    ref_range = ref.depth / rays[..., 2]
    with np.errstate(invalid="ignore"):
        near = (b - np.sqrt(disc)) / a
    hit = np.isfinite(ref.depth) & (disc > 0) & (near > 0) & (near < ref_range)
    points = np.where(hit, near, ref_range)[..., None] * rays
    normals = np.where(hit[..., None], across(points - centre) / radius, ref.normals)
    return ref, rays, hit, points, normals


def test_exact_normals_of_a_contact_across_the_image_give_its_depth_in_a_cosine_box():
    # a ridge pressed into the flat pad spans the image's height: natural sides at both image borders, which
    # used to leave the contact to SuperLU (27,000-75,000 px: 0.2-1 s); now a box with a type-II cosine axis
    from nlipscalib.core.sensor import shipped_design
    from nlipscalib.learn.integrate_regions import BOTH_SIDES, _regions

    ref, rays, hit, points, normals = _cylinder_pressed_into_the_gel(shipped_design("flat"), 3.0, 1.0, (0, 1, 0))
    on_gel = np.isfinite(ref.depth)
    unknown = ndimage.binary_dilation(hit, iterations=3) & on_gel
    assert unknown[0].any() and unknown[-1].any()
    boxes, edge_boxes, sparse = _regions(unknown, on_gel, "auto")
    assert boxes == sparse == [] and [e for _, e in edge_boxes] == [(BOTH_SIDES, 0)]
    geo = RayGeometry.from_reference(rays, ref.depth.astype(np.float64))
    got, _ = integrate_on_dome(normals, unknown, geo)
    dent, true_dent = ref.depth - got, ref.depth - points[..., 2]
    assert dent[unknown].max() == pytest.approx(true_dent[unknown].max(), rel=0.01)
    assert np.abs(dent - true_dent)[unknown].mean() < 0.01 * true_dent[unknown].max()


def _band(shape, axis, lo, hi):
    """(H, W) bool: lines lo to hi - 1 across the whole image along ``axis`` (0: rows, a band spanning the width)."""
    band = np.zeros(shape, bool)
    band[(slice(lo, hi), slice(None)) if axis == 0 else (slice(None), slice(lo, hi))] = True
    return band


@pytest.mark.parametrize(
    ("axis", "lo", "hi", "edges"), [(0, 100, 190, (0, 2)), (0, 0, 61, (-1, 2)), (1, 500, 640, (2, 1))]
)
def test_a_box_across_the_image_solves_the_sparse_paths_equations_on_its_pixels(axis, lo, hi, edges):
    # random smooth normals over a band spanning the image (a side at an image border too): the cosine box must
    # solve exactly the sparse path's equations over its pixels (every pixel but its ring off the border)
    from nlipscalib.learn.integrate_regions import _regions

    ref, geo, on_gel, _, _ = _dome_and_sphere()
    rng = np.random.default_rng(lo + hi)
    unknown = _band(on_gel.shape, axis, lo, hi)
    tilt = ndimage.gaussian_filter(rng.normal(size=on_gel.shape + (3,)), (8, 8, 0)) * 20
    normals = ref.normals + np.where(unknown[..., None], tilt, 0)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    (((rows, cols), got_edges),) = _regions(unknown, on_gel, "auto")[1]
    assert got_edges == edges
    inner = _solved_in_box(unknown.shape, rows, cols)
    box, _ = integrate_on_dome(normals, unknown, geo)
    sparse, _ = integrate_on_dome(normals, inner, geo, "sparse")
    assert np.abs(sparse - ref.depth)[inner].max() > 0.1  # mm: a surface unlike the dome
    np.testing.assert_allclose(box[inner], sparse[inner], atol=5e-4)  # mm: float32 against float64


def test_a_band_across_both_axes_keeps_the_sparse_path():
    # a cross spanning the width and the height: its box (the image) has no ring, no fixed pixel
    from nlipscalib.learn.integrate_regions import _crop_edges, _regions
    from nlipscalib.learn.integrate_rim import _rim_box_anchor

    _, _, on_gel, _, _ = _dome_and_sphere()
    cross = _band(on_gel.shape, 0, 200, 210) | _band(on_gel.shape, 1, 300, 310)
    boxes, edge_boxes, sparse = _regions(cross, on_gel, "auto")
    assert boxes == edge_boxes == [] and len(sparse) == 1
    # nor an anchored box: it would anchor the unchanged pixels that the sparse path holds at the reference
    assert _rim_box_anchor(cross, on_gel, sparse[0], _crop_edges(cross, sparse[0])) is None


def _flat_pad():
    from nlipscalib.core.sensor import shipped_design

    design = shipped_design("flat")
    ref, rays, _, _, _ = _sphere_pressed_into_the_dome(design, 0, 0, 4.0, 1.0)
    return design, ref, RayGeometry.from_reference(rays, ref.depth.astype(np.float64)), np.isfinite(ref.depth)


def _disc_of_smooth_normals(ref, on_gel, rng, row, col, radius):
    """The gel pixels of a disc around (row, col) as changed, and the reference normals tilted there by random smooth
    normals of ``rng`` (unit; NaN off the gel): a rim box's test case."""
    rr, cc = np.mgrid[: on_gel.shape[0], : on_gel.shape[1]]
    unknown = ((rr - row) ** 2 + (cc - col) ** 2 < radius**2) & on_gel
    tilt = ndimage.gaussian_filter(rng.normal(size=on_gel.shape + (3,)), (6, 6, 0)) * 10
    normals = ref.normals + np.where(unknown[..., None], tilt, 0)
    with np.errstate(invalid="ignore"):  # NaN off the gel
        return unknown, normals / np.linalg.norm(normals, axis=-1, keepdims=True)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_rim_box_solves_the_sparse_paths_equations_on_its_gel_pixels(seed):
    # a blob of random smooth normals near the flat pad's rim: its box holds off-gel pixels, where the sparse
    # path has no pixel pair (a natural side along the gel's outline); the rim box must solve exactly that
    # equation over its interior's gel pixels, up to rounding
    from nlipscalib.learn.integrate_regions import _regions
    from nlipscalib.learn.integrate_rim import _faster_rim_box, _interior_mask, _rim_box_applies, _rim_rows

    _, ref, geo, on_gel = _flat_pad()
    rng = np.random.default_rng(seed)
    row = int(rng.integers(60, 420))
    side = np.flatnonzero(on_gel[row])[[0, -1][seed % 2]]
    col = side + int(rng.integers(-5, 15)) * (1 if seed % 2 == 0 else -1)
    radius = int(rng.integers(15, 45))
    unknown, normals = _disc_of_smooth_normals(ref, on_gel, rng, row, col, radius)
    boxes, edge_boxes, (crop,) = _regions(unknown, on_gel, "auto")
    assert boxes == edge_boxes == [] and _rim_box_applies(unknown, on_gel, crop)
    crop = _faster_rim_box(unknown, on_gel, crop, [])  # the box integrate_on_dome solves
    assert _rim_rows(on_gel[crop])[1].sum() > 10  # rim pixels in the box: the capacitance correction is at work
    inner = np.zeros_like(unknown)
    inner[crop] = _interior_mask(on_gel[crop])
    got, _ = integrate_on_dome(normals, unknown, geo)
    sparse, _ = integrate_on_dome(normals, inner, geo, "sparse")
    assert np.abs(sparse - ref.depth)[inner].max() > 0.05  # mm: a surface unlike the pad
    np.testing.assert_allclose(got[inner], sparse[inner], atol=2e-5)  # mm: float32 points of float64 solves
    outside = on_gel & ~inner
    np.testing.assert_array_equal(got[outside], ref.depth[outside])


@pytest.mark.parametrize(("polar", "azimuth", "radius"), [(48, 0, 5.0), (45, 20, 4.0)])
def test_exact_normals_of_a_sphere_at_the_pads_rim_give_its_depth_in_a_rim_box(polar, azimuth, radius):
    # 13,000-15,000 px at 640x480: SuperLU took 106-150 ms a frame (s25-wide); the rim box, 12-22 ms
    from nlipscalib.learn.integrate_regions import _regions
    from nlipscalib.learn.integrate_rim import _rim_box_applies

    design, ref, geo, on_gel = _flat_pad()
    _, _, hit, points, normals = _sphere_pressed_into_the_dome(design, polar, azimuth, radius, 1.0)
    unknown = ndimage.binary_dilation(hit, iterations=3) & on_gel
    (crop,) = _regions(unknown, on_gel, "auto")[2]
    assert _rim_box_applies(unknown, on_gel, crop) and not on_gel[crop].all()
    got, _ = integrate_on_dome(normals, unknown, geo)
    dent, true_dent = ref.depth - got, ref.depth - points[..., 2]
    assert dent[unknown].max() == pytest.approx(true_dent[unknown].max(), rel=0.02)
    assert np.abs(dent - true_dent)[unknown].mean() < 0.02 * true_dent[unknown].max()


@pytest.mark.parametrize(
    ("m", "n", "edges", "anchor"),
    [(7, 11, (0, 0), 0.0), (12, 5, (0, 0), 0.0), (7, 11, (-1, 2), 0.0), (9, 6, (1, 0), 0.0), (8, 10, (2, 2), 1e-4)],
)
def test_the_box_greens_function_is_the_inverse_of_its_laplacian(m, n, edges, anchor):
    # per axis: fixed beyond both ends (0), natural at the image border (-1: before index 0, +1: after the last)
    # or at both (2); with both axes natural only the anchor makes the matrix invertible
    from scipy.sparse import diags, identity, kron

    from nlipscalib.learn.integrate_green import _box_green, _box_solve

    def path(k, edge):
        diagonal = 2 * np.ones(k)
        diagonal[[0] if edge == -1 else [-1] if edge == 1 else [0, -1] if edge == 2 else []] = 1  # no pair beyond
        return diags([-np.ones(k - 1), diagonal, -np.ones(k - 1)], [-1, 0, 1])

    matrix = kron(path(m, edges[0]), identity(n)) + kron(identity(m), path(n, edges[1])) + anchor * identity(m * n)
    inverse = np.linalg.inv(matrix.toarray())
    rng = np.random.default_rng(m * n)
    p, q = rng.integers(0, m * n, 30), rng.integers(0, m * n, 9)
    # few distinct rows of p (a rim along the rows): _box_green sums the other axis's modes; both must agree
    for pick in (p, p % n + n * (p // n % 2)):
        got = _box_green(*np.divmod(pick, n), *np.divmod(q, n), m, n, edges, anchor)
        np.testing.assert_allclose(got, inverse[np.ix_(pick, q)], rtol=1e-10, atol=1e-12)
    f = rng.normal(size=(m, n))  # and the transform solve is the same matrix's
    np.testing.assert_allclose(_box_solve(f, edges, anchor).ravel(), inverse @ f.ravel(), rtol=1e-9, atol=1e-9)


def test_a_rim_box_whose_gel_touches_no_fixed_pixel_keeps_the_sparse_path():
    # a gel island in the box whose every neighbour is off the gel: nothing fixes its level but the anchor
    from nlipscalib.learn.integrate_rim import _rim_box_applies

    on_gel = np.ones((40, 40), bool)
    on_gel[10:30, 10:30] = False
    on_gel[15:25, 15:25] = True  # the island
    unknown = np.zeros_like(on_gel)
    unknown[17:23, 17:23] = True
    for box in ((slice(14, 26), slice(14, 26)), (slice(5, 35), slice(5, 35))):
        assert not _rim_box_applies(unknown, on_gel, box)
    on_gel[20, 10:15] = True  # a bridge to the gel around: its level is fixed there
    for box in ((slice(14, 26), slice(14, 26)), (slice(5, 35), slice(5, 35))):
        assert _rim_box_applies(unknown, on_gel, box)
    assert not _rim_box_applies(unknown, on_gel, (slice(17, 26), slice(14, 26)))  # a changed pixel on its ring


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_rim_box_at_the_image_border_solves_the_sparse_paths_equations_on_its_gel_pixels(seed):
    # a blob of random smooth normals in a corner of the flat pad: its box holds off-gel pixels and reaches the
    # top or bottom image border (a natural side there, mirrored as an edge box's), 0.2-0.3 s of SuperLU before
    from nlipscalib.learn.integrate_regions import _crop_edges, _regions
    from nlipscalib.learn.integrate_rim import _faster_rim_box, _interior_mask, _rim_box_anchor

    _, ref, geo, on_gel = _flat_pad()
    rng = np.random.default_rng(seed)
    row = [int(rng.integers(0, 8)), int(rng.integers(472, 480))][seed // 2]
    side = np.flatnonzero(on_gel[row])[[0, -1][seed % 2]]
    col = side + int(rng.integers(-5, 15)) * (1 if seed % 2 == 0 else -1)
    radius = int(rng.integers(20, 45))
    unknown, normals = _disc_of_smooth_normals(ref, on_gel, rng, row, col, radius)
    (crop,) = _regions(unknown, on_gel, "auto")[2]
    edges = _crop_edges(unknown, crop)
    assert edges == ([-1, 1][seed // 2], 0) and _rim_box_anchor(unknown, on_gel, crop, edges) == 0
    crop = _faster_rim_box(unknown, on_gel, crop, [], edges)  # the box integrate_on_dome solves
    inner = np.zeros_like(unknown)
    inner[crop] = _interior_mask(on_gel[crop], edges)
    assert not on_gel[crop].all() and _at_border(inner).sum() > 10
    got, _ = integrate_on_dome(normals, unknown, geo)
    sparse, _ = integrate_on_dome(normals, inner, geo, "sparse")
    assert np.abs(sparse - ref.depth)[inner].max() > 0.05  # mm: a surface unlike the pad
    np.testing.assert_allclose(got[inner], sparse[inner], atol=2e-5)  # mm: float32 points of float64 solves
    outside = on_gel & ~inner
    np.testing.assert_array_equal(got[outside], ref.depth[outside])


def test_a_frame_changed_on_the_whole_gel_solves_the_sparse_paths_anchored_equation():
    # every pixel changed: a box across both axes, natural on all four sides; its one zero eigenvalue (the level)
    # is the anchor's, which the sparse path puts on every pixel here -- the same equation (4 s of SuperLU before)
    from nlipscalib.learn.integrate_regions import BOTH_SIDES, _crop_edges, _regions
    from nlipscalib.learn.integrate_rim import _rim_box_anchor
    from nlipscalib.learn.integrate_sparse import ANCHOR_WEIGHT

    ref, geo, on_gel, _, _ = _dome_and_sphere()
    rng = np.random.default_rng(5)
    tilt = ndimage.gaussian_filter(rng.normal(size=on_gel.shape + (3,)), (8, 8, 0)) * 5
    normals = ref.normals + tilt
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    (crop,) = _regions(on_gel, on_gel, "auto")[2]
    assert _crop_edges(on_gel, crop) == (BOTH_SIDES, BOTH_SIDES)
    assert _rim_box_anchor(on_gel, on_gel, crop, (BOTH_SIDES, BOTH_SIDES)) == ANCHOR_WEIGHT
    got, _ = integrate_on_dome(normals, on_gel, geo)
    sparse, _ = integrate_on_dome(normals, on_gel, geo, "sparse")
    assert np.abs(sparse - ref.depth).max() > 0.05  # mm
    np.testing.assert_allclose(got, sparse, atol=2e-5)


def test_a_changed_gel_island_touching_no_fixed_pixel_is_solved_with_the_anchor_in_a_rim_box():
    # the whole of a gel island changed: no fixed pixel, the sparse path anchors each of its pixels; so does the
    # rim box. An island with unchanged pixels would be another equation: it keeps the sparse path
    from nlipscalib.learn.integrate_regions import _regions
    from nlipscalib.learn.integrate_rim import _rim_box_anchor
    from nlipscalib.learn.integrate_sparse import ANCHOR_WEIGHT

    ref, _, _, _, normals = _dome_and_sphere()
    depth = ref.depth.astype(np.float64).copy()
    depth[190:260, 290:370] = np.nan
    depth[200:250, 300:360] = ref.depth[200:250, 300:360]  # the island, off the gel all round
    geo = RayGeometry.from_reference(_dome_rays(), depth)
    on_gel = np.isfinite(depth)
    island = np.zeros_like(on_gel)
    island[200:250, 300:360] = True
    (crop,) = _regions(island, on_gel, "auto")[2]
    assert _rim_box_anchor(island, on_gel, crop) == ANCHOR_WEIGHT
    got, _ = integrate_on_dome(normals, island, geo)
    sparse, _ = integrate_on_dome(normals, island, geo, "sparse")
    assert np.abs(sparse - depth)[island].max() > 0.05  # mm: the sphere's dent
    np.testing.assert_allclose(got[island], sparse[island], atol=2e-5)
    part = island.copy()
    part[220:225, 320:330] = False  # unchanged pixels inside: they fix the level on the sparse path
    assert _rim_box_anchor(part, on_gel, _regions(part, on_gel, "auto")[2][0]) is None


def _dome_rays():
    from nlipscalib.core.sensor import SensorDesign

    return SensorDesign().camera_model().rays


def _small(design):
    """``design`` at 160x120: a CI-sized frame."""
    import dataclasses

    return dataclasses.replace(design, camera=dataclasses.replace(design.camera, width=160, height=120))


def _amg_and_superlu(monkeypatch, normals, unknown, geo):
    """Depth of ``integrate_on_dome`` with the sparse path's regions solved by AMG (the size threshold forced to 0),
    then by SuperLU (no region large enough), and whether AMG ran (a hierarchy was cached)."""
    from nlipscalib.learn import integrate_sparse

    monkeypatch.setattr(integrate_sparse, "_amg_cache", integrate_sparse.collections.OrderedDict())
    monkeypatch.setattr(integrate_sparse, "SPARSE_AMG_MIN_UNKNOWNS", 0)
    amg, _ = integrate_on_dome(normals, unknown, geo)
    ran = len(integrate_sparse._amg_cache) == 1
    monkeypatch.setattr(integrate_sparse, "SPARSE_AMG_MIN_UNKNOWNS", np.inf)
    superlu, _ = integrate_on_dome(normals, unknown, geo)
    return amg, superlu, ran


def _tilted(ref, changed, seed, sigma=2):
    """The reference normals tilted by random smooth normals where ``changed`` (unit; NaN off the gel)."""
    tilt = ndimage.gaussian_filter(np.random.default_rng(seed).normal(size=changed.shape + (3,)), (sigma, sigma, 0))
    normals = ref.normals + np.where(changed[..., None], tilt * 10, 0)
    with np.errstate(invalid="ignore"):
        return normals / np.linalg.norm(normals, axis=-1, keepdims=True)


def test_amg_solves_a_cross_over_both_axes_as_superlu_does(monkeypatch):
    # a cross of bands over the default dome at 160x120: the sparse path (no box applies); AMG-preconditioned CG
    # to INTEGRATION_AMG_RTOL must give SuperLU's depth within the integration parity tolerance
    from nlipscalib.core.sensor import SensorDesign
    from nlipscalib.core.tolerances import TORCH_INTEGRATION_PARITY_MM

    ref, rays, _, _, _ = _sphere_pressed_into_the_dome(_small(SensorDesign()), 0, 0, 4.0, 1.0)
    geo = RayGeometry.from_reference(rays, ref.depth.astype(np.float64))
    cross = _band(ref.depth.shape, 0, 50, 65) | _band(ref.depth.shape, 1, 75, 90)
    amg, superlu, ran = _amg_and_superlu(monkeypatch, _tilted(ref, cross, 3), cross, geo)
    assert ran
    assert np.abs(superlu - ref.depth)[cross].max() > 0.1  # mm: a surface unlike the dome
    np.testing.assert_allclose(amg, superlu, atol=TORCH_INTEGRATION_PARITY_MM)


def test_amg_solves_the_flat_pads_whole_gel_changed_as_superlu_does_and_reuses_its_hierarchy(monkeypatch):
    # every gel pixel of the flat pad changed (a frame whose lighting drifted): no fixed pixel, the anchor holds the
    # level. The hierarchy depends on the mask alone: a second frame with other normals reuses it and still matches
    from nlipscalib.core.sensor import shipped_design
    from nlipscalib.core.tolerances import TORCH_INTEGRATION_PARITY_MM
    from nlipscalib.learn import integrate_rim, integrate_sparse

    ref, rays, _, _, _ = _sphere_pressed_into_the_dome(_small(shipped_design("flat")), 0, 0, 4.0, 1.0)
    geo = RayGeometry.from_reference(rays, ref.depth.astype(np.float64))
    on_gel = np.isfinite(ref.depth)
    assert not on_gel.all()  # the pad does not fill the image: its outline is a natural side
    # at 640x480 its rim (992 pixels) is too long for the rim box's Green's sum; at 160x120 it is not: say so
    monkeypatch.setattr(integrate_rim, "MAX_RIM_GREEN_VALUES", 0)
    for seed in (4, 5):
        amg, superlu, ran = _amg_and_superlu(monkeypatch, _tilted(ref, on_gel, seed, sigma=6), on_gel, geo)
        assert ran
        assert np.nanmax(np.abs(superlu - ref.depth)) > 0.05  # mm
        np.testing.assert_allclose(amg, superlu, atol=TORCH_INTEGRATION_PARITY_MM)
    monkeypatch.setattr(integrate_sparse, "_amg_cache", cached := integrate_sparse.collections.OrderedDict())
    monkeypatch.setattr(integrate_sparse, "SPARSE_AMG_MIN_UNKNOWNS", 0)
    first, _ = integrate_on_dome(_tilted(ref, on_gel, 4, sigma=6), on_gel, geo)
    (hierarchy,) = cached.values()
    second, _ = integrate_on_dome(_tilted(ref, on_gel, 5, sigma=6), on_gel, geo)
    assert list(cached.values()) == [hierarchy]  # reused, not rebuilt
    monkeypatch.setattr(integrate_sparse, "SPARSE_AMG_MIN_UNKNOWNS", np.inf)
    want, _ = integrate_on_dome(_tilted(ref, on_gel, 5, sigma=6), on_gel, geo)
    assert np.nanmax(np.abs(first - second)) > 0.05  # mm: the two frames differ
    np.testing.assert_allclose(second, want, atol=TORCH_INTEGRATION_PARITY_MM)


def test_amg_hierarchies_shared_by_threads_give_the_single_thread_depths(monkeypatch):
    # a stream may integrate frames on several threads at once: the hierarchy cache (two kept) is read, filled and
    # trimmed by all of them, and each solve limits BLAS to one thread while it runs; two masks, four calls each at
    # once, must give the depths of one thread (the blocks on several threads share the process's limit:
    # core.blas.blas_threads)
    from concurrent.futures import ThreadPoolExecutor

    from nlipscalib.core.sensor import SensorDesign
    from nlipscalib.learn import integrate_sparse

    ref, rays, _, _, _ = _sphere_pressed_into_the_dome(_small(SensorDesign()), 0, 0, 4.0, 1.0)
    geo = RayGeometry.from_reference(rays, ref.depth.astype(np.float64))
    masks = (
        _band(ref.depth.shape, 0, 50, 65) | _band(ref.depth.shape, 1, 75, 90),
        _band(ref.depth.shape, 0, 30, 50) | _band(ref.depth.shape, 1, 40, 60),
    )
    frames = [(_tilted(ref, mask, seed), mask) for seed, mask in enumerate(masks)]
    monkeypatch.setattr(integrate_sparse, "SPARSE_AMG_MIN_UNKNOWNS", 0)
    monkeypatch.setattr(integrate_sparse, "_amg_cache", cache := integrate_sparse.collections.OrderedDict())
    alone = [integrate_on_dome(normals, mask, geo)[0] for normals, mask in frames]
    assert len(cache) == 2 and np.nanmax(np.abs(alone[0] - alone[1])) > 0.1  # mm: two shapes, two surfaces
    for _ in range(3):
        cache.clear()
        with ThreadPoolExecutor(8) as pool:
            depths = list(pool.map(lambda i: integrate_on_dome(*frames[i % 2], geo)[0], range(8)))
        for i, depth in enumerate(depths):
            np.testing.assert_array_equal(depth, alone[i % 2])
        assert len(cache) == 2


@pytest.mark.parametrize("method", ["auto", "box", "sparse"])
def test_normals_missing_around_the_pixels_to_solve_are_one_clear_error(method):
    """A Reconstruction's normals (NaN outside its reconstructed pixels) integrated as they are came back as a depth of
    NaN on every solved pixel, without a word (the docstring asked for normals finite "where unknown" only); the
    reference's normals filled in there give the depth. An `unknown` of numbers failed inside NumPy."""
    from nlipscalib.core.errors import ShapeError

    ref, geo, on_gel, contact, normals = _dome_and_sphere()
    solved = np.where(contact[..., None], normals, np.nan)
    with pytest.raises(ShapeError, match="normals are not finite around the pixels to solve"):
        integrate_on_dome(solved, contact, geo, method)
    filled, _ = integrate_on_dome(np.where(contact[..., None], normals, ref.normals), contact, geo, method)
    assert np.isfinite(filled[contact]).all()
    with pytest.raises(ShapeError, match="unknown must be an \\(H, W\\) bool array, got float64"):
        integrate_on_dome(normals, contact.astype(float), geo, method)
