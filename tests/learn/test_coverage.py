"""Coverage report: known answers on synthetic calibration samples (no solver, no twin)."""

import dataclasses

import numpy as np
import pytest

from nlipscalib.learn.coverage import STEEP_RELIEF, coverage, steep_gap, tilt_deg

H, W = 64, 64


class FakeDataset:
    """What ``coverage`` reads of a CalibrationDataset: the reference and per-press contact samples."""

    def __init__(self, presses: dict[str, tuple[str, np.ndarray]]):
        self.presses = presses  # name -> (indenter kind, tilts in degrees of its samples)
        self.entries = [{"name": n, "press": {"indenter": k}} for n, (k, _) in presses.items()]
        self.tricolor_left_out: list[dict] = []  # the presses `nlips calibrate` left out for their tri-colour frame
        self.tricolor_kept: list[str] = []  # those kept with --keep-tricolor-mismatch

    def reference(self):
        normals = np.zeros((H, W, 3))
        normals[..., 2] = -1.0  # the undeformed surface faces the camera
        return {"valid": np.ones((H, W), bool), "normals": normals}

    def load(self, name):
        _, tilts = self.presses[name]
        rng = np.random.default_rng(len(name))
        n = len(tilts)
        pixel = np.stack([rng.integers(0, W, n), rng.integers(0, H, n)], axis=1)
        azimuth = rng.uniform(-np.pi, np.pi, n)
        t = np.radians(tilts)
        normal = np.stack([np.sin(t) * np.cos(azimuth), np.sin(t) * np.sin(azimuth), -np.cos(t)], axis=1)
        return {"contact": np.ones(n, bool), "source": np.zeros(n, int), "pixel": pixel, "normal": normal}


def smooth_press(kind: str, n: int = 40_000, most: float = 30.0):
    return kind, np.random.default_rng(0).uniform(3.0, most, n)


def test_tilt_is_the_angle_from_the_undeformed_normal():
    ref = np.array([[0.0, 0.0, -1.0]] * 3)
    t = np.radians([0.0, 30.0, 90.0])
    normals = np.stack([np.sin(t), np.zeros(3), -np.cos(t)], axis=1)
    np.testing.assert_allclose(tilt_deg(normals, ref), [0.0, 30.0, 90.0], atol=1e-6)


def test_smooth_presses_only_ask_for_steep_relief():
    data = FakeDataset({"a": smooth_press("sphere"), "b": smooth_press("cube")})
    steep = coverage(data)["steep"]
    assert steep["untaught_from_deg"] == 45.0  # the 45-90 deg ring is empty in every region
    assert 29.0 <= steep["taught_tilt_deg"] <= 31.0  # 99 % of U(3, 30) deg
    assert STEEP_RELIEF in steep["advice"] and "45 deg" in steep["advice"]


def test_a_press_with_steep_relief_fills_the_gap():
    steep_kind = ("brick", np.concatenate([np.random.default_rng(1).uniform(3.0, 30.0, 20_000), np.full(20_000, 60.0)]))
    data = FakeDataset({"a": smooth_press("sphere"), "b": steep_kind})
    steep = coverage(data)["steep"]
    assert steep["untaught_from_deg"] is None and steep["advice"] == ""
    assert steep["taught_tilt_deg"] == pytest.approx(60.0, abs=1.0)  # to the whole degree


def test_steep_gap_of_an_empty_dataset_asks_from_the_first_ring():
    covered = np.zeros((4, 4, 32), bool)
    steep = steep_gap(covered, np.ones((4, 4), bool), np.zeros(181, np.int64))
    assert steep["taught_tilt_deg"] is None and steep["untaught_from_deg"] == 2.0 and "no samples" in steep["advice"]


def test_the_advice_names_the_object_with_its_article():
    """Captured presses record no indenter: the advice said "press next: a unknown"."""
    from nlipscalib.learn.coverage import _next_press

    covered = np.zeros((2, 2, 3), bool)
    counts = np.zeros((2, 2, 3))
    gel = np.ones((2, 2), bool)
    kinds = {"object": np.ones(3)}
    assert _next_press(counts, covered, gel, kinds, np.ones((20, 20), bool))["advice"].startswith(
        "an object in image region"
    )
    assert _next_press(counts, covered, gel, {"sphere": np.ones(3)}, np.ones((20, 20), bool))["advice"].startswith(
        "a sphere in"
    )
    assert _next_press(counts, covered, gel, {}, np.ones((20, 20), bool))["advice"].startswith("any indenter in")


@pytest.mark.parametrize("recorded", [None, "unknown"])
def test_a_press_that_records_no_indenter_is_an_object(recorded):
    """Captured presses are recorded with no indenter kind (older datasets: "unknown"): `nlips calibrate` advised
    "press next: an unknown in image region ..."."""
    data = FakeDataset({"a": smooth_press(recorded), "b": smooth_press(recorded)})
    cov = coverage(data)
    assert list(cov["kinds"]) == ["object"] and cov["next_press"]["indenter"] == "object"
    assert cov["next_press"]["advice"].startswith("an object in image region")


@pytest.mark.parametrize("shape", ["hemisphere", "flat"])
@pytest.mark.parametrize(("polar", "azimuth"), [(0.0, 0.0), (15.0, 30.0), (25.0, 200.0), (35.0, 300.0)])
def test_a_regions_press_direction_is_the_one_the_twin_presses_there(shape, polar, azimuth):
    """The advice named an image region only; the press direction given for it must be the one whose press lands
    there (``nlips render --polar --azimuth``): a press point projected into the image comes back as its angles."""
    from nlipscalib.core.dome import dome_surface_point, reference_surface
    from nlipscalib.core.sensor import SensorDesign
    from nlipscalib.learn.coverage import region_press_angles

    design = SensorDesign()
    design = dataclasses.replace(design, dome=dataclasses.replace(design.dome, shape=shape))
    camera = design.camera_model()
    position = np.asarray(design.camera.position, float)
    point, _ = dome_surface_point(design.dome, polar, azimuth)
    u, v = np.round(camera.project(point - position)).astype(int)
    box = [u - 2, v - 2, u + 3, v + 3]  # centred on that pixel
    got = region_press_angles(box, reference_surface(design, camera).depth, camera, tuple(position))
    assert got is not None
    assert got[0] == pytest.approx(polar, abs=0.5)
    if polar > 0:  # the apex has no azimuth
        assert (got[1] - azimuth + 180) % 360 - 180 == pytest.approx(0.0, abs=1.5)


def test_the_advice_gives_the_press_direction_when_the_sensor_geometry_is_known():
    from nlipscalib.learn.coverage import _next_press

    covered, counts, gel = np.zeros((2, 2, 3), bool), np.zeros((2, 2, 3)), np.ones((2, 2), bool)
    advice = _next_press(counts, covered, gel, {}, np.ones((20, 20), bool), lambda box: (12.34, 251.6))
    assert "(centre u=4, v=4; press direction polar 12°, azimuth 252°)" in advice["advice"]
    assert (advice["polar_deg"], advice["azimuth_deg"]) == (12.3, 251.6)
    unknown = _next_press(counts, covered, gel, {}, np.ones((20, 20), bool))
    assert "polar" not in unknown["advice"] and unknown["polar_deg"] is None


def test_a_region_that_holds_gel_and_black_corner_is_advised_on_its_gel():
    """A camera that sees beyond the gel (nlipstac's dome, the camera 8 mm below the base with a 130 deg view at
    160x120: a circular image, black corners): the top-left region is half gel, half black corner. The advice named
    the region's centre, a pixel off the gel ("centre u=20, v=14"), and the press direction of the gel pixel nearest
    it, on the dome's base (polar 90 deg); it names the centre of the region's gel and a direction onto it."""
    from nlipscalib.core.dome import reference_surface
    from nlipscalib.core.sensor import SensorDesign
    from nlipscalib.learn.coverage import _next_press, gel_centre, region_press_angles

    design = SensorDesign()
    view = dataclasses.replace(design.camera, width=160, height=120, hfov_deg=130.0, position=(0.0, 0.0, -8.0))
    design = dataclasses.replace(design, camera=view)
    camera = design.camera_model()
    depth = reference_surface(design, camera).depth
    valid = np.isfinite(depth)
    assert 0.3 < valid[:30, :40].mean() < 0.7  # the region is partly off the gel
    u, v = gel_centre([0, 0, 40, 30], valid)
    assert valid[round(v), round(u)]
    polar, _ = region_press_angles([0, 0, 40, 30], depth, camera, tuple(view.position))
    assert polar < 85  # on the gel's side, not its base
    covered, counts, gel = np.ones((4, 4, 3), bool), np.zeros((4, 4, 3)), np.ones((4, 4), bool)
    covered[0, 0] = False
    advice = _next_press(counts, covered, gel, {}, valid)
    assert (
        advice["box_u0_v0_u1_v1"] == [0, 0, 40, 30]
        and valid[round(advice["centre_uv"][1]), round(advice["centre_uv"][0])]
    )
    # where the gel fills the region, the advice is its centre, as before
    assert gel_centre([0, 0, 40, 30], np.ones((120, 160), bool)) == (19.5, 14.5)


def test_the_presses_left_out_or_kept_for_their_tri_colour_frame_are_named():
    data = FakeDataset({"a": smooth_press("sphere"), "b": smooth_press("cube")})
    assert coverage(data)["tricolor"] == {"left_out": [], "kept": [], "advice": ""}
    data.tricolor_left_out = [{"name": "press_0003", "folder": "/p/press_0003", "tricolor": {"verdict": "colours"}}]
    data.tricolor_kept = ["b"]
    found = coverage(data)["tricolor"]
    assert found["left_out"] == ["press_0003"] and found["kept"] == ["b"]
    assert found["advice"].startswith("1 press left out of the dataset, whose tri-colour frame does not hold")
    assert (
        "(press_0003): what they pressed is not covered" in found["advice"]
        and "--keep-tricolor-mismatch (b)" in (found["advice"])
    )
