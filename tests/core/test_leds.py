import numpy as np
import pytest

from nlipscalib.core.errors import ConfigError, ShapeError
from nlipscalib.core.leds import Led, led_arrays, led_falloff, led_shading, tricolor_colors, tricolor_groups


def test_shading_known_answer_directly_below_led():
    # LED 10 mm in front of a plane facing it, pointing straight at it: (n_s.d)^mu = 1, cos = 1
    led = Led(position=(0, 0, 0), direction=(0, 0, 1), mu=3.0, intensity=(2.0, 1.0, 0.5))
    s = led_shading(np.array([[0.0, 0, 10]]), np.array([[0.0, 0, -1]]), [led])
    np.testing.assert_allclose(s[0, 0], np.array([2.0, 1.0, 0.5]) / 100.0)


def test_shading_anisotropy_and_lambert_cosine():
    led = Led(position=(0, 0, 0), direction=(0, 0, 1), mu=2.0)
    x = np.array([[10.0, 0, 10]])  # 45 deg off the LED axis
    n = np.array([[0.0, 0, -1]])  # plane normal facing the LED side
    r2 = 200.0
    expected = np.cos(np.pi / 4) ** 2 * np.cos(np.pi / 4) / r2
    np.testing.assert_allclose(led_shading(x, n, [led])[0, 0, 0], expected, rtol=1e-12)


def test_shading_is_zero_in_attached_shadow():
    led = Led(position=(0, 0, 0))
    s = led_shading(np.array([[0.0, 0, 10]]), np.array([[0.0, 0, 1]]), [led])
    assert np.all(s == 0)


def test_the_falloff_times_each_leds_intensity_is_the_shading_bit_for_bit():
    """``led_falloff`` is ``led_shading`` without Psi: its product with each LED's per-channel intensity gives the
    shading's very bits (the same products), for LEDs of other exponents (mu 0, 1 and not integer), points in
    shadow and a (h, w) grid of points."""
    rng = np.random.default_rng(4)
    leds = [
        Led(position=(5, 0, 0), direction=(-1, 0, 1), mu=0.0, intensity=(1.0, 0.7, 0.2)),
        Led(position=(0, 5, 0), direction=(0, -1, 1), mu=1.0, intensity=(0.3, 1.1, 0.9)),
        Led(position=(-4, -4, 1), direction=(1, 1, 2), mu=2.7, intensity=(2.0, 1.0, 0.5)),
    ]
    points = rng.normal(size=(9, 7, 3)) * 3 + [0, 0, 12]
    normals = rng.normal(size=(9, 7, 3))
    normals[..., 2] = -np.abs(normals[..., 2])
    normals[0, :, 2] *= -1  # a row facing away: in attached shadow
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    shading = led_shading(points, normals, leds)
    falloff = led_falloff(points, normals, leds)
    assert falloff.shape == (3, 9, 7)
    assert np.array_equal(falloff[..., None] * led_arrays(leds)[3][:, None, None], shading)
    assert np.all(falloff[:, 0] == 0) and np.all(falloff[:, 1:] >= 0) and falloff[:, 1:].any()


def test_tricolor_groups_nlipstac_and_general():
    g = tricolor_groups(12)
    assert list(g) == [0] * 4 + [1] * 4 + [2] * 4
    assert sorted(set(tricolor_groups(7))) == [0, 1, 2]
    with pytest.raises(ConfigError):
        tricolor_groups(2)


def test_led_validation():
    with pytest.raises(ConfigError, match="direction"):
        Led(position=(0, 0, 0), direction=(0, 0, 0))
    with pytest.raises(ConfigError, match="position"):
        Led(position=(0, 0))
    d = Led(position=(1, 2, 3), direction=(0, 0, 2)).to_dict()
    assert Led.from_dict(d).direction == (0.0, 0.0, 1.0)


def test_disk_shading_matches_the_closed_form_on_the_axis():
    # a Lambertian (mu = 1) disk of radius R seen on its axis from distance h by a facing surface
    # gives Psi / (h^2 + R^2) (the disk's form factor); the point LED gives Psi / h^2
    from nlipscalib.core.leds import disk_shading

    led = Led((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 1.0, (1.0, 2.0, 3.0))
    for h, tol in ((10.0, 1e-5), (6.0, 2e-4)):
        s = disk_shading(np.array([[0.0, 0.0, h]]), np.array([[0.0, 0.0, -1.0]]), [led], 1.8)
        np.testing.assert_allclose(s[0, 0], np.array([1.0, 2.0, 3.0]) / (h * h + 1.8**2), rtol=tol)
        assert s[0, 0, 0] < 1 / h**2  # the disk's edge is farther and more oblique than its centre


def test_disk_shading_of_radius_zero_is_the_point_model_and_off_axis_is_a_disk_mean():
    from nlipscalib.core.leds import disk_shading

    rng = np.random.default_rng(1)
    pts = rng.normal(size=(50, 3)) * 3 + [0.0, 0.0, 12.0]
    nrm = -pts / np.linalg.norm(pts, axis=1, keepdims=True)
    leds = [Led((5.0, 1.0, 2.0), (-0.3, 0.0, 0.954), 1.7, (1.0, 1.0, 1.0)), Led((-4.0, 3.0, 2.5), (0.2, -0.2, 0.96))]
    np.testing.assert_array_equal(disk_shading(pts, nrm, leds, 0.0), led_shading(pts, nrm, leds))
    # against a fine polar grid of point LEDs over the disk (midpoint rule, area weights)
    R = 1.8
    d = np.asarray(leds[0].direction) / np.linalg.norm(leds[0].direction)
    u = np.cross(d, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    r = (np.arange(40) + 0.5) / 40 * R
    t = (np.arange(64) + 0.5) / 64 * 2 * np.pi
    rr, tt = np.meshgrid(r, t, indexing="ij")
    w = (rr / rr.sum()).ravel()
    grid = [
        Led(tuple(np.add(leds[0].position, a * np.cos(b) * u + a * np.sin(b) * v)), tuple(d), 1.7)
        for a, b in zip(rr.ravel(), tt.ravel())
    ]
    fine = np.tensordot(w, led_shading(pts, nrm, grid), axes=1)
    np.testing.assert_allclose(disk_shading(pts, nrm, leds[:1], R)[0], fine, rtol=2e-3)
    with pytest.raises(ConfigError):
        disk_shading(pts, nrm, leds, -1.0)


def test_shading_in_cache_sized_blocks_equals_each_point_alone(monkeypatch):
    # the blocked evaluation (led_shading's speed) must give every point the numbers of a lone evaluation,
    # across block boundaries, for any leading shape
    import nlipscalib.core.leds as leds_module

    rng = np.random.default_rng(3)
    points = rng.uniform(-5, 5, (7, 5, 3)) + np.array([0.0, 0.0, 14.0])
    normals = rng.normal(size=(7, 5, 3)) - np.array([0.0, 0.0, 2.0])
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    leds = [Led((9 * np.cos(a), 9 * np.sin(a), 3.0), (0.0, 0.3, 1.0), 1.5, (1.0, 0.9, 0.8)) for a in (0.0, 2.0, 4.0)]
    monkeypatch.setattr(leds_module, "SHADING_BLOCK", 4)  # 35 points: nine blocks, the last one partial
    blocked = led_shading(points, normals, leds)
    assert blocked.shape == (3, 7, 5, 3)
    pairs = zip(points.reshape(-1, 3), normals.reshape(-1, 3))
    alone = np.stack([led_shading(p[None], n[None], leds)[:, 0] for p, n in pairs], 1)
    np.testing.assert_array_equal(blocked, alone.reshape(blocked.shape))
    assert (blocked > 0).mean() > 0.3  # most points are lit: the comparison is not between zeros
    out = np.full((3, 7, 5, 3), np.nan)
    for rows in (slice(0, 3), slice(3, 7)):  # written in place by blocks of rows (the solver's threads)
        assert led_shading(points[rows], normals[rows], leds, out=out[:, rows]) is not None
    np.testing.assert_array_equal(out, blocked)
    with pytest.raises(ShapeError, match="out must be"):
        led_shading(points, normals, leds, out=np.empty((3, 5, 7, 3)))


def test_disk_shading_checks_points_and_normals_like_led_shading():
    """Pinned (the audit read no check in disk_shading): every path goes through led_shading's."""
    from nlipscalib.core.leds import disk_shading

    led = Led((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    for points, normals in ((np.zeros((4, 3)), np.zeros((5, 3))), (np.zeros((4, 2)), np.zeros((4, 2)))):
        for leds, radius in (([led], 1.8), ([], 1.8), ([led], 0.0)):
            with pytest.raises(ShapeError, match=r"\(\.\.\., 3\)"):
                disk_shading(points, normals, leds, radius)


def test_an_led_direction_without_a_length_is_a_mismatch():
    from nlipscalib.core.leds import led_geometry_mismatch

    positions = np.array([[9.0, 0.0, 3.0], [0.0, 9.0, 3.0]])
    directions = np.array([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    assert led_geometry_mismatch(positions, directions, positions, directions) is None
    broken = directions.copy()
    broken[1] = 0.0
    assert "LED 2" in led_geometry_mismatch(positions, directions, positions, broken)


def test_tricolor_colors_light_leds_1_to_4_red_5_to_8_green_9_to_12_blue():
    colors = tricolor_colors(12)
    assert colors.shape == (12, 3)
    np.testing.assert_array_equal(colors.argmax(axis=1), [0] * 4 + [1] * 4 + [2] * 4)
    np.testing.assert_array_equal(colors.sum(axis=1), np.ones(12))  # one channel each, fully on


def test_a_binary_file_given_as_an_led_file_is_named_without_the_decoders_byte_offsets(tmp_path):
    """`nlips solve PRESS --leds out/nlipsnet.pt` (a model, not the LED JSON) said "not a valid LED file ('utf-8'
    codec can't decode byte 0x80 in position 64: invalid start byte)"."""
    from nlipscalib.core.errors import CaptureError
    from nlipscalib.core.ledfile import read_led_file

    model = tmp_path / "nlipsnet.pt"
    model.write_bytes(b"PK\x03\x04" + bytes(range(256)))
    with pytest.raises(CaptureError) as err:
        read_led_file(model)
    assert str(err.value) == f"{model}: not an LED file (binary, not JSON): give the .json from `nlips calibrate-leds`"


def test_an_led_files_not_fitted_leds_are_read_back_and_a_malformed_list_is_named(tmp_path):
    """calibrate-leds records the LEDs it kept at their starting values (``not_fitted``); the reader hands them on
    (so `nlips solve --leds` can say so) and names the file when the list is not LED indices."""
    from nlipscalib.core.errors import CaptureError
    from nlipscalib.core.ledfile import read_led_file, save_leds

    leds = [Led(position=(float(i), 0.0, 1.0), direction=(0.0, 0.0, 1.0)) for i in range(4)]
    good = save_leds(tmp_path / "leds.json", leds, {"not_fitted": [2]})
    assert read_led_file(good).not_fitted == (2,)
    assert read_led_file(save_leds(tmp_path / "all.json", leds)).not_fitted == ()
    bad = save_leds(tmp_path / "bad.json", leds, {"not_fitted": [4]})
    with pytest.raises(CaptureError) as err:
        read_led_file(bad)
    assert str(err.value) == f"{bad}: not a valid LED file ('not_fitted' must list LED indices 0-3)"


def test_disk_falloff_is_disk_shading_without_psi_and_the_point_falloff_at_radius_zero():
    """The indirect term's solved patches average the channel-free falloff and multiply by Psi after
    (``solver.indirect.Surface.replaced``): of disk LEDs the same products as :func:`disk_shading`'s."""
    from nlipscalib.core.leds import disk_falloff, disk_shading

    rng = np.random.default_rng(2)
    pts = rng.normal(size=(4, 5, 3)) * 3 + [0.0, 0.0, 12.0]
    nrm = -pts / np.linalg.norm(pts, axis=-1, keepdims=True)
    leds = [Led((5.0, 1.0, 2.0), (-0.3, 0.0, 0.954), 1.7, (1.2, 0.9, 0.7)), Led((-4.0, 3.0, 2.5), (0.2, -0.2, 0.96))]
    psi = led_arrays(leds)[3][:, None, None, :]
    falloff = disk_falloff(pts, nrm, leds, 1.8)
    assert falloff.shape == (2, 4, 5)
    np.testing.assert_array_equal(falloff[..., None] * psi, disk_shading(pts, nrm, leds, 1.8))
    assert not np.allclose(falloff, led_falloff(pts, nrm, leds), rtol=1e-4)
    np.testing.assert_array_equal(disk_falloff(pts, nrm, leds, 0.0), led_falloff(pts, nrm, leds))
    with pytest.raises(ConfigError):
        disk_falloff(pts, nrm, leds, -1.0)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((3, []), r"path must be the LED file's path \(str or Path\), got int 3"),
        (("leds.json", "leds"), "leds must be a list of Led"),
        (("leds.json", [1, 2]), r"leds\[0\] must be an Led \(nlipscalib.core.leds.Led\), got int 1"),
    ],
)
def test_save_leds_of_another_kind_names_the_argument(tmp_path, monkeypatch, args, message):
    """save_leds(path, [1, 2]) failed with an AttributeError ('int' object has no attribute 'to_dict')."""
    from nlipscalib.core.errors import ShapeError
    from nlipscalib.core.ledfile import save_leds

    monkeypatch.chdir(tmp_path)
    with pytest.raises(ShapeError, match=message):
        save_leds(*args)
    assert list(tmp_path.iterdir()) == []
