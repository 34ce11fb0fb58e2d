"""Pressing an indenter into the gel dome: a quasi-static, geometric deformation model.

The indenter moves along the inward surface normal at the press point by ``depth``. Every gel
vertex that would end up inside it must move along that press axis at least onto the indenter's
leading surface (its height field): that is the ``push``. The gel's displacement is the shape of a
thin plate on an elastic foundation (cotangent Laplacian of the curved, refined mesh) that stays
on or ahead of the indenter (an obstacle problem, solved with a primal-dual active set) and is held
at zero ``SPREAD_PER_THICKNESS * thickness`` beyond the footprint and on the dome's rim. The gel so
touches the indenter where it must, lifts off it tangentially, and fades into the undeformed dome
over about ``DRAPE_PER_THICKNESS * thickness``. ``max(drape, push)`` is taken last so the gel never
penetrates the indenter.

The mesh is refined (pymeshlab's conformal midpoint subdivision, new vertices projected onto the
analytic dome) to ``contact_edge_length`` around the footprint so that textures such as coin relief show.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import threading

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import trimesh
from scipy.spatial import cKDTree

from ..core.errors import ConfigError
from ..core.sensor import DomeConfig
from ..core.tolerances import CONTACT_MM, NORMAL_EPS
from .dome import check_dome, dome_surface_point, make_dome, project_to_dome
from .indenters import HeightField, IndenterConfig, indenter_heightfield, make_indenter, mesh_file_stamp

SPREAD_PER_THICKNESS = 2.0
"""The gel's deformation fades to zero this many gel thicknesses beyond the indenter's footprint."""
REFINE_MARGIN_PER_THICKNESS = 0.33
"""The finest mesh reaches this many gel thicknesses beyond the footprint (the steep draping zone)."""
DRAPE_PER_THICKNESS = 0.5
"""Decay length of the gel's draping around a contact, in gel thicknesses (plate on elastic foundation)."""
TOUCH_MM = 1e-4
"""A contact vertex whose displacement equals the indenter's push within this (mm) touches it."""


@dataclasses.dataclass(frozen=True)
class PressConfig:
    """One press of an indenter into the gel."""

    indenter: IndenterConfig = IndenterConfig()
    """What presses."""
    polar_deg: float = 0.0
    """Where: polar angle from the dome's axis (+z) of the ray from the dome-frame origin, degrees."""
    azimuth_deg: float = 0.0
    """Where: azimuth of that ray from +x toward +y, degrees."""
    spin_deg: float = 0.0
    """Rotation of the indenter about the press axis, degrees (0: local x along the azimuthal direction)."""
    depth: float = 1.0
    """How far the indenter moves into the gel past first touch, mm (0 < depth <= dome thickness)."""

    def __post_init__(self):
        """Each field within its range, refused here in one ConfigError naming it (``polar_deg: must be in [0, 90)
        deg ...``), not when the render reaches it: a script's ``PressConfig(polar_deg=200)`` was said to be "off the
        dome" by the render, after its scene was set up (s36-apileft). The depth's upper bound is the scene's gel
        thickness, checked by the render (:func:`deform_gel`)."""
        if not isinstance(self.indenter, IndenterConfig):
            raise ConfigError(f"indenter: must be an IndenterConfig, got {type(self.indenter).__name__}")
        for name in ("polar_deg", "azimuth_deg", "spin_deg", "depth"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real):
                raise ConfigError(f"{name}: must be a number, got {value!r}")
        check_polar("polar_deg", self.polar_deg)
        for name in ("azimuth_deg", "spin_deg"):
            if not math.isfinite(getattr(self, name)):
                raise ConfigError(f"{name}: must be a finite angle in degrees, got {getattr(self, name)!r}")
        if not self.depth > 0:  # also NaN
            raise ConfigError(f"press depth must be > 0 mm, got {self.depth}")


def check_polar(where: str, value: float) -> float:
    """``value`` a polar angle on the dome, in [0, 90) deg (``core.dome.dome_surface_point``'s limit: 90 deg is
    the base rim, whose ray leaves the dome); else a ConfigError naming ``where`` (an option or spec key)."""
    if not 0.0 <= value < 90.0:  # also NaN
        raise ConfigError(f"{where}: must be in [0, 90) deg (90 is the dome's open base), got {value!r}")
    return value


@dataclasses.dataclass(frozen=True, eq=False)
class DeformedGel:
    """The gel surface under a press (dome frame, mm)."""

    mesh: trimesh.Trimesh
    """Deformed surface, dome frame, mm; faces wound inward, smooth area-weighted inward vertex normals."""
    displacement: np.ndarray
    """(V,) float, mm, along ``press_axis``: how far each vertex moved."""
    contact: np.ndarray
    """(V,) bool: vertex displaced by more than ``CONTACT_MM``."""
    touching: np.ndarray
    """(V,) bool: vertex lies on the indenter's surface."""
    indenter_mesh: trimesh.Trimesh
    """Indenter posed at full depth, dome frame, mm."""
    press_point: np.ndarray
    """(3,) float, mm, dome frame: where the indenter first touches the undeformed surface."""
    press_axis: np.ndarray
    """(3,) float, unit, dome frame: direction of motion = inward normal at ``press_point``."""
    rotation: np.ndarray
    """(3, 3) float: columns are the indenter frame's x, y, z axes in the dome frame."""
    tip: np.ndarray
    """(3,) float, mm, dome frame: indenter-frame origin at full depth (press_point + depth * press_axis)."""


def press_frame(dome_cfg: DomeConfig, press: PressConfig) -> tuple[np.ndarray, np.ndarray]:
    """Press point and the indenter frame's axes.

    Returns
    -------
    point : (3,) float, mm, dome frame
    rotation : (3, 3) float, columns x, y, z of the indenter frame in the dome frame (z = press axis)
    """
    point, axis = dome_surface_point(dome_cfg, press.polar_deg, press.azimuth_deg)
    ph = np.radians(press.azimuth_deg)
    east = np.array([-np.sin(ph), np.cos(ph), 0.0])  # perpendicular to every meridian plane
    east -= axis * (east @ axis)
    east /= np.linalg.norm(east)
    north = np.cross(axis, east)
    sp_ = np.radians(press.spin_deg)
    x = np.cos(sp_) * east + np.sin(sp_) * north
    return point, np.stack([x, np.cross(axis, x), axis], 1)


def apply_press(dome_cfg: DomeConfig, press_cfg: PressConfig) -> DeformedGel:
    """Deform the dome under one press.

    Parameters
    ----------
    dome_cfg : DomeConfig
    press_cfg : PressConfig

    Returns
    -------
    DeformedGel

    Raises
    ------
    ConfigError
        Press off the dome, footprint crossing the base rim or pad edge, depth <= 0 or deeper than
        the gel, or a bad indenter.
    """
    check_dome(dome_cfg)
    if press_cfg.depth > dome_cfg.thickness:
        raise ConfigError(f"press depth {press_cfg.depth} mm exceeds the gel thickness {dome_cfg.thickness} mm")
    point, rot = press_frame(dome_cfg, press_cfg)
    tip = point + press_cfg.depth * rot[:, 2]
    hf = _heightfield(press_cfg.indenter, dome_cfg.contact_edge_length / 2, mesh_file_stamp(press_cfg.indenter))
    footprint = _footprint_radius(hf, press_cfg.depth)
    dome = make_dome(dome_cfg)
    vertices, faces = _refine_near(dome_cfg, dome.vertices, dome.faces, point, footprint + press_cfg.depth)
    push = _push(hf, vertices, tip, rot)
    boundary = _boundary_vertices(faces, len(vertices))
    if np.any(push[boundary] > 0) or _footprint_off_dome(dome_cfg, hf, press_cfg.depth, tip, rot):
        raise ConfigError(
            f"the indenter's footprint ({footprint:.2f} mm) at polar {press_cfg.polar_deg} deg crosses the dome's "
            "base rim / pad edge: press nearer the apex or use a smaller indenter"
        )
    spread = footprint + press_cfg.depth + SPREAD_PER_THICKNESS * dome_cfg.thickness
    free = (np.linalg.norm(vertices - point, axis=1) < spread) & (push <= 0) & ~boundary
    disp = _drape(vertices, faces, dome.faces, push, free, DRAPE_PER_THICKNESS * dome_cfg.thickness)
    moved = vertices + disp[:, None] * rot[:, 2]
    mesh = trimesh.Trimesh(moved, faces, vertex_normals=_vertex_normals(moved, faces), process=False)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, tip
    return DeformedGel(
        mesh=mesh,
        displacement=disp,
        contact=disp > CONTACT_MM,
        touching=(push > 0) & (disp - push <= TOUCH_MM),
        indenter_mesh=make_indenter(press_cfg.indenter).apply_transform(pose),
        press_point=point,
        press_axis=rot[:, 2].copy(),
        rotation=rot,
        tip=tip,
    )


@functools.lru_cache(maxsize=32)
def _heightfield(cfg: IndenterConfig, resolution: float, stamp: tuple[int, int] | None = None) -> HeightField:
    """Cached per indenter, resolution and mesh file stamp (:func:`mesh_file_stamp`: an edited file is read again)."""
    if cfg.kind == "sphere":
        return _sphere_heightfield(cfg.size / 2, resolution)
    return indenter_heightfield(make_indenter(cfg), resolution)


def _sphere_heightfield(radius: float, step: float) -> HeightField:
    """Exact sphere cap: the faceted mesh would print its facets into the gel's normals."""
    n = int(np.ceil(radius / step)) + 2
    g = np.arange(-n, n + 1) * step
    r2 = g[:, None] ** 2 + g[None, :] ** 2
    with np.errstate(invalid="ignore"):
        z = np.where(r2 <= radius**2, np.sqrt(radius**2 - r2) - radius, -np.inf)
    return HeightField(float(g[0]), float(g[0]), step, z)


def _footprint_radius(hf: HeightField, depth: float) -> float:
    """Largest distance from the press axis of indenter material that can reach the gel, mm."""
    reach = hf.z > -depth
    if not reach.any():
        return 0.0
    i, j = np.nonzero(reach)
    r = np.hypot(hf.x0 + i * hf.step, hf.y0 + j * hf.step)
    return float(r.max() + hf.step)


def _footprint_off_dome(dome_cfg: DomeConfig, hf: HeightField, depth: float, tip: np.ndarray, rot: np.ndarray) -> bool:
    """Whether indenter material that reaches the gel lies below the base plane or beside the flat pad."""
    i, j = np.nonzero(hf.z > -depth)
    local = np.stack([hf.x0 + i * hf.step, hf.y0 + j * hf.step, hf.z[i, j]], 1)
    world = tip + local @ rot.T
    if dome_cfg.shape == "flat":
        return bool(np.any(np.abs(world[:, :2]) > dome_cfg.radius))
    return bool(np.any(world[:, 2] < 0))


def _push(hf: HeightField, vertices: np.ndarray, tip: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """(V,) float, mm: how far along the press axis each vertex must move to leave the indenter (0 if outside)."""
    local = (vertices - tip) @ rot
    with np.errstate(invalid="ignore"):
        push = hf(local[:, :2]) - local[:, 2]
    return np.where(np.isfinite(push) & (push > 0), push, 0.0)


def _refine_near(dome_cfg: DomeConfig, vertices: np.ndarray, faces: np.ndarray, centre: np.ndarray, radius: float):
    """Subdivide faces near ``centre`` until their edges reach ``contact_edge_length``.

    Coarser levels reach further out, so each level's transition lies on faces that
    the next level leaves alone and the grading stays smooth.
    """
    levels = max(0, int(np.ceil(np.log2(dome_cfg.edge_length / dome_cfg.contact_edge_length))))
    reach = radius + REFINE_MARGIN_PER_THICKNESS * dome_cfg.thickness
    edge = dome_cfg.edge_length
    for _ in range(levels):
        centres = vertices[faces].mean(axis=1)
        mask = np.linalg.norm(centres - centre, axis=1) < reach + 3 * edge
        n_old = len(vertices)
        vertices, faces = _subdivide(vertices, faces, mask)
        vertices[n_old:] = project_to_dome(dome_cfg, vertices[n_old:])
        edge /= 2
    return vertices, faces


def _subdivide(vertices: np.ndarray, faces: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One conformal midpoint-subdivision step of the masked faces (pymeshlab); no T-junctions remain.

    pymeshlab keeps the old vertices first, in order, and appends the edge midpoints, which the
    coarse-to-fine draping relies on.
    """
    import pymeshlab

    with _PYMESHLAB:
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces, f_scalar_array=mask.astype(np.float64)))
        ms.compute_selection_by_condition_per_face(condselect="fq > 0.5")
        ms.meshing_surface_subdivision_midpoint(iterations=1, threshold=pymeshlab.PercentageValue(0.0), selected=True)
        mesh = ms.current_mesh()
        return np.asarray(mesh.vertex_matrix(), dtype=np.float64), np.asarray(mesh.face_matrix(), dtype=np.int64)


_PYMESHLAB = threading.Lock()
"""Held while pymeshlab works: two indentations at once in one process (a Dask worker started with
``--nthreads 2``) failed a press with "PyMeshLabException ... std::bad_alloc" (s26-dasklogs). A subdivision is
milliseconds of a render's seconds, so one at a time costs nothing."""


def _boundary_vertices(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """(V,) bool: vertex on an edge used by one face only (the dome's base rim, the pad's edge)."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    once = edges[trimesh.grouping.group_rows(edges, require_count=1)]
    out = np.zeros(n_vertices, bool)
    out[once.ravel()] = True
    return out


def _drape(
    vertices: np.ndarray, faces: np.ndarray, coarse_faces: np.ndarray, push: np.ndarray, free: np.ndarray, length: float
):
    """Thin-plate draping of the gel around the contact: (V,) float, mm, along the press axis.

    The gel's displacement d minimises the discrete energy of a thin plate on an elastic foundation,
    d^T (L^T M^-1 L + M / length^4) d (cotangent Laplacian L, lumped mass M of the curved mesh),
    subject to d >= push (no penetration), with d = 0 outside ``free`` and ``push > 0``. This
    obstacle problem is solved by a primal-dual
    active-set loop on the unrefined mesh ``coarse_faces`` (fast), whose contact set then
    fixes the fine vertices for one solve on the refined mesh. The gel so leaves the indenter
    tangentially where it lifts off and meets the undeformed dome with zero slope.
    """
    out = push.copy()
    if not free.any() or not (push > 0).any():
        return out
    region = free | (push > 0)
    n_coarse = int(coarse_faces.max()) + 1  # refinement appends vertices: the coarse ones come first
    coarse_push = _restrict_max(vertices, push, region, n_coarse)
    lap_c, mass_c = _cotan_laplacian(vertices[:n_coarse], coarse_faces)
    active_c = _active_set(_plate(lap_c, mass_c, length), coarse_push, region[:n_coarse])
    nearest = cKDTree(vertices[:n_coarse]).query(vertices[region])[1]
    fixed = np.zeros(len(vertices), bool)
    fixed[np.flatnonzero(region)] = active_c[nearest]
    fixed &= push > 0
    unknown = region & ~fixed
    lap, mass = _cotan_laplacian(vertices, faces)
    out[unknown] = _solve(_plate(lap, mass, length), np.where(fixed, push, 0.0), unknown)
    # the plate may overshoot between held ridges; no gel moves further than the indenter pushes it
    return np.maximum(np.minimum(out, push.max()), push)


def _plate(lap: sp.csr_matrix, mass: np.ndarray, length: float):
    """Stiffness of a thin plate on an elastic foundation: L^T M^-1 L + M / length^4.

    The foundation (the gel's own elasticity over its rigid shell) confines the deformation to
    about ``length`` around the contact, as a soft layer on a rigid backing does.
    """
    return (lap.T @ sp.diags(1.0 / mass) @ lap + sp.diags(mass / length**4)).tocsr()


def _solve(q: sp.csr_matrix, known: np.ndarray, unknown: np.ndarray):
    """Values on ``unknown`` minimising x^T q x with the rest held at ``known``.

    The system is symmetric positive definite, so SuperLU runs in its symmetric mode: a minimum-degree ordering
    of A^T + A and pivots on the diagonal. ``spsolve``'s default (COLAMD, partial pivoting) fills the factors
    ~1.5x as much and took twice as long on the refined mesh's solve (57k unknowns under a screw: 3.4 s against
    1.6 s), which is most of a press's draping; the answer agrees to ~1e-11 mm (benchmarks/RESULTS.md, s18-j).
    """
    ui = np.flatnonzero(unknown)
    rhs = -(q[ui] @ known)
    lu = spla.splu(
        q[ui][:, ui].tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
    )
    return lu.solve(rhs)


def _active_set(q: sp.csr_matrix, obstacle: np.ndarray, region: np.ndarray, max_iter: int = 30):
    """(n,) bool: where the minimiser of x^T q x subject to x >= obstacle on ``region`` (x = 0 elsewhere) touches."""
    active = region & (obstacle > 0)
    for _ in range(max_iter):
        x = np.where(active, obstacle, 0.0)
        x[region & ~active] = _solve(q, x, region & ~active)
        force = q @ x  # contact force; must be >= 0 where the gel is held
        tol = 1e-9 * np.abs(force).max()
        new = region & ((active & (force > -tol)) | (~active & (x < obstacle - 1e-9)))
        if np.array_equal(new, active):
            break
        active = new
    return active


def _restrict_max(vertices: np.ndarray, values: np.ndarray, region: np.ndarray, n_coarse: int):
    """(n_coarse,) float: the largest value of ``values`` among region vertices nearest each coarse vertex."""
    idx = np.flatnonzero(region)
    nearest = cKDTree(vertices[:n_coarse]).query(vertices[idx])[1]
    out = np.zeros(n_coarse)
    np.maximum.at(out, nearest, values[idx])
    return out


def _cotan_laplacian(vertices: np.ndarray, faces: np.ndarray):
    """Cotangent stiffness matrix (V, V), positive semi-definite, and lumped vertex areas (V,) mm^2."""
    n = len(vertices)
    tri = vertices[faces]
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j = faces[:, (k + 1) % 3], faces[:, (k + 2) % 3]  # the edge opposite corner k
        e1 = tri[:, (k + 1) % 3] - tri[:, k]
        e2 = tri[:, (k + 2) % 3] - tri[:, k]
        cross = np.linalg.norm(np.cross(e1, e2), axis=1)
        cot = np.einsum("ij,ij->i", e1, e2) / np.maximum(cross, NORMAL_EPS)
        rows += [i, j]
        cols += [j, i]
        vals += [-cot / 2, -cot / 2]
    w = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
    lap = w - sp.diags(np.asarray(w.sum(axis=1)).ravel())
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1) / 2
    mass = np.bincount(faces.ravel(), np.repeat(area / 3, 3), minlength=n)
    return lap, np.maximum(mass, NORMAL_EPS)


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) float, unit: area-weighted mean of the (inward) face normals."""
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # |cross| = 2 * area
    acc = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(acc, faces[:, k], cross)
    return acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), NORMAL_EPS)
