"""Presses: the gel meets the indenter, never enters it, and relaxes to the dome away from it."""

import numpy as np
import pytest

from nlipscalib.core.errors import ConfigError
from nlipscalib.sim.dome import make_dome
from nlipscalib.sim.indent import PressConfig, _heightfield, apply_press
from nlipscalib.sim.indenters import IndenterConfig
from nlipscalib.sim.scene import DomeConfig, load_scene

DOME = DomeConfig()
SPHERE = PressConfig(IndenterConfig(kind="sphere", size=6.0), polar_deg=20, azimuth_deg=30, depth=1.0)


@pytest.fixture(scope="module")
def sphere_press():
    return apply_press(DOME, SPHERE)


def _undeformed(gel):
    return gel.mesh.vertices - gel.displacement[:, None] * gel.press_axis


def _gap(gel, press, dome):
    """(V,) mm: how far each vertex is ahead of the indenter's leading surface (negative = inside)."""
    hf = _heightfield(press.indenter, dome.contact_edge_length / 2)
    local = (gel.mesh.vertices - gel.tip) @ gel.rotation
    h = hf(local[:, :2])
    return np.where(np.isfinite(h), local[:, 2] - h, np.inf)


def test_sphere_pushes_the_press_point_by_depth(sphere_press):
    gel = sphere_press
    r = np.linalg.norm(_undeformed(gel) - gel.press_point, axis=1)
    assert gel.displacement.max() == pytest.approx(SPHERE.depth, abs=0.01)
    assert gel.displacement[r < 0.1].min() > 0.97 * SPHERE.depth
    assert gel.touching.any() and np.all(gel.contact[gel.touching])


def test_no_vertex_enters_the_indenter(sphere_press):
    assert _gap(sphere_press, SPHERE, DOME).min() > -1e-3
    # and against the posed watertight mesh itself
    v = sphere_press.mesh.vertices
    centre = sphere_press.tip - 3.0 * sphere_press.press_axis
    assert np.linalg.norm(v - centre, axis=1).min() > 3.0 - 2e-3


def test_displacement_vanishes_far_away_and_falls_off(sphere_press):
    gel = sphere_press
    r = np.linalg.norm(_undeformed(gel) - gel.press_point, axis=1)
    assert np.all(gel.displacement[r > 10] == 0)
    assert not gel.contact[r > 10].any()
    bins = np.arange(0, 8, 0.5)
    means = [gel.displacement[(r >= a) & (r < a + 0.5)].mean() for a in bins]
    assert np.all(np.diff(means) <= 1e-3)  # monotone outward on average
    assert means[0] > 0.9 and means[-1] < 0.05


def test_mesh_refined_inward_and_reasonable(sphere_press):
    gel = sphere_press
    base = make_dome(DOME)
    assert len(base.faces) < len(gel.mesh.faces) < 400_000
    near = np.linalg.norm(gel.mesh.triangles_center - gel.press_point, axis=1) < 1.5
    assert np.median(gel.mesh.edges_unique_length[np.isin(gel.mesh.edges_unique, gel.mesh.faces[near]).all(1)]) < 0.1
    to_camera = np.array([0, 0, -3.0]) - gel.mesh.vertices
    assert np.mean(np.einsum("ij,ij->i", gel.mesh.vertex_normals, to_camera) > 0) > 0.999
    assert gel.mesh.is_winding_consistent and gel.mesh.euler_number == 1
    assert len(gel.displacement) == len(gel.contact) == len(gel.touching) == len(gel.mesh.vertices)


def test_coin_relief_shows_in_the_gel():
    press = PressConfig(IndenterConfig(kind="coin", size=6.0), polar_deg=0, depth=0.8)
    gel = apply_press(DOME, press)
    assert _gap(gel, press, DOME).min() > -1e-3
    touching = gel.displacement[gel.touching]
    # the rim and emblem stand 0.24 mm proud of the coin face: two families of pushes
    counts, _ = np.histogram(touching, bins=8)
    assert np.ptp(touching) > 0.2 and (counts > 0.02 * counts.sum()).sum() >= 2


def test_other_domes_and_user_mesh():
    from pathlib import Path

    pyramid = Path(__file__).resolve().parents[2] / "scenes" / "indenters" / "pyramid.stl"
    press = PressConfig(IndenterConfig(kind="mesh", mesh=str(pyramid), size=4.0), polar_deg=10, depth=0.5)
    for name in ("capsule", "flat"):
        dome = load_scene(name).dome
        gel = apply_press(dome, press)
        # a sharp tip is sampled by the nearest gel vertex: within about one refined edge of depth
        assert gel.displacement.max() == pytest.approx(0.5, abs=dome.contact_edge_length)
        assert _gap(gel, press, dome).min() > -1e-3


def test_shallow_press_leaves_far_gel_alone():
    gel = apply_press(DOME, PressConfig(IndenterConfig(kind="cube", size=3.0), polar_deg=40, depth=0.05))
    far = np.linalg.norm(_undeformed(gel) - gel.press_point, axis=1) > 8
    assert gel.contact.sum() > 0 and not gel.contact[far].any()


@pytest.mark.parametrize(
    "press, match",
    [
        (PressConfig(polar_deg=85, depth=1.0), "base rim"),
        (PressConfig(IndenterConfig(kind="cube", size=8), polar_deg=80, depth=1.0), "base rim"),
        (PressConfig(depth=4.0), "thickness"),
    ],
)
def test_bad_presses_raise(press, match):
    with pytest.raises(ConfigError, match=match):
        apply_press(DOME, press)


def test_non_positive_depth_raises():
    with pytest.raises(ConfigError, match="depth"):
        PressConfig(depth=0.0)


def test_the_plate_solve_matches_a_dense_solve():
    """The draping's sparse solve (SuperLU in symmetric mode, diagonal pivots) is the plate's exact minimiser."""
    from nlipscalib.sim.indent import _cotan_laplacian, _plate, _solve

    dome = make_dome(DomeConfig(edge_length=3.0))
    lap, mass = _cotan_laplacian(dome.vertices, dome.faces)
    q = _plate(lap, mass, 1.0)
    apex = np.argmax(dome.vertices[:, 2])
    near = np.linalg.norm(dome.vertices - dome.vertices[apex], axis=1)
    known = np.where(near < 4.0, 1.0, 0.0)
    unknown = (near >= 4.0) & (near < 12.0)
    ui = np.flatnonzero(unknown)
    dense = q.toarray()
    expected = np.linalg.solve(dense[np.ix_(ui, ui)], -dense[ui] @ known)
    np.testing.assert_allclose(_solve(q, known, unknown), expected, rtol=0, atol=1e-10)


def test_one_pymeshlab_subdivision_at_a_time():
    """Two indentations at once in one process (a Dask worker with --nthreads 2) failed a press with pymeshlab's
    std::bad_alloc: a subdivision waits while another holds pymeshlab."""
    import threading

    from nlipscalib.sim import indent

    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    faces = np.array([[0, 1, 2]])
    done = []
    with indent._PYMESHLAB:
        worker = threading.Thread(target=lambda: done.append(indent._subdivide(vertices, faces, np.ones(1, bool))))
        worker.start()
        worker.join(0.5)
        assert worker.is_alive() and not done  # waiting for the lock, not inside pymeshlab
    worker.join(60)
    assert len(done) == 1 and len(done[0][1]) == 4  # one triangle split into four


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"polar_deg": 200}, r"polar_deg: must be in \[0, 90\) deg .*got 200"),
        ({"polar_deg": -1.0}, r"polar_deg: must be in \[0, 90\) deg .*got -1.0"),
        ({"polar_deg": float("nan")}, r"polar_deg: must be in \[0, 90\) deg .*got nan"),
        ({"azimuth_deg": float("inf")}, "azimuth_deg: must be a finite angle in degrees, got inf"),
        ({"spin_deg": float("nan")}, "spin_deg: must be a finite angle in degrees, got nan"),
        ({"polar_deg": "20"}, "polar_deg: must be a number, got '20'"),
        ({"depth": True}, "depth: must be a number, got True"),
        ({"indenter": "sphere"}, "indenter: must be an IndenterConfig, got str"),
    ],
)
def test_a_press_out_of_range_is_refused_when_made(fields, message):
    """PressConfig(polar_deg=200) was refused by the render ("off the dome"), after the scene was set up."""
    with pytest.raises(ConfigError, match=message):
        PressConfig(**fields)


def test_a_missing_mesh_file_is_refused_when_the_indenter_is_made(tmp_path):
    with pytest.raises(ConfigError, match=f"indenter mesh {tmp_path / 'nope.stl'}: no such file"):
        IndenterConfig(kind="mesh", mesh=str(tmp_path / "nope.stl"))
    with pytest.raises(ConfigError, match="a folder, not a mesh file"):
        IndenterConfig(kind="mesh", mesh=str(tmp_path))
