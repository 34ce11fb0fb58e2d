"""Indenter bodies and the height field of their leading surface.

Indenter frame: local +z is the direction of motion into the gel, the leading tip is at z = 0 and
the body lies at z <= 0, centred on the z axis (bounding-box centre in x and y). Each builder makes
the body in a natural pose with its textured side facing +z; ``orientation`` and ``rotation_deg``
turn it before it is posed. What indentation needs is :func:`indenter_heightfield`, the largest
local z of material above each (x, y): the gel is pushed onto that surface.
"""

from __future__ import annotations

import dataclasses
import functools
import numbers
from pathlib import Path
from typing import Literal

import numpy as np
import shapely
import trimesh
from shapely import affinity
from shapely.geometry import Point, Polygon, box

from ..core.errors import ConfigError
from ..core.sensor import EXAMPLE_MESH

IndenterKind = Literal["sphere", "cube", "cylinder", "cone", "screw", "coin", "cap", "gear", "key", "brick", "mesh"]
Orientation = Literal["default", "face", "edge", "corner", "side", "end"]

# orientations each kind accepts; the first is what "default" means
_ORIENTATIONS = {
    "sphere": ("face",),
    "cube": ("face", "edge", "corner"),
    "cylinder": ("end", "side"),
    "cone": ("end",),
    "screw": ("side", "end"),
    "coin": ("face", "side"),
    "cap": ("side", "face"),
    "gear": ("face", "side"),
    "key": ("face", "side"),
    "brick": ("face",),
    "mesh": ("face",),
}


@dataclasses.dataclass(frozen=True)
class IndenterConfig:
    """An indenter: a primitive, a procedural everyday object, or a user mesh."""

    kind: IndenterKind = "sphere"
    """sphere, cube, cylinder (flat end), cone, screw (threaded shaft), coin (rim, emblem, reeded edge),
    cap (knurled bottle cap), gear (involute-like teeth), key (blade with bitting and groove),
    brick (LEGO-like 2x4, studs toward the gel) or mesh (``mesh`` file)."""
    size: float = 6.0
    """Characteristic size, mm: diameter (sphere, cylinder, cone base, coin, cap, gear, screw), side (cube),
    overall length (key, brick), largest extent (mesh, when ``scale_to_size``)."""
    orientation: Orientation = "default"
    """Which side meets the gel: cube face/edge/corner; cylinder end/side; screw side/end; coin face/side
    (reeded edge); cap side (knurl)/face; gear face/side (teeth); key face/side (bitting edge)."""
    relief: float | None = None
    """Height of the texture (coin relief, knurl, thread, teeth depth, key groove), mm; None = 4% of size."""
    count: int | None = None
    """Number of repeated features (gear teeth, knurl ridges, coin reeds, screw turns); None = kind default."""
    length: float | None = None
    """Length along the axis of cylinder, cone and screw, mm; None = ``size``."""
    mesh: str | None = None
    """Path of an STL/OBJ/PLY file for ``kind = "mesh"``; its +z side meets the gel."""
    scale_to_size: bool = True
    """For ``kind = "mesh"``: scale the file so that its largest extent equals ``size``."""
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Extra rotation about x, then y, then z (degrees) applied before the tip is put at z = 0."""

    def __post_init__(self):
        if not isinstance(self.scale_to_size, bool):  # "no" is truthy: it scaled (s38-apikinds)
            raise ConfigError(f"indenter.scale_to_size: must be true or false, got {self.scale_to_size!r}")
        if self.kind not in _ORIENTATIONS:
            raise ConfigError(f"unknown indenter kind {self.kind!r} (known: {', '.join(_ORIENTATIONS)})")
        for name in ("size", "relief", "length", "count"):  # as PressConfig's numbers: not a TypeError from ">"
            value = getattr(self, name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, numbers.Real)):
                raise ConfigError(f"indenter.{name}: must be a number, got {value!r}")
        if not self.size > 0:
            raise ConfigError(f"indenter.size must be > 0, got {self.size}")
        allowed = _ORIENTATIONS[self.kind]
        if self.orientation != "default" and self.orientation not in allowed:
            raise ConfigError(
                f"indenter {self.kind!r} cannot be pressed {self.orientation!r} (orientations: {', '.join(allowed)})"
            )
        for name in ("relief", "length"):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise ConfigError(f"indenter.{name} must be > 0, got {value}")
        if self.count is not None and self.count < 3:
            raise ConfigError(f"indenter.count must be >= 3, got {self.count}")
        if self.kind == "mesh" and not self.mesh:
            raise ConfigError("indenter kind 'mesh' needs indenter.mesh (path of an STL/OBJ/PLY file)")
        if self.kind == "mesh" and (problem := mesh_path_problem(self.mesh)):
            # here, not when the render reads it: a script's PressConfig is told at once, not minutes later
            raise ConfigError(problem)

    @property
    def pose(self) -> str:
        """The orientation actually used (``default`` resolved)."""
        return _ORIENTATIONS[self.kind][0] if self.orientation == "default" else self.orientation

    @property
    def relief_mm(self) -> float:
        return self.relief if self.relief is not None else 0.04 * self.size

    @property
    def length_mm(self) -> float:
        return self.length if self.length is not None else self.size


def make_indenter(cfg: IndenterConfig) -> trimesh.Trimesh:
    """Indenter body in the indenter frame (+z = motion into the gel, tip at z = 0, body at z <= 0).

    Returns
    -------
    trimesh.Trimesh
        mm, indenter frame; watertight for every built-in kind. A fresh copy each call.
    """
    return _make_indenter_cached(cfg, mesh_file_stamp(cfg)).copy()


def mesh_file_stamp(cfg: IndenterConfig) -> tuple[int, int] | None:
    """(modification time ns, size) of a mesh indenter's file, None for other kinds or an unreadable file.

    Why: part of the in-process caches' keys (the indenter body, its height field), so a process that renders
    again after the file was edited (a notebook, an experiment driver) gets the new shape, not the cached one."""
    if cfg.kind != "mesh" or not cfg.mesh:
        return None
    try:
        st = Path(cfg.mesh).expanduser().stat()
    except OSError:
        return None
    return st.st_mtime_ns, st.st_size


@functools.lru_cache(maxsize=32)
def _make_indenter_cached(cfg: IndenterConfig, stamp: tuple[int, int] | None = None) -> trimesh.Trimesh:
    mesh = _load_mesh(cfg) if cfg.kind == "mesh" else _BUILDERS[cfg.kind](cfg)
    mesh.apply_transform(_pose_matrix(cfg))
    if any(cfg.rotation_deg):
        angles = np.radians(cfg.rotation_deg)
        mesh.apply_transform(trimesh.transformations.euler_matrix(*angles, axes="sxyz"))
    lo, hi = mesh.bounds
    mesh.apply_translation([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -hi[2]])
    return mesh


def _pose_matrix(cfg: IndenterConfig) -> np.ndarray:
    """Turn the natural pose (texture toward +z, axis along z) into the requested orientation."""
    rot = trimesh.transformations.rotation_matrix
    pose = cfg.pose
    if cfg.kind == "cube" and pose == "edge":
        return rot(np.pi / 4, [1, 0, 0])
    if cfg.kind == "cube" and pose == "corner":
        return trimesh.geometry.align_vectors([1, 1, 1], [0, 0, 1])
    if pose == "side" and cfg.kind == "key":
        return rot(-np.pi / 2, [1, 0, 0])  # the bitting edge (+y) meets the gel
    if pose == "side":
        return rot(np.pi / 2, [1, 0, 0])  # axis along y, the curved side meets the gel
    return np.eye(4)


# --- builders: natural pose, textured side toward +z --------------------------------------------


def _sphere(cfg: IndenterConfig):
    return trimesh.creation.icosphere(subdivisions=5, radius=cfg.size / 2)


def _cube(cfg: IndenterConfig):
    return trimesh.creation.box(extents=[cfg.size] * 3)


def _cylinder(cfg: IndenterConfig):
    return trimesh.creation.cylinder(radius=cfg.size / 2, height=cfg.length_mm, sections=256)


def _cone(cfg: IndenterConfig):
    # trimesh's cone has its base at z = 0 and its apex at +height: apex first
    return trimesh.creation.cone(radius=cfg.size / 2, height=cfg.length_mm / 2, sections=256)


def _screw(cfg: IndenterConfig):
    """Threaded shaft along z: a tube whose radius follows a helical triangle wave."""
    r_out, depth = cfg.size / 2, min(cfg.relief_mm * 2, cfg.size / 4)
    turns = cfg.count or 8
    pitch = cfg.length_mm / turns
    n_th, n_s = 128, turns * 24 + 1
    th = np.linspace(0, 2 * np.pi, n_th, endpoint=False)
    s = np.linspace(-cfg.length_mm / 2, cfg.length_mm / 2, n_s)
    phase = (s[:, None] / pitch - th[None, :] / (2 * np.pi)) % 1.0
    r = r_out - depth * 2 * np.abs(phase - 0.5)  # crest at phase 0.5, root at 0 and 1
    pts = np.stack([r * np.cos(th), r * np.sin(th), np.broadcast_to(s[:, None], r.shape)], -1).reshape(-1, 3)
    return _closed_tube(pts, n_s, n_th)


def _closed_tube(points: np.ndarray, n_s: int, n_th: int) -> trimesh.Trimesh:
    """Watertight tube from an (n_s x n_th) grid of rings along z, closed by fans at both ends."""
    i, j = np.meshgrid(np.arange(n_s - 1), np.arange(n_th), indexing="ij")
    a, b = i * n_th + j, i * n_th + (j + 1) % n_th
    c, d = a + n_th, b + n_th
    side = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    ends = np.array([[0, 0, points[0, 2]], [0, 0, points[-1, 2]]])
    c0, c1 = len(points), len(points) + 1
    ring = np.arange(n_th)
    cap0 = np.stack([np.full(n_th, c0), (ring + 1) % n_th, ring], 1)
    top = (n_s - 1) * n_th
    cap1 = np.stack([np.full(n_th, c1), top + ring, top + (ring + 1) % n_th], 1)
    mesh = trimesh.Trimesh(np.concatenate([points, ends]), np.concatenate([side, cap0, cap1]))
    trimesh.repair.fix_normals(mesh)
    return mesh


def _ridged_disc(radius: float, depth: float, count: int, samples_per_ridge: int = 8) -> Polygon:
    """Disc whose rim carries ``count`` rounded ridges of radial ``depth`` (knurl, reeding)."""
    t = np.linspace(0, 2 * np.pi, count * samples_per_ridge, endpoint=False)
    r = radius - depth * 0.5 * (1 - np.cos(count * t))
    return Polygon(np.stack([r * np.cos(t), r * np.sin(t)], 1))


def _extrude(poly: Polygon | shapely.MultiPolygon, z0: float, z1: float) -> trimesh.Trimesh:
    """Prism of a (multi)polygon between heights z0 < z1; disjoint pieces stay separate bodies."""
    parts = getattr(poly, "geoms", [poly])
    # the caps triangulated by manifold3d (a sim dependency) by name: trimesh otherwise takes mapbox_earcut where it
    # happens to be installed (other triangles, so other indenter meshes) and fails where neither is (trimesh < 4.4.2)
    mesh = trimesh.util.concatenate([trimesh.creation.extrude_polygon(p, z1 - z0, engine="manifold") for p in parts])
    mesh.apply_translation([0, 0, z0])
    return mesh


def _union(*meshes) -> trimesh.Trimesh:
    return trimesh.boolean.union(list(meshes), engine="manifold")


def _coin(cfg: IndenterConfig):
    """Coin: reeded edge, raised rim and an emblem of letter-like strokes and dots."""
    r, h, t = cfg.size / 2, cfg.relief_mm, 0.12 * cfg.size
    body = _extrude(_ridged_disc(r, 0.02 * cfg.size, cfg.count or 60), -t, 0.0)
    rim = Point(0, 0).buffer(r * 0.97, 128).difference(Point(0, 0).buffer(r * 0.85, 128))
    w = 0.05 * cfg.size
    strokes = [  # an "N", an "L" and a bar: letter-like ridges of varied direction
        box(-0.5 * r, -0.3 * r, -0.5 * r + w, 0.3 * r),
        box(-0.2 * r, -0.3 * r, -0.2 * r + w, 0.3 * r),
        affinity.rotate(box(-0.5 * r, -w / 2, -0.2 * r + w, w / 2), -63, origin="center"),
        box(0.05 * r, -0.3 * r, 0.05 * r + w, 0.3 * r),
        box(0.05 * r, -0.3 * r, 0.4 * r, -0.3 * r + w),
        box(-0.5 * r, -0.55 * r, 0.5 * r, -0.55 * r + w),
    ]
    dots = [Point(0.55 * r * np.cos(a), 0.55 * r * np.sin(a)).buffer(0.04 * cfg.size, 24) for a in (0.6, 1.2, 1.9)]
    emblem = shapely.union_all([rim, *strokes, *dots])
    return _union(body, _extrude(emblem, -0.01 * t, h))


def _cap(cfg: IndenterConfig):
    """Knurled bottle cap: fine ridges round the side, a recessed top inside a rim."""
    r, height = cfg.size / 2, 0.4 * cfg.size
    body = _extrude(_ridged_disc(r, cfg.relief_mm, cfg.count or 48, 6), -height, 0.0)
    recess = _extrude(Point(0, 0).buffer(0.8 * r, 128), -cfg.relief_mm, 0.01 * cfg.size)
    return trimesh.boolean.difference([body, recess], engine="manifold")


def _gear(cfg: IndenterConfig):
    """Spur gear with involute-flank teeth and a bore, face toward +z."""
    outline = _gear_outline(cfg.size / 2, cfg.count or 16)
    bore = Point(0, 0).buffer(0.15 * cfg.size, 64)
    return _extrude(outline.difference(bore), -0.25 * cfg.size, 0.0)


def _gear_outline(r_tip: float, teeth: int, pressure_deg: float = 20.0) -> Polygon:
    m = 2 * r_tip / (teeth + 2)
    rp = m * teeth / 2
    rb, rf = rp * np.cos(np.radians(pressure_deg)), rp - 1.25 * m
    # involute flank from the base circle out to the tip circle, angle measured from the tooth centre
    t_max = np.sqrt((r_tip / rb) ** 2 - 1)
    t = np.linspace(0, t_max, 12)
    rad = rb * np.sqrt(1 + t**2)
    inv = t - np.arctan(t)
    inv_p = np.tan(np.radians(pressure_deg)) - np.radians(pressure_deg)
    half = np.pi / (2 * teeth) + inv_p  # half tooth angle at the base circle
    flank_r = np.concatenate([[max(rf, 0.5 * rb)], rad])
    flank_a = np.concatenate([[half], half - inv])
    pts = []
    for k in range(teeth):
        c = 2 * np.pi * k / teeth
        a = np.concatenate([c - flank_a, (c + flank_a)[::-1]])
        rr = np.concatenate([flank_r, flank_r[::-1]])
        pts.append(np.stack([rr * np.cos(a), rr * np.sin(a)], 1))
    return Polygon(np.concatenate(pts)).buffer(0)


def _key(cfg: IndenterConfig):
    """Flat key: round bow with a hole, blade with bitting cuts on +y and a groove on the +z face."""
    L = cfg.size
    w, t = 0.2 * L, 0.07 * L
    bow_r = 0.17 * L
    x0 = -L / 2 + 2 * bow_r
    blade = box(x0 - 0.05 * L, -w / 2, L / 2, w / 2)
    cuts = [Point(x0 + (0.12 + 0.11 * i) * L, w / 2).buffer((0.03 + 0.015 * (i % 3)) * L, 4) for i in range(5)]
    tip = Polygon([(L / 2 - 0.06 * L, w / 2), (L / 2 + 0.01, w / 2), (L / 2 + 0.01, 0)])
    bow = Point(-L / 2 + bow_r, 0).buffer(bow_r, 96).difference(Point(-L / 2 + bow_r, 0).buffer(0.35 * bow_r, 48))
    outline = shapely.union_all([bow, blade.difference(shapely.union_all([*cuts, tip]))])
    body = _extrude(outline, -t, 0.0)
    groove = _extrude(box(x0 + 0.02 * L, -0.03 * L, L / 2 + 0.01, 0.01 * L), -min(cfg.relief_mm, t / 2), 0.01 * L)
    return trimesh.boolean.difference([body, groove], engine="manifold")


def _brick(cfg: IndenterConfig):
    """LEGO-like 2x4 brick, studs toward +z (pitch = size / 4)."""
    p = cfg.size / 4
    shell = _extrude(box(-2 * p, -p, 2 * p, p), -1.2 * p, 0.0)
    studs = [
        _extrude(Point((i - 1.5) * p, (j - 0.5) * p).buffer(0.3 * p, 64), -0.01 * p, 0.2125 * p)
        for i in range(4)
        for j in range(2)
    ]
    return _union(shell, *studs)


_BUILDERS = {
    "sphere": _sphere,
    "cube": _cube,
    "cylinder": _cylinder,
    "cone": _cone,
    "screw": _screw,
    "coin": _coin,
    "cap": _cap,
    "gear": _gear,
    "key": _key,
    "brick": _brick,
}


def with_mesh_beside(indenter: object, folder: Path) -> object:
    """An indenter mapping whose relative ``mesh`` path is found beside the file that names it.

    A press file or dataset spec naming ``mesh = "indenters/pyramid.stl"`` means the file next to it, wherever
    the command runs; a path that exists from the working directory keeps its meaning (and the spec hash of the
    presses rendered with it). Anything that is not such a mapping comes back unchanged (``from_mapping``
    reports it).

    Parameters
    ----------
    indenter : the raw ``[indenter]`` mapping (any value)
    folder : Path -- the directory of the press file or spec

    Returns
    -------
    the mapping, with ``mesh`` joined to ``folder`` where that is the file meant
    """
    if not isinstance(indenter, dict) or not isinstance(indenter.get("mesh"), str):
        return indenter
    mesh = Path(indenter["mesh"]).expanduser()
    if mesh.is_absolute() or mesh.exists() or not (folder / mesh).exists():
        return indenter
    return indenter | {"mesh": str(folder / mesh)}


def mesh_path_problem(mesh: str | Path) -> str | None:
    """What is wrong with ``mesh`` as an indenter mesh's path (a folder, no such file), naming it; None when it is
    a file (its content is read and checked by the render, :func:`make_indenter`)."""
    path = Path(mesh).expanduser()
    if path.is_dir():
        return f"indenter mesh {path}: a folder, not a mesh file (give one file: {', '.join(MESH_TYPES)})"
    if not path.is_file():
        # the shipped example named without its path (README: "under the installed package"): say where it is
        named_example = path.name in (EXAMPLE_MESH.name, EXAMPLE_MESH.stem)
        hint = f" (the example shipped with nlipscalib is {EXAMPLE_MESH}: --mesh takes a path)" if named_example else ""
        return f"indenter mesh {path}: no such file{hint}"
    return None


def _load_mesh(cfg: IndenterConfig) -> trimesh.Trimesh:
    """Read a user's indenter mesh; it must be a closed solid (small holes are repaired, with a warning)."""
    path = Path(cfg.mesh).expanduser()
    if problem := mesh_path_problem(cfg.mesh):  # checked when the config was made, and now: it may have gone since
        raise ConfigError(problem)
    suffix = path.suffix.lower().lstrip(".")
    if suffix not in MESH_TYPES:
        raise ConfigError(f"indenter mesh {path}: unknown mesh type '.{suffix}' (use {', '.join(MESH_TYPES)})")
    data = path.read_bytes()
    if suffix == "stl" and not _looks_like_stl(data):
        raise ConfigError(f"indenter mesh {path}: not an STL file (neither binary STL nor ASCII 'solid ... facet')")
    if suffix in TEXT_MESH_TYPES and not _is_text(data):
        raise ConfigError(f"indenter mesh {path}: not a .{suffix} file (binary or undecodable bytes)")
    try:
        mesh = trimesh.load(trimesh.util.wrap_as_stream(data), file_type=suffix, force="mesh")
    except ImportError:  # trimesh falls back on optional text-encoding guessers for bytes it cannot decode
        raise ConfigError(f"indenter mesh {path}: not a readable .{suffix} file (undecodable bytes)") from None
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise ConfigError(f"indenter mesh {path}: cannot read it as a .{suffix} mesh ({exc})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0 or not np.all(np.isfinite(mesh.vertices)):
        raise ConfigError(f"indenter mesh {path}: holds no triangles")
    extent = float(np.max(mesh.extents))
    if not extent > 0:
        raise ConfigError(f"indenter mesh {path}: has zero size")
    if not cfg.scale_to_size:
        _check_unscaled_extent(path, extent)
    mesh = _closed_solid(mesh, path)
    if cfg.scale_to_size:
        mesh.apply_scale(cfg.size / extent)
    return mesh


MESH_EXTENT_MM = (0.2, 200.0)
"""Extents (mm) an unscaled indenter mesh may have: smaller than a fifth of a millimetre it cannot dent the gel
visibly (a 6 mm part exported in metres is 0.006 across), larger than 200 mm it is no fingertip indenter (a part
exported in micrometres)."""


def _check_unscaled_extent(path: Path, extent: float) -> None:
    """A mesh read as it is (``scale_to_size = false``) must be in millimetres: one line when its size says
    it is not."""
    lo, hi = MESH_EXTENT_MM
    if lo <= extent <= hi:
        return
    unit = "metres" if extent < lo else "micrometres"
    raise ConfigError(
        f"indenter mesh {path}: its largest extent is {extent:.3g} mm with scale_to_size = false (files are read in "
        f"millimetres; is it in {unit}?): scale it in a mesh editor, or let scale_to_size scale it to indenter.size"
    )


MESH_TYPES = ("stl", "obj", "ply", "off", "glb", "gltf")
"""Mesh files trimesh reads without optional extras."""


TEXT_MESH_TYPES = ("obj", "off", "gltf")


def _is_text(data: bytes) -> bool:
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return b"\x00" not in data


def _looks_like_stl(data: bytes) -> bool:
    """Binary STL (80-byte header, triangle count, 50 bytes per triangle) or ASCII STL."""
    if len(data) >= 84:
        n = int.from_bytes(data[80:84], "little")
        if 84 + 50 * n == len(data):
            return True
    head = data[:1024].lstrip().lower()
    return head.startswith(b"solid") and b"facet" in data[:4096].lower()


def _closed_solid(mesh: trimesh.Trimesh, path: Path) -> trimesh.Trimesh:
    """The mesh as a watertight solid: holes filled and normals fixed if needed (warned), else refused."""
    import logging

    if len(mesh.faces) < 4:
        raise ConfigError(f"indenter mesh {path}: {len(mesh.faces)} triangle(s) cannot enclose a solid")
    if mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0:
        return mesh
    repaired = mesh.copy()
    repaired.merge_vertices()
    trimesh.repair.fill_holes(repaired)
    trimesh.repair.fix_normals(repaired)
    if not (repaired.is_watertight and abs(repaired.volume) > 0):
        open_edges = len(trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1))
        raise ConfigError(
            f"indenter mesh {path}: not a closed solid ({open_edges} open edges) and the holes are too large "
            "to fill; close it in a mesh editor"
        )
    logging.getLogger(__name__).warning(
        "indenter mesh %s was not watertight: holes filled and normals fixed (%d -> %d triangles)",
        path,
        len(mesh.faces),
        len(repaired.faces),
    )
    return repaired


# --- height field of the leading surface --------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class HeightField:
    """Largest local z of indenter material over a regular (x, y) grid of the indenter frame."""

    x0: float
    """x of grid column 0, mm, indenter frame."""
    y0: float
    """y of grid row 0, mm, indenter frame."""
    step: float
    """Grid spacing, mm."""
    z: np.ndarray
    """(NX, NY) float, mm, indenter frame: leading-surface height; -inf where there is no material."""

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        """Leading-surface height at ``xy``.

        Bilinear where the four surrounding samples have material; at the footprint's edge the
        largest of the samples that do, so a vertex there is never left inside the body.

        Parameters
        ----------
        xy : (N, 2) float, mm, indenter frame

        Returns
        -------
        (N,) float, mm, indenter frame; -inf off the footprint
        """
        xy = np.asarray(xy, dtype=float)
        fx = (xy[:, 0] - self.x0) / self.step
        fy = (xy[:, 1] - self.y0) / self.step
        nx, ny = self.z.shape
        inside = (fx >= 0) & (fy >= 0) & (fx < nx - 1) & (fy < ny - 1)
        out = np.full(len(xy), -np.inf)
        i, j = np.floor(fx[inside]).astype(int), np.floor(fy[inside]).astype(int)
        tx, ty = fx[inside] - i, fy[inside] - j
        c = np.stack([self.z[i, j], self.z[i + 1, j], self.z[i, j + 1], self.z[i + 1, j + 1]], 1)
        w = np.stack([(1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty], 1)
        full = np.all(np.isfinite(c), axis=1)
        with np.errstate(invalid="ignore"):
            bilinear = np.einsum("ij,ij->i", np.where(np.isfinite(c), c, 0.0), w)
        out[inside] = np.where(full, bilinear, c.max(axis=1))
        return out

    @property
    def levels(self) -> np.ndarray:
        """Distinct finite heights rounded to 1 µm, mm (for tests and diagnostics)."""
        finite = self.z[np.isfinite(self.z)]
        return np.unique(np.round(finite, 3))


def indenter_heightfield(mesh: trimesh.Trimesh, resolution_mm: float) -> HeightField:
    """Rasterise the indenter's upward-facing triangles: the largest z above each grid point.

    Parameters
    ----------
    mesh : trimesh.Trimesh, mm, indenter frame
    resolution_mm : float, mm
        Grid spacing.

    Returns
    -------
    HeightField
        Padded by one empty (-inf) sample on every side.
    """
    if not resolution_mm > 0:
        raise ConfigError(f"height-field resolution must be > 0, got {resolution_mm}")
    lo, hi = mesh.bounds
    x0, y0 = lo[0] - resolution_mm, lo[1] - resolution_mm
    nx = int(np.ceil((hi[0] - x0) / resolution_mm)) + 2
    ny = int(np.ceil((hi[1] - y0) / resolution_mm)) + 2
    z = np.full((nx, ny), -np.inf)
    tri = mesh.triangles
    # only faces whose projection onto xy has area can be the top surface
    area2 = (tri[:, 1, 0] - tri[:, 0, 0]) * (tri[:, 2, 1] - tri[:, 0, 1]) - (tri[:, 2, 0] - tri[:, 0, 0]) * (
        tri[:, 1, 1] - tri[:, 0, 1]
    )
    tri = tri[np.abs(area2) > 1e-12]
    for chunk in _chunks(tri, x0, y0, resolution_mm):
        _rasterise(z, chunk, x0, y0, resolution_mm)
    return HeightField(x0, y0, resolution_mm, z)


def _chunks(tri: np.ndarray, x0: float, y0: float, step: float, max_pairs: int = 2_000_000):
    """Split triangles so that each chunk tests about ``max_pairs`` (triangle, sample) pairs."""
    i0 = np.ceil((tri[:, :, 0].min(1) - x0) / step).astype(int)
    i1 = np.floor((tri[:, :, 0].max(1) - x0) / step).astype(int)
    j0 = np.ceil((tri[:, :, 1].min(1) - y0) / step).astype(int)
    j1 = np.floor((tri[:, :, 1].max(1) - y0) / step).astype(int)
    ni, nj = np.maximum(i1 - i0 + 1, 0), np.maximum(j1 - j0 + 1, 0)
    group = np.cumsum(ni * nj) // max_pairs
    for g in np.unique(group):
        sel = np.flatnonzero(group == g)
        yield tri[sel], i0[sel], j0[sel], ni[sel], nj[sel]


def _rasterise(z: np.ndarray, chunk: tuple[np.ndarray, ...], x0: float, y0: float, step: float):
    tri, i0, j0, ni, nj = chunk
    n = ni * nj
    t = np.repeat(np.arange(len(tri)), n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    ii, jj = i0[t] + k % ni[t], j0[t] + k // ni[t]
    px, py = x0 + ii * step, y0 + jj * step
    a, b, c = tri[t, 0], tri[t, 1], tri[t, 2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    u = ((px - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (py - a[:, 1])) / det
    v = ((b[:, 0] - a[:, 0]) * (py - a[:, 1]) - (px - a[:, 0]) * (b[:, 1] - a[:, 1])) / det
    eps = 1e-9  # samples on shared edges belong to both triangles: no cracks
    hit = (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps)
    height = a[:, 2] + u * (b[:, 2] - a[:, 2]) + v * (c[:, 2] - a[:, 2])
    np.maximum.at(z, (ii[hit], jj[hit]), height[hit])
