"""Indenter bodies: posed tip-first, textured where they should be, loadable from files."""

from pathlib import Path

import numpy as np
import pytest

from nlipscalib.core.errors import ConfigError
from nlipscalib.sim.indenters import _ORIENTATIONS, IndenterConfig, indenter_heightfield, make_indenter

PYRAMID = Path(__file__).resolve().parents[2] / "scenes" / "indenters" / "pyramid.stl"
CASES = [(k, o) for k, ors in _ORIENTATIONS.items() if k != "mesh" for o in ors]


@pytest.mark.parametrize("kind, orientation", CASES)
def test_tip_at_zero_and_body_below(kind, orientation):
    mesh = make_indenter(IndenterConfig(kind=kind, orientation=orientation))
    assert mesh.bounds[1, 2] == pytest.approx(0.0, abs=1e-9)
    assert np.all(mesh.vertices[:, 2] <= 1e-9)
    assert mesh.is_watertight and mesh.volume > 0
    np.testing.assert_allclose((mesh.bounds[0, :2] + mesh.bounds[1, :2]) / 2, 0.0, atol=1e-9)


@pytest.mark.parametrize(
    "kind, orientation",
    [
        ("coin", "face"),
        ("coin", "side"),
        ("cap", "side"),
        ("cap", "face"),
        ("gear", "side"),
        ("key", "face"),
        ("key", "side"),
        ("brick", "face"),
        ("screw", "side"),
    ],
)
def test_textured_kinds_have_relief(kind, orientation):
    cfg = IndenterConfig(kind=kind, orientation=orientation)
    hf = indenter_heightfield(make_indenter(cfg), 0.04)
    z = hf.z[np.isfinite(hf.z)]
    near_front = z[z > -cfg.relief_mm * 3]
    # at least two distinct plateaus or a ridged profile within a few relief heights of the tip
    counts, _ = np.histogram(near_front, bins=10)
    assert (counts > 0.02 * counts.sum()).sum() >= 2


def test_sphere_heightfield_matches_cap():
    hf = indenter_heightfield(make_indenter(IndenterConfig(kind="sphere", size=6)), 0.05)
    xy = np.array([[0.0, 0.0], [1.0, 0.5], [2.0, -1.0], [4.0, 0.0]])
    h = hf(xy)
    expect = np.sqrt(9 - (xy**2).sum(1)[:3]) - 3
    np.testing.assert_allclose(h[:3], expect, atol=0.01)
    assert h[3] == -np.inf


def test_cube_orientations_change_the_leading_shape():
    face = indenter_heightfield(make_indenter(IndenterConfig(kind="cube", orientation="face")), 0.1)
    corner = indenter_heightfield(make_indenter(IndenterConfig(kind="cube", orientation="corner")), 0.1)
    assert np.isfinite(face.z).sum() > 0 and np.ptp(face.z[np.isfinite(face.z)]) < 1e-9
    assert face(np.array([[2.0, 2.0]]))[0] == pytest.approx(0.0)
    assert corner(np.array([[2.0, 0.0]]))[0] < -1.0  # falls away from the corner


def test_mesh_loader_scales_and_poses():
    mesh = make_indenter(IndenterConfig(kind="mesh", mesh=str(PYRAMID), size=5.0))
    assert np.max(mesh.extents) == pytest.approx(5.0)
    assert mesh.bounds[1, 2] == pytest.approx(0.0)
    unscaled = make_indenter(IndenterConfig(kind="mesh", mesh=str(PYRAMID), scale_to_size=False))
    assert np.max(unscaled.extents) == pytest.approx(4.0)


def test_mesh_loader_errors_name_the_file(tmp_path):
    missing = tmp_path / "nope.stl"
    with pytest.raises(ConfigError, match="nope.stl"):
        make_indenter(IndenterConfig(kind="mesh", mesh=str(missing)))
    garbage = tmp_path / "garbage.stl"
    garbage.write_bytes(b"\x00\x01not a mesh at all" * 3)
    with pytest.raises(ConfigError, match="garbage.stl"):
        make_indenter(IndenterConfig(kind="mesh", mesh=str(garbage)))


def test_bad_configs_raise():
    with pytest.raises(ConfigError, match="unknown indenter kind"):
        IndenterConfig(kind="banana")
    with pytest.raises(ConfigError, match="cannot be pressed"):
        IndenterConfig(kind="sphere", orientation="corner")
    with pytest.raises(ConfigError, match="size"):
        IndenterConfig(size=0)
    with pytest.raises(ConfigError, match="needs indenter.mesh"):
        IndenterConfig(kind="mesh")


def test_unscaled_mesh_in_metres_or_micrometres_is_refused(tmp_path):
    """A part exported in metres read as it is (scale_to_size = false) was 0.004 mm across: rendered without a
    word, its press touched no pixel."""
    import trimesh

    for scale, unit in ((0.001, "metres"), (1000.0, "micrometres")):
        mesh = trimesh.load(PYRAMID)
        mesh.apply_scale(scale)
        path = tmp_path / f"pyramid_{unit}.stl"
        mesh.export(path)
        with pytest.raises(ConfigError, match=f"pyramid_{unit}.stl: its largest extent .* is it in {unit}"):
            make_indenter(IndenterConfig(kind="mesh", mesh=str(path), scale_to_size=False))
        scaled = make_indenter(IndenterConfig(kind="mesh", mesh=str(path), size=5.0))  # scaled to size: fine
        assert np.max(scaled.extents) == pytest.approx(5.0)


def test_a_relative_mesh_path_is_found_beside_the_file_naming_it(tmp_path, monkeypatch):
    from nlipscalib.sim.indenters import with_mesh_beside

    (tmp_path / "specs").mkdir()
    (tmp_path / "specs" / "part.stl").write_bytes(PYRAMID.read_bytes())
    monkeypatch.chdir(tmp_path)
    beside = with_mesh_beside({"kind": "mesh", "mesh": "part.stl"}, tmp_path / "specs")
    assert beside["mesh"] == str(tmp_path / "specs" / "part.stl")
    (tmp_path / "part.stl").write_bytes(PYRAMID.read_bytes())  # one in the working directory keeps its meaning
    assert with_mesh_beside({"kind": "mesh", "mesh": "part.stl"}, tmp_path / "specs")["mesh"] == "part.stl"
    assert with_mesh_beside("sphere", tmp_path) == "sphere"  # not a mapping: from_mapping reports it
