"""Many presses from one spec: a grid (indenters x locations x depths) or a seeded random draw.

Rendering is parallel (worker processes, each with its share of the cores) and resumable: a press
whose folder is complete is never rendered again, and interrupted writes leave only ``.tmp-*``
folders, which are cleaned before the run.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from ..config import from_mapping, read_config_file
from ..core.atomic import clean_interrupted, write_json
from ..core.capture import is_press_folder
from ..errors import ConfigError
from .indent import IndenterConfig, PressConfig
from .scene import SceneConfig, load_scene

log = logging.getLogger(__name__)
REFERENCE_NAME = "reference"


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
    random: RandomSpec | None = None

    def __post_init__(self):
        if (self.grid is None) == (self.random is None):
            raise ConfigError("give exactly one of [grid] and [random]")


@dataclasses.dataclass(frozen=True)
class PressJob:
    name: str
    press: PressConfig | None
    seed: int


def load_dataset_spec(path: str | Path) -> tuple[DatasetSpec, SceneConfig]:
    """Read a dataset spec file and the scene it names (render/noise/camera overrides applied)."""
    path = Path(path)
    spec = from_mapping(DatasetSpec, read_config_file(path), str(path))
    scene_path = path.parent / spec.scene
    scene = load_scene(scene_path if scene_path.is_file() else spec.scene)
    sections = {k: v for k, v in (("render", spec.render), ("noise", spec.noise), ("camera", spec.camera)) if v}
    return spec, scene.replace(**sections) if sections else scene


def expand_jobs(spec: DatasetSpec) -> list[PressJob]:
    """The presses of a spec, in a fixed order, each with its own seed."""
    presses = _grid_presses(spec.grid) if spec.grid else _random_presses(spec.random, spec.seed)
    seeds = np.random.SeedSequence(spec.seed).generate_state(len(presses) + 1)
    jobs = [PressJob(f"press_{i:04d}", p, int(s)) for i, (p, s) in enumerate(zip(presses, seeds[1:]))]
    if spec.reference:
        jobs.insert(0, PressJob(REFERENCE_NAME, None, int(seeds[0])))
    return jobs


def run_dataset(scene: SceneConfig, jobs: list[PressJob], out: str | Path, workers: int = 0, progress=True) -> dict:
    """Render every job not yet done into ``out``; returns {"rendered", "skipped", "failed"} lists.

    Parameters
    ----------
    workers : processes (0 = one per two cores, at least 1); each gets cores // workers threads.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for stale in clean_interrupted(out):
        log.info("removed interrupted write %s", stale.name)
    todo = [j for j in jobs if not is_press_folder(out / j.name)]
    result = {"rendered": [], "skipped": [j.name for j in jobs if j not in todo], "failed": []}
    if not todo:
        return result
    cores = os.cpu_count() or 1
    workers = min(len(todo), workers or max(1, cores // 2))
    threads = max(1, cores // workers)
    scene = scene.replace(render={"threads": threads})
    bar = _progress(len(jobs), len(result["skipped"]), progress)
    if workers == 1:
        for job in todo:
            _record(result, job.name, _run_one, (scene, job, out), bar)
    else:
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
            futures = {pool.submit(_render_job, scene, job, out): job for job in todo}
            for fut in as_completed(futures):
                _record(result, futures[fut].name, fut.result, (), bar)
    bar.close()
    return result


def write_manifest(out: Path, spec: DatasetSpec, scene: SceneConfig, jobs: list[PressJob]) -> None:
    """A JSON list of the dataset's presses beside them (what was asked, not what finished)."""
    from ..config import to_mapping

    write_json(
        out / "dataset.json",
        {
            "spec": to_mapping(spec),
            "scene": scene.to_dict(),
            "presses": [{"name": j.name, "seed": j.seed, "press": to_mapping(j.press)} for j in jobs],
        },
    )


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


def _render_job(scene: SceneConfig, job: PressJob, out: Path) -> str | None:
    """Worker body: returns None on success, else the error text (errors must not kill the pool)."""
    try:
        _run_one(scene, job, out)
        return None
    except Exception as exc:  # reported per press; the other presses go on
        return f"{type(exc).__name__}: {exc}"


def _run_one(scene: SceneConfig, job: PressJob, out: Path) -> None:
    from .press import render_press

    render_press(scene, job.press, out / job.name, seed=job.seed)


def _record(result: dict, name: str, call, args, bar) -> None:
    try:
        error = call(*args)
    except Exception as exc:
        error = f"{type(exc).__name__}: {exc}"
    if error:
        result["failed"].append((name, error))
        log.error("%s failed: %s", name, error)
    else:
        result["rendered"].append(name)
    bar.update(1)


def _progress(total: int, done: int, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=done, unit="press", desc="rendering", disable=not enabled)
