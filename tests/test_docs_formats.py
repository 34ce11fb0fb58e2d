"""docs/formats.md names every top-level key the writers put into the JSON files it describes."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np

from nlipscalib.core import Camera, Led, SensorResponse, write_press
from nlipscalib.learn.dataset import SamplingConfig, write_index

FORMATS = Path(__file__).resolve().parents[1] / "docs" / "formats.md"


def _section(start: str, end: str) -> str:
    text = FORMATS.read_text()
    return text[text.index(start) : text.index(end)]


def _undocumented(keys, section: str) -> list[str]:
    named = set(re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", section))
    return sorted(set(keys) - named)


def test_every_index_json_key_is_documented(tmp_path):
    write_index(tmp_path, {"camera": {}}, SamplingConfig(), [], str(tmp_path))
    index = json.loads((tmp_path / "index.json").read_text())
    section = _section("# Calibration dataset", "# NLiPsNet model file")
    assert _undocumented(index, section) == []
    assert _undocumented(index["sampling"], section) == []
    assert {"reference", "software_version"} <= set(index)  # the two keys the document once left out
    assert [f.name for f in dataclasses.fields(SamplingConfig)] == list(index["sampling"])


def test_every_meta_json_key_is_documented(tmp_path):
    camera = Camera(4, 3, 2.0, 2.0, 1.5, 1.0, "brown", (0.0,) * 5)
    leds = [Led((float(i), 0.0, -1.0)) for i in range(3)]
    img = np.zeros((3, 4, 3), np.uint16)
    folder = write_press(tmp_path / "p", camera, leds, SensorResponse(), img, np.stack([img] * 3), img)
    meta = json.loads((folder / "meta.json").read_text())
    section = _section("## meta.json", "## reference.npz")
    assert _undocumented(meta, section) == []
    assert _undocumented(meta["sensor"], section) == []
    assert _undocumented(meta["camera"], section) == []
    assert _undocumented(meta["leds"][0], section) == []


def test_the_dataset_spec_section_documents_every_key_and_its_example_loads(tmp_path):
    """A lab's own spec (`nlips dataset SPEC`) had no description outside the source: the README's "or a spec file
    of yours" left a new user reading dataset_spec.py to make even a small try-out."""
    from nlipscalib.sim.dataset import DatasetSpec, GridSpec, RandomSpec, expand_jobs, load_dataset_spec

    section = _section("# Dataset spec", "# Reconstruction format")
    for cls in (DatasetSpec, GridSpec, RandomSpec):
        assert _undocumented([f.name for f in dataclasses.fields(cls)], section) == [], cls.__name__
    (example,) = re.findall(r"```toml\n(.*?)```", section, re.S)
    (tmp_path / "tiny.toml").write_text(example)
    spec, scene = load_dataset_spec(tmp_path / "tiny.toml")
    jobs = expand_jobs(spec)
    assert [j.name for j in jobs] == ["reference"] + [f"press_{i:04d}" for i in range(1, 7)]  # as the text says
    assert (scene.camera.width, scene.camera.height, scene.render.bounces) == (160, 120, 1)
