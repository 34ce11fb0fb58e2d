"""A dataset spec: what to render (a grid of indenters x locations x depths x spins, or a seeded random draw),
read from a TOML/YAML file, checked, and expanded to one job per press, each with its own seed."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np

from ..core.config import check_count, check_range, check_size_pair, from_mapping, read_config_file
from ..core.errors import ConfigError
from ..core.press_meta import REFERENCE_FOLDER
from .indent import IndenterConfig, PressConfig
from .scene import SceneConfig, load_scene

REFERENCE_NAME = REFERENCE_FOLDER  # the name every folder of presses uses (core.capture)
FIRST_PRESS = 1
"""Number of a dataset's first press (``press_0001``): presses count from 1, as a capture session's do and as LEDs
do (docs/conventions.md), so the first press of a rendered dataset and of a captured session have one name.
Datasets rendered before this numbered from 0; their folders keep it (:func:`.dataset_manifest.first_press_number`)."""


@dataclasses.dataclass(frozen=True)
class GridSpec:
    """Every combination of the listed values."""

    indenters: tuple[IndenterConfig, ...]
    """Indenters to press."""
    polar_deg: tuple[float, ...] = (0.0,)
    """Press locations: polar angles from the dome axis, degrees."""
    azimuth_deg: tuple[float, ...] = (0.0,)
    """Press locations: azimuths from +x toward +y, degrees."""
    depth: tuple[float, ...] = (1.0,)
    """Indentation depths, mm."""
    spin_deg: tuple[float, ...] = (0.0,)
    """Rotations of the indenter about the press axis, degrees."""

    def __post_init__(self):
        _check_values(self, ranges=False)


@dataclasses.dataclass(frozen=True)
class RandomSpec:
    """``count`` presses drawn uniformly from the ranges, with the dataset's seed."""

    count: int
    """Number of presses."""
    indenters: tuple[IndenterConfig, ...]
    """Indenters to choose from (uniformly)."""
    polar_deg: tuple[float, float] = (0.0, 30.0)
    """Range of polar angles, degrees."""
    azimuth_deg: tuple[float, float] = (0.0, 360.0)
    """Range of azimuths, degrees."""
    depth: tuple[float, float] = (0.3, 1.5)
    """Range of depths, mm."""
    spin_deg: tuple[float, float] = (0.0, 360.0)
    """Range of spins, degrees."""

    def __post_init__(self):
        check_count("count", self.count, minimum=1)
        _check_values(self, ranges=True)
        for name in ("polar_deg", "azimuth_deg", "depth", "spin_deg"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ConfigError(f"{name}: the range [{lo}, {hi}] is empty (low > high)")


def _check_values(spec: GridSpec | RandomSpec, ranges: bool) -> None:
    """Shared range checks of grid values (``ranges`` False) and random ranges (True): polar angles, depths,
    indenters."""
    from .indent import check_polar

    min_count = 2 if ranges else 1
    if not spec.indenters:
        raise ConfigError("indenters: give at least one indenter")
    for name in ("polar_deg", "azimuth_deg", "depth", "spin_deg"):
        if len(getattr(spec, name)) < min_count:
            raise ConfigError(f"{name}: give at least {min_count} value(s)")
    # every grid angle is pressed; a random range's high end only bounds the draw (uniform in [low, high))
    ends = spec.polar_deg[:1] if ranges else spec.polar_deg
    for v in ends:
        check_polar("polar_deg", v)
    for v in spec.polar_deg:
        check_range("polar_deg", v, 0.0, 90.0)
    for v in spec.depth:
        check_range("depth", v, 0.0, open_lo=True)


@dataclasses.dataclass(frozen=True)
class DatasetSpec:
    """What to render; exactly one of ``grid`` and ``random``."""

    scene: str = "nlipstac"
    """Scene file (relative to the spec file) or shipped scene name."""
    seed: int = 0
    """Seed of the random draw and of each press's render noise."""
    reference: bool = True
    """Also render the undeformed dome (folder ``reference``), e.g. for LED calibration."""
    render: dict = dataclasses.field(default_factory=dict)
    """Overrides of the scene's [render] section, e.g. {spp = 16, bounces = 1}."""
    noise: dict = dataclasses.field(default_factory=dict)
    """Overrides of the scene's [noise] section."""
    camera: dict = dataclasses.field(default_factory=dict)
    """Overrides of the scene's [camera] section, e.g. {width = 160, height = 120} for previews."""
    grid: GridSpec | None = None
    """``[grid]``: every combination of the listed indenters, locations, depths and spins (or None)."""
    random: RandomSpec | None = None
    """``[random]``: ``count`` presses drawn from ranges with the spec's ``seed`` (or None)."""

    def __post_init__(self):
        if (self.grid is None) == (self.random is None):
            raise ConfigError("give exactly one of [grid] and [random]")
        check_count("seed", self.seed, minimum=0)


@dataclasses.dataclass(frozen=True)
class PressJob:
    name: str
    press: PressConfig | None
    seed: int


def load_dataset_spec(path: str | Path) -> tuple[DatasetSpec, SceneConfig]:
    """Read a dataset spec file and the scene it names (render/noise/camera overrides applied)."""
    path = Path(path)
    spec = from_mapping(DatasetSpec, _meshes_beside(read_config_file(path), path.parent), str(path))
    scene_path = path.parent / spec.scene
    try:
        scene = load_scene(scene_path if scene_path.is_file() else spec.scene)
    except ConfigError as exc:  # an unknown scene name: the spec file that names it is the one to edit
        message = str(exc)
        raise ConfigError(message if message.startswith(str(path)) else f"{path}: {message}") from None
    sections = {k: v for k, v in (("render", spec.render), ("noise", spec.noise), ("camera", spec.camera)) if v}
    # one side alone kept the scene's other: [camera] width = 160 rendered 160x480 presses without a word
    size = (scene.camera.width, scene.camera.height)
    check_size_pair(spec.camera.get("width"), spec.camera.get("height"), size, "{}", " = ", ", ", f"{path}: [camera] ")
    try:
        scene = scene.replace(**sections) if sections else scene
    except ConfigError as exc:  # an override out of range: name the spec file, not the scene
        raise ConfigError(f"{path}: {str(exc).removeprefix('scene.')}") from None
    _check_presses(spec, scene, path)
    return spec, scene


def _meshes_beside(data: dict, folder: Path) -> dict:
    """The raw spec with relative indenter mesh paths found beside the spec file (``indenters.with_mesh_beside``)."""
    from .indenters import with_mesh_beside

    for mode in ("grid", "random"):
        section = data.get(mode)
        if isinstance(section, dict) and isinstance(section.get("indenters"), list):
            indenters = [with_mesh_beside(ind, folder) for ind in section["indenters"]]
            data = data | {mode: section | {"indenters": indenters}}
    return data


def _check_presses(spec: DatasetSpec, scene: SceneConfig, path: Path) -> None:
    """Cheap checks of every press against the scene, so a bad one fails now, naming the spec file."""
    from .indenters import make_indenter

    mode = "grid" if spec.grid else "random"
    for i, ind in enumerate((spec.grid or spec.random).indenters):
        if ind.kind == "mesh":
            try:
                make_indenter(ind)
            except ConfigError as exc:
                raise ConfigError(f"{path}: {mode}.indenters[{i}]: {exc}") from None
    depths = spec.grid.depth if spec.grid else spec.random.depth
    if max(depths) > scene.dome.thickness:
        raise ConfigError(f"{path}: {mode}.depth: {max(depths)} mm exceeds the gel thickness {scene.dome.thickness} mm")


def expand_jobs(spec: DatasetSpec, first: int = FIRST_PRESS) -> list[PressJob]:
    """The presses of a spec, in a fixed order, each with its own seed, named ``press_0001``, ... (from ``first``:
    0 for a folder rendered before presses were numbered from 1, :func:`.dataset_manifest.first_press_number`)."""
    presses = _grid_presses(spec.grid) if spec.grid else _random_presses(spec.random, spec.seed)
    seeds = np.random.SeedSequence(spec.seed).generate_state(len(presses) + 1)
    jobs = [PressJob(f"press_{first + i:04d}", p, int(s)) for i, (p, s) in enumerate(zip(presses, seeds[1:]))]
    if spec.reference:
        jobs.insert(0, PressJob(REFERENCE_NAME, None, int(seeds[0])))
    return jobs


def limit_presses(jobs: list[PressJob], limit: int) -> list[PressJob]:
    """The reference (if any) and the first ``limit`` presses of ``jobs`` (``--limit`` counts presses only)."""
    presses = [j.name for j in jobs if j.press is not None][:limit]
    return [j for j in jobs if j.press is None or j.name in presses]


# ---------------------------------------------------------------------- internals
def _grid_presses(grid: GridSpec) -> list[PressConfig]:
    combos = itertools.product(grid.indenters, grid.polar_deg, grid.azimuth_deg, grid.depth, grid.spin_deg)
    return [
        PressConfig(indenter=ind, polar_deg=polar, azimuth_deg=az, spin_deg=spin, depth=depth)
        for ind, polar, az, depth, spin in combos
    ]


def _random_presses(spec: RandomSpec, seed: int) -> list[PressConfig]:
    rng = np.random.default_rng(seed)
    u = lambda lo_hi: float(rng.uniform(*lo_hi))  # noqa: E731
    return [
        PressConfig(
            indenter=spec.indenters[int(rng.integers(len(spec.indenters)))],
            polar_deg=u(spec.polar_deg),
            azimuth_deg=u(spec.azimuth_deg),
            spin_deg=u(spec.spin_deg),
            depth=u(spec.depth),
        )
        for _ in range(spec.count)
    ]
