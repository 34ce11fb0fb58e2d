"""The indirect term of a disk-LED solve (``led_radius`` > 0, ``nlips solve --led-model disks``) is shaded with the
same disks (:func:`nlipscalib.solver.indirect.term_shading`), and what it caches is keyed by their radius.

Before s33-diskterm the term (the reference surface's shading it is fitted on, the off-view dome's light, the outer
loop's surfaces) kept the point LEDs under a disk solve: on a one-bounce gel-filling press the solve's image model was
rho (S_disk + kappa G_point) against data rho (S_disk + kappa G_disk), and the whole gel lost (the 320x240 sphere's
depth RMSE 0.0237 mm against 0.0068 with the term of the disks, benchmarks/RESULTS.md, s33-disklose). And the cached
fit, reference shading and surfaces were keyed by the LEDs alone, so a disk solve would have read a point solve's.
"""

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.core.camera import depth_to_points  # noqa: E402
from nlipscalib.core.leds import disk_shading  # noqa: E402
from nlipscalib.core.metrics import evaluate  # noqa: E402
from nlipscalib.sim.indent import PressConfig  # noqa: E402
from nlipscalib.sim.indenters import IndenterConfig  # noqa: E402
from nlipscalib.sim.press import render_press  # noqa: E402
from nlipscalib.sim.scene import load_scene  # noqa: E402
from nlipscalib.solver import reuse  # noqa: E402
from nlipscalib.solver.indirect import Surface, direct_shading, term_key  # noqa: E402
from nlipscalib.solver.press import solve_press  # noqa: E402

RADIUS = 1.8
"""mm: the default twin's LED light cups (``[led_package] size = 3.6``)."""
DISK_TERM_DEPTH_RMSE = 0.021
"""mm: the whole gel's depth RMSE of the fixture's disk solve bound: 0.0168 with the term of the disks, 0.0276 with
the point term it had before (s33-diskterm)."""
DISK_TERM_AAE_DEG = 0.5
"""deg: its whole gel's AAE bound: 0.354 with the term of the disks, 0.655 with the point term."""
SPHERE = PressConfig(IndenterConfig(kind="sphere", size=6.0), polar_deg=15, azimuth_deg=30, depth=1.5)


@pytest.fixture(scope="module")
def one_bounce(tmp_path_factory):
    """The default twin (3.6 mm disk LEDs), one bounce, 16 spp, 160x120, noise-free: the undeformed dome and the
    sphere press. Its meta.json LEDs are the disks' centres and axes (the true disks at ``RADIUS``)."""
    root = tmp_path_factory.mktemp("diskterm")
    scene = load_scene().replace(
        noise={"enabled": False}, render={"bounces": 1, "spp": 16}, camera={"width": 160, "height": 120}
    )
    flat = load_press(render_press(scene, None, root / "flat", seed=3))
    press = load_press(render_press(scene, SPHERE, root / "sphere", seed=4))
    return flat, press


def test_the_terms_shading_and_surfaces_are_the_disks(one_bounce):
    flat, _ = one_bounce
    ref, leds = flat.reference, flat.leds
    disks = direct_shading(flat.camera, leds, ref.depth, ref.normals, RADIUS)
    valid = np.isfinite(ref.depth)
    points = direct_shading(flat.camera, leds, ref.depth, ref.normals)
    assert np.abs(disks - points)[:, valid].max() > 1e-3 * points[:, valid].max()  # the disks are not points here
    pts = depth_to_points(np.where(valid, ref.depth, 0.0), flat.camera.rays)[valid]
    np.testing.assert_allclose(disks[:, valid], disk_shading(pts, ref.normals[valid], leds, RADIUS), rtol=1e-12)
    # a solved region's patches (Surface.replaced) shade as a new surface of the disks does, not as points
    surf = Surface(flat.camera, leds, ref.depth, ref.normals, 4, radius=RADIUS)
    changed = np.zeros_like(valid)
    changed[40:80, 60:100] = valid[40:80, 60:100]
    normals = ref.normals.copy()
    normals[changed] = (normals[changed] + [0.0, 0.2, 0.0]) / np.linalg.norm(
        normals[changed] + [0.0, 0.2, 0.0], axis=-1
    )[:, None]
    again = Surface(flat.camera, leds, ref.depth, normals, 4, radius=RADIUS)
    np.testing.assert_allclose(surf.replaced(ref.depth, normals, changed).shading, again.shading, rtol=1e-9, atol=1e-15)
    assert term_key(leds) == tuple(leds)  # point keys as before disks were threaded through
    assert term_key(leds, RADIUS) != term_key(leds)


def test_a_disk_solve_with_the_term_of_its_disks_fits_the_one_bounce_twin(one_bounce):
    """The true disks (the meta.json LEDs at ``RADIUS``) against the undeformed capture: the whole gel's depth and
    normals as close as the disks' own model allows (with the point term: see the module's docstring)."""
    flat, press = one_bounce
    score = evaluate(solve_press(press, indirect=flat, led_radius=RADIUS), press.ground_truth)
    assert score["all"]["depth_rmse_mm"] < DISK_TERM_DEPTH_RMSE, score["all"]
    assert score["all"]["aae_deg"] < DISK_TERM_AAE_DEG, score["all"]


def test_a_disk_solve_never_reads_a_point_solves_cached_term_nor_back(one_bounce, tmp_path, monkeypatch):
    """Points then disks, and disks then points, in one process and one cache folder: each result is the one a fresh
    process with an empty cache makes (the disks here are the points' own LEDs: only the radius tells them apart)."""
    from nlipscalib.core import diskcache

    flat, press = one_bounce

    def fresh(name: str) -> None:
        diskcache.wait()
        reuse.clear()
        monkeypatch.setenv("NLIPS_CACHE_DIR", str(tmp_path / name))

    def solve(radius: float):
        return solve_press(press, indirect=flat, led_radius=radius, max_outer=1)

    fresh("alone-points")
    points = solve(0.0)
    fresh("alone-disks")
    disks = solve(RADIUS)
    assert not np.array_equal(points.depth, disks.depth)
    fresh("points-then-disks")
    solve(0.0)
    np.testing.assert_array_equal(solve(RADIUS).depth, disks.depth)
    reuse.clear()  # the next process: the fits, surfaces and off-view light from disk
    np.testing.assert_array_equal(solve(0.0).depth, points.depth)
    np.testing.assert_array_equal(solve(RADIUS).depth, disks.depth)
