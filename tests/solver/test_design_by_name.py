"""Captures made before the sensor design was recorded: ``nlips capture`` wrote only its name
(``provenance.design = "nlipstac"``) until 2026-12-04, and the interreflection term then left the dome beyond
the view out (benchmarks/RESULTS.md: 2.37 deg instead of 0.53). A shipped name is now resolved to its design.

One tiny render (80x60, one bounce) relabelled the way each version of ``nlips capture`` writes a device capture:
with the design's sections (now), with its name only (before), with the name of a design that does not ship.
"""

import dataclasses
import json
import shutil

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.sim.indent import PressConfig  # noqa: E402
from nlipscalib.sim.indenters import IndenterConfig  # noqa: E402
from nlipscalib.sim.press import render_press  # noqa: E402
from nlipscalib.sim.scene import load_scene  # noqa: E402
from nlipscalib.solver import SolverOptions, reuse, solve_press  # noqa: E402

SPHERE = PressConfig(IndenterConfig(kind="sphere", size=6.0), polar_deg=15, azimuth_deg=30, depth=1.5)
DEVICE_META = {
    "sections": {"design": dataclasses.asdict(load_scene("nlipstac").design)},  # nlips capture since 2026-12-04
    "name": {},  # before: the design's name alone
    "unknown": {},
}
NAMES = {"sections": "nlipstac", "name": "nlipstac", "unknown": "mysensor"}


def relabel(folder, dest, label):
    """A copy of the render ``folder`` at ``dest`` whose meta.json is a device capture's as ``label`` writes it:
    no scene in the provenance, the design by name, and the design's sections for ``sections``."""
    shutil.copytree(folder, dest)
    meta = json.loads((dest / "meta.json").read_text(encoding="utf-8"))
    meta["provenance"] = {"source": "device", "design": NAMES[label]}
    meta |= DEVICE_META[label]
    (dest / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    return load_press(dest)


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    """The sphere press solved with each relabelled reference: label -> the solve's result."""
    root = tmp_path_factory.mktemp("design_by_name")
    sc = load_scene("nlipstac").replace(
        render={"bounces": 1, "spp": 4}, camera={"width": 80, "height": 60}, noise={"enabled": False}
    )
    reference = render_press(sc, None, root / "reference", seed=3)
    press = load_press(render_press(sc, SPHERE, root / "press", seed=4))
    solved = {}
    for label in DEVICE_META:
        with pytest.MonkeyPatch.context() as mp:  # each its own fit: none served from another's (same images)
            mp.setenv("NLIPS_CACHE_DIR", "off")
            reuse.clear()
            indirect = relabel(reference, root / label, label)
            options = SolverOptions(max_iters=20)
            solved[label] = solve_press(press, indirect=indirect, interreflection="on", options=options)
    reuse.clear()
    return solved


def test_a_capture_naming_a_shipped_design_is_solved_with_its_dome(solved):
    by_name, sections = solved["name"], solved["sections"]
    term = by_name.report["interreflection"]
    assert term["off_view_dome"], term["reason"]
    assert "sensor design taken by name: the shipped 'nlipstac'" in term["reason"]
    assert term["kappa"] == sections.report["interreflection"]["kappa"]
    np.testing.assert_array_equal(by_name.normals, sections.normals)  # as if it had recorded the sections
    assert "taken by name" not in sections.report["interreflection"]["reason"]


def test_a_capture_naming_a_design_that_does_not_ship_keeps_the_warning(solved):
    term = solved["unknown"].report["interreflection"]
    assert not term["off_view_dome"]
    assert "no sensor design in the capture: the dome beyond the view is not modelled" in term["reason"]
    assert "'mysensor', which does not ship with nlipscalib" in term["reason"]
    assert not np.array_equal(solved["unknown"].normals, solved["sections"].normals)  # the weaker model
