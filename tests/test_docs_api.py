"""docs/api.md: every ```python block runs, in order, in one namespace, so the page cannot rot.

The page's first block sets the paths a user sets to their own; here the same names point at a tiny exact-data
sensor (tests/solver/synth.py, 64x48, no rendering), its model trained as tests/learn/test_infer.py's ``tiny_model``
is (seconds), a folder of its tri-colour frames as the camera, and an in-process virtual LED board as the port. The
twin block renders two 64x48 presses with Mitsuba (a few seconds).
"""

from __future__ import annotations

import ast
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

API = Path(__file__).resolve().parents[1] / "docs" / "api.md"
N_FRAMES = 3
"""Frames of the test's 'camera' folder: the page's loops read N_FRAMES of them."""


def python_blocks(text: str) -> list[tuple[int, str]]:
    """(line of the block's first code line in the page, code) of every ```python block, in order."""
    fences = re.finditer(r"^```python\n(.*?)^```", text, re.S | re.M)
    return [(text.count("\n", 0, m.start(1)) + 1, m.group(1)) for m in fences]


def assigned_names(code: str) -> set[str]:
    """The names a block assigns at its top level."""
    return {t.id for node in ast.parse(code).body if isinstance(node, ast.Assign) for t in node.targets}


def run_block(line: int, code: str, namespace: dict) -> None:
    """Run one block in ``namespace``; a traceback names docs/api.md and the page's own line numbers."""
    exec(compile("\n" * (line - 1) + code, str(API), "exec"), namespace)


@pytest.fixture(scope="module")
def tiny_sensor(tmp_path_factory) -> dict:
    """The page's path variables: an unsolved exact-data press, its reference, three solved presses (PRESSES), a tiny
    model of its sensor, a folder of tri-colour frames (CAMERA), N_FRAMES, and OUT (PORT is the test's own virtual
    board)."""
    from nlipscalib.learn.dataset import CalibrationDataset, build_dataset
    from nlipscalib.learn.train import train
    from nlipscalib.pipeline import solve_folder
    from nlipscalib.solver import SolverOptions
    from tests.learn.test_resume import NAMES, TINY
    from tests.solver import synth

    root = tmp_path_factory.mktemp("docs_api")
    synth.make_press(root / "reference", "none", size=(64, 48))
    for name, kind in zip(NAMES, ("sphere", "cube", "sphere")):
        synth.make_press(root / name, kind, size=(64, 48))
        solve_folder(root / name, options=SolverOptions(max_iters=6), figures=False, progress=False)
    build_dataset([root / n for n in NAMES], root / "reference", root / "calib", progress=False)
    train(CalibrationDataset(root / "calib"), TINY, root / "model.pt", progress=False)
    synth.make_press(root / "press", "cube", depth=1.8, size=(64, 48))  # not seen in training, not solved
    frames = root / "frames"
    frames.mkdir()
    for i, name in enumerate([*NAMES, "press"][:N_FRAMES]):
        shutil.copy(root / name / "tricolor.png", frames / f"frame_{i:02d}.png")
    return {
        "PRESS": root / "press",
        "REFERENCE": root / "reference",
        "PRESSES": [root / n for n in NAMES],
        "MODEL": root / "model.pt",
        "CAMERA": str(frames),
        "N_FRAMES": N_FRAMES,
        "OUT": root / "out",
    }


def test_the_first_block_sets_the_paths_the_examples_read(tiny_sensor):
    """The page's 'set these' block names exactly the variables the test sets (PORT: the test's virtual board)."""
    (line, code), *_ = python_blocks(API.read_text(encoding="utf-8"))
    assert assigned_names(code) == set(tiny_sensor) | {"PORT"}
    namespace = {}
    run_block(line, code, namespace)  # valid as written: plain paths and numbers
    assert namespace["N_FRAMES"] >= 1


def test_every_python_block_of_the_page_runs_in_order(tiny_sensor):
    pytest.importorskip("torch")
    pytest.importorskip("cv2")
    pytest.importorskip("mitsuba")  # the twin block renders; .ci/run turns this skip into a failure
    from nlipscalib.device.virtual_board import VirtualBoard

    blocks = python_blocks(API.read_text(encoding="utf-8"))
    assert len(blocks) >= 9  # every section's example was found (a fence change would otherwise pass silently)
    out = tiny_sensor["OUT"]
    before = process_settings()
    with VirtualBoard(12) as board:
        namespace = dict(tiny_sensor, PORT=board.url)
        for line, code in blocks[1:]:
            run_block(line, code, namespace)
        assert not board.latched.any()  # the camera blocks switched the LEDs off when they ended
    assert (out / "nlips" / "result.npz").is_file() and (out / "nlips_points.ply").is_file()
    assert (
        (out / "leds.json").is_file()
        and (out / "model.pt").is_file()
        and set(namespace["statuses"].values()) == {"solved"}
    )  # solved again: with the calibrated LEDs, other settings than the fixture's
    assert (out / "twin" / "sphere" / "meta.json").is_file() and (out / "nlipsnet_points.ply").is_file()
    assert sorted(p.name for p in (out / "stream").glob("*.npz")) == ["frame_000000.npz"]  # every 10th of 3 frames
    frame = namespace["frame"]
    assert frame.depth.shape == (48, 64) and np.isfinite(namespace["depth_at_centre"])
    assert namespace["stats"].frames == N_FRAMES
    assert namespace["contact"]["aae_deg"] < 10  # the solve ran and was scored (exact data: far below this)
    assert process_settings() == before  # a notebook that ran the page keeps its own settings


def process_settings() -> dict:
    """What a library must leave as the user's process had it: logging's root, signal handlers, torch's and BLAS's
    thread counts, NumPy's print and error settings, the standard streams."""
    import logging
    import signal
    import sys

    import torch
    from threadpoolctl import threadpool_info

    root = logging.getLogger()
    return {
        "root logger": (list(root.handlers), root.level, root.disabled),
        "signals": [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)],
        "torch threads": torch.get_num_threads(),
        "blas threads": sorted((i["filepath"], i["num_threads"]) for i in threadpool_info()),
        "numpy": (np.get_printoptions(), np.geterr()),
        "streams": (sys.stdout, sys.stderr),
    }


def test_the_page_links_only_files_that_exist():
    links = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", API.read_text(encoding="utf-8"))
    assert links and [link for link in links if not (API.parent / link).exists()] == []


def test_a_mesh_indenter_is_scaled_to_its_size_unless_told_to_keep_the_files_millimetres(tmp_path):
    """The page: ``kind="mesh"`` scales the file's largest extent to ``size`` unless ``scale_to_size=False``."""
    import trimesh

    from nlipscalib.sim.indenters import IndenterConfig, make_indenter

    part = tmp_path / "part.stl"
    trimesh.creation.box(extents=(4.0, 2.0, 1.0)).export(part)  # mm: 4 mm its largest extent
    scaled = make_indenter(IndenterConfig(kind="mesh", mesh=str(part)))  # size: its default
    assert max(scaled.extents) == pytest.approx(IndenterConfig().size, rel=1e-6)
    kept = make_indenter(IndenterConfig(kind="mesh", mesh=str(part), scale_to_size=False))
    assert max(kept.extents) == pytest.approx(4.0, rel=1e-6)


def test_every_keyword_the_pages_give_solve_press_is_one_it_takes():
    """api.md names ``solve_press(..., check_sensor=False)``, ``reorder_leds=False`` and the pipeline's
    ``solver_keywords={"check_sensor": False}`` (s28): a renamed keyword would reach the solve as a TypeError."""
    import inspect

    from nlipscalib.solver import press

    root = API.parents[1]
    pages = [root / "README.md", *sorted((root / "docs").glob("*.md"))]
    text = "\n".join(page.read_text(encoding="utf-8") for page in pages)
    calls = re.findall(r"solve_press\(([^)]*)\)", text)
    named = {k for call in calls for k in re.findall(r"(\w+)=", call)}
    named |= {k for d in re.findall(r"solver_keywords=\{([^}]*)\}", text) for k in re.findall(r"\"(\w+)\":", d)}
    assert len(calls) >= 4 and "indirect" in named  # the pages were read
    assert sorted(named - set(inspect.signature(press._solve_press).parameters)) == []


PAGE_EXTRA_NAMES = {
    "VirtualBoard": "nlipscalib.device.virtual_board",
    "solve_folder": "nlipscalib.pipeline",
    "AdalightController": "nlipscalib.device.adalight",
}
"""Bare names the pages call inline that api.md's blocks do not import: the module each is from."""


def _callable_named(name: str, imported: dict[str, str]):
    """The object a page's inline call names: ``nlipscalib.x.f`` / ``x.f`` (a subpackage) or a bare name that api.md's
    blocks import (or PAGE_EXTRA_NAMES lists); None for anything else (``torch.load``)."""
    import importlib

    parts = name.removeprefix("nlipscalib.").split(".")
    if len(parts) == 1:
        module = imported.get(name) or PAGE_EXTRA_NAMES.get(name)
        return getattr(importlib.import_module(module), name) if module else None
    for cut in range(len(parts) - 1, 0, -1):
        try:
            obj = importlib.import_module("nlipscalib." + ".".join(parts[:cut]))
        except ImportError:
            continue
        for part in parts[cut:]:
            obj = getattr(obj, part)  # a missing one: the page names what is not there
        return obj
    return None


def test_every_keyword_an_inline_call_of_the_pages_gives_is_one_the_callable_takes():
    """s32-docwalk: the pages' prose calls (``Predictor(MODEL, threads=2)``, ``CameraSettings(...,
    linear_gamma=False)``, ``VirtualBoard(n, baudrate=57600)``, ``calibrate_leds``' ``led_radius``, ...) are run by no
    block; a renamed keyword would reach a lab's script as a TypeError. solve_press has its own test above."""
    import inspect

    imported = {
        alias.asname or alias.name: node.module
        for _, code in python_blocks(API.read_text(encoding="utf-8"))
        for node in ast.parse(code).body
        if isinstance(node, ast.ImportFrom) and node.module.startswith("nlipscalib")
        for alias in node.names
    }
    root = API.parents[1]
    pages = [root / "README.md", *sorted((root / "docs").rglob("*.md"))]
    checked, unknown = set(), {}
    for page in pages:
        for span in re.findall(r"`([^`\n]+)`", page.read_text(encoding="utf-8")):
            for name, args in re.findall(r"([A-Za-z_][\w.]*)\(([^()]*(?:\([^()]*\)[^()]*)*)\)", span):
                keywords = re.findall(r"(?<![=\w])(\w+)=(?!=)", args)
                target = _callable_named(name, imported) if keywords else None
                if target is None:
                    continue
                parameters = inspect.signature(target).parameters
                if any(p.kind is p.VAR_KEYWORD for p in parameters.values()):
                    continue
                checked.add(name.rsplit(".", 1)[-1])
                if wrong := [k for k in keywords if k not in parameters]:
                    unknown[f"{page.name}: {name}({args})"] = wrong
    assert {"Predictor", "CameraSettings", "VirtualBoard", "calibrate_leds", "solve_presses"} <= checked  # read
    assert unknown == {}
