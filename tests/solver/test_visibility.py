"""The interreflection gather's visibility test (radiosity.Occluders, radiosity._hidden): known answers on a
concave dome (nothing hidden: the same bits as without the test) and on a valley with a ridge (the ridge hides one
slope's low part from the other's)."""

import numpy as np

from nlipscalib.solver import radiosity

from .test_radiosity import _dome, _exact, _grid

RIDGE_TOP = 97.0
"""mm from the camera: the ridge's flat top, 2.5-3 mm nearer the camera than the valley floor beside it."""


def _valley(ridge: bool = True) -> dict:
    """A patch grid of a valley seen from the camera 100 mm away (x right, z forward): two planes z = 100 - |x| / 2
    (the floor at x = 0 the farthest) facing each other across it, and, with ``ridge``, a flat-topped ridge at
    |x| <= 1 whose top stands at z = RIDGE_TOP; rows along y, columns along x (0.5 mm apart)."""
    x, y = np.meshgrid(np.linspace(-10, 10, 41), np.linspace(-3, 3, 13))
    z = 100.0 - np.abs(x) / 2
    top = ridge & (np.abs(x) <= 1.0)
    z = np.where(top, RIDGE_TOP, z)
    normals = np.stack([0.5 * np.sign(-x), np.zeros_like(x), -np.ones_like(x)], -1)  # toward the camera, the valley
    normals[top] = (0.0, 0.0, -1.0)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    return {"x": x, "points": np.stack([x, y, z], -1), "normals": normals, "area": np.full(x.shape, 0.25)}


def _segment_depth_over_ridge(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(m, k) -- the larger z of the segments from p (m, 3) to q (k, 3) where they cross x = -1 and x = 1 (the
    ridge's edges): the segment passes behind the ridge's top where it exceeds RIDGE_TOP (the camera's rays are
    within 6 deg of z here)."""
    xp, zp, xq, zq = p[:, None, 0], p[:, None, 2], q[None, :, 0], q[None, :, 2]
    at = [zp + (edge - xp) / (xq - xp) * (zq - zp) for edge in (-1.0, 1.0)]
    return np.maximum(*at)


def test_a_domes_inside_hides_nothing():
    """The inside of a sphere seen from near its centre (the undeformed dome): no patch stands on the camera's side
    of its neighbours' segment, so nothing is tested and the gathers keep their bits; a flat surface alike."""
    s = _dome()
    assert radiosity.Occluders.of(s["points"], s["area"]).box is None
    everywhere = np.ones(s["area"].shape, bool)
    np.testing.assert_array_equal(_exact(s, everywhere), _exact(s, everywhere, visibility=False))
    np.testing.assert_array_equal(_grid(s, everywhere), _grid(s, everywhere, visibility=False))
    flat = _valley(ridge=False)
    flat["points"][..., 2] = 100.0
    assert radiosity.Occluders.of(flat["points"], flat["area"]).box is None


def test_a_ridge_hides_the_far_slopes_low_part():
    """Left slope to right slope across the ridge: a pair is hidden exactly where its segment passes behind the
    ridge's top (farther from the camera), away from the edge of that condition by the tolerance."""
    v = _valley()
    occluders = radiosity.Occluders.of(v["points"], v["area"])
    assert occluders.box is not None
    left, right = v["x"] < -1.4, v["x"] > 1.4
    emitters = radiosity._Emitters.of(
        v["points"][right], v["normals"][right], v["area"][right], radiosity.patch_cells(right)
    )
    hidden = radiosity._hidden(v["points"][left], radiosity.patch_cells(left), emitters, occluders)
    depth = _segment_depth_over_ridge(v["points"][left], v["points"][right])
    margin = 0.3  # mm: the samples read the ridge at whole patches
    behind, clear = depth > RIDGE_TOP + margin, depth < RIDGE_TOP - margin
    assert behind.any() and clear.any()
    assert hidden[behind].all()
    assert not hidden[clear].any()


def test_a_ridge_leaves_the_low_left_slope_no_light_of_the_right_slope():
    """Light only on the right slope: a receiver low on the left slope (every segment to the right slope passes
    behind the ridge) gathers none of it with the visibility test, and some without; a receiver high on the left
    slope still sees the right slope's high part over the ridge."""
    v = _valley()
    light = np.where((v["x"] > 1.4)[..., None], np.array([1.0, 0.5, 0.25]), 0.0)[None]  # (1, h, w, 3)
    low = (v["x"] >= -3.5) & (v["x"] <= -1.5)
    high = v["x"] <= -8.0
    for receivers, lit in ((low, False), (high, True)):
        seen = _grid({**v, "radiance": light}, receivers, ratio=0.0)
        blind = _grid({**v, "radiance": light}, receivers, ratio=0.0, visibility=False)
        assert (blind > 0).all()
        assert (seen > 0).all() if lit else (seen == 0).all()
        assert (seen <= blind).all()


def test_grouped_gather_with_visibility_stays_near_the_exact_one():
    """The dome's dent 1 mm deep hides up to an eighth of a patch's light (2.5 % on average); the grouped gather
    tests a far cluster at its centroid, seen or hidden whole, and errs by up to 4.5 % at the edge of the hidden
    part (0.3 % in the median) against the exact gather's pair by pair."""
    s = _dome(dent=1.0)
    everywhere = np.ones(s["area"].shape, bool)
    exact = _exact(s, everywhere)
    hidden_share = 1 - exact.sum(axis=(0, 2)) / _exact(s, everywhere, visibility=False).sum(axis=(0, 2))
    assert hidden_share.max() > 0.05  # the premise: the dent hides light
    rel = np.abs(_grid(s, everywhere) - exact) / np.abs(exact)
    assert rel.max() < 0.06
    assert np.median(rel) < 5e-3


def test_a_patch_off_the_grid_is_tested_on_the_grid_only():
    """An emitter beyond the grid (the view) is tested along the part of its segment on the grid: hidden where that
    part passes behind the ridge, seen where it runs away from it."""
    v = _valley()
    occluders = radiosity.Occluders.of(v["points"], v["area"])
    beyond = np.array([[6.0, -2500.0], [6.0, 2500.0]], np.float32)  # far left and far right of the grid
    far = radiosity._Emitters.of(
        np.array([[-60.0, 0.0, 80.0], [60.0, 0.0, 80.0]]),
        np.array([[0.6, 0.0, -0.8], [-0.6, 0.0, -0.8]]),
        np.ones(2),
        beyond,
    )
    receiver = np.array([[-2.0, 0.0, 99.0]])  # low on the left slope, at row 6, column 16: the ridge to its right
    hidden = radiosity._hidden(receiver, np.array([[6.0, 16.0]], np.float32), far, occluders)
    assert hidden.tolist() == [[False, True]]


def test_the_pairs_picked_by_among_get_the_whole_tests_answers():
    """``among`` picks the pairs to test before the box's clipping: they come out as in the test of every pair and the
    others seen, with the box inside the grid (the dent: samples not clipped to it) and past its edge (the ridge runs
    the grid's length: samples clipped)."""
    dent = _dome(dent=1.0)
    ridge = _valley()
    rng = np.random.default_rng(7)
    for s, inside in ((dent, True), (ridge, False)):
        occluders = radiosity.Occluders.of(s["points"], s["area"])
        h2, w2 = occluders.points.shape[:2]
        box = occluders.box
        assert (box[0] >= 0 and box[1] <= h2 - 1 and box[2] >= 0 and box[3] <= w2 - 1) == inside
        everywhere = np.ones(s["area"].shape, bool)
        cells = radiosity.patch_cells(everywhere)
        emitters = radiosity._Emitters.of(
            s["points"].reshape(-1, 3), s["normals"].reshape(-1, 3), s["area"].ravel(), cells
        )
        receivers = rng.choice(len(cells), 60, replace=False)
        pr = s["points"].reshape(-1, 3)[receivers]
        whole = radiosity._hidden(pr, cells[receivers], emitters, occluders)
        assert whole.mean() > 0.01  # the premise: the surface hides pairs
        among = rng.random(whole.shape) < 0.5
        picked = radiosity._hidden(pr, cells[receivers], emitters, occluders, among=among)
        np.testing.assert_array_equal(picked, whole & among)


def test_a_pair_left_out_by_the_outcodes_misses_the_box():
    """The ends' outcodes leave out a pair only where the box's clipping finds its line missing the box, also for
    ends a hair beyond a side (within the margin: kept) and for ends off the grid."""
    box = (5, 20, 8, 30)
    rng = np.random.default_rng(11)
    near_sides = np.array(box, np.float32) - 1 + rng.choice([-0.02, -0.005, 0.005, 0.02], 4)  # unbordered
    cells = np.concatenate(
        [
            rng.uniform(-40, 70, (400, 2)).astype(np.float32),
            np.stack([np.repeat(near_sides[:2], 20), rng.uniform(0, 40, 40)], 1).astype(np.float32),
            np.stack([rng.uniform(0, 30, 40), np.repeat(near_sides[2:], 20)], 1).astype(np.float32),
        ]
    )
    codes = radiosity._outcode(cells, box)
    left_out = np.bitwise_and.outer(codes, codes) != 0
    assert 0.2 < left_out.mean() < 0.8  # the premise: both kinds of pairs
    r0, c0 = cells[:, :1] + np.float32(1), cells[:, 1:] + np.float32(1)
    dr = cells[None, :, 0] + np.float32(1) - r0
    dc = cells[None, :, 1] + np.float32(1) - c0
    t0, t1 = radiosity._clip(r0, c0, dr, dc, box)
    assert not (left_out & (t1 > t0)).any()
    assert (~left_out & (t1 <= t0)).any()  # the outcodes leave some misses to the clipping
