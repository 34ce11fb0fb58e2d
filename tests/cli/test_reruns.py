"""Honest re-runs: the same spec skips, a changed spec is an error (or a re-render with --overwrite)."""

from __future__ import annotations

import json

import pytest

from nlipscalib.cli import main
from nlipscalib.sim import dataset as ds
from tests.cli.test_faults import SPEC, _fake_render


def test_dataset_rerun_with_changed_spec_is_not_silent(tmp_path, monkeypatch, capsys):
    spec, out = tmp_path / "spec.toml", tmp_path / "out"
    spec.write_text(SPEC)
    calls = []
    monkeypatch.setattr(ds, "_run_one", _fake_render(calls))
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1", "--limit", "2"]) == 0
    manifest = (out / "dataset.json").read_text()
    assert len(json.loads(manifest)["presses"]) == 5  # the whole spec, whatever --limit renders
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 0
    assert "3 rendered, 2 already there" in capsys.readouterr().out

    spec.write_text(SPEC.replace("spp = 1", "spp = 2"))
    calls.clear()
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert str(out) in err and "different scene or spec" in err and "--overwrite" in err
    assert calls == [] and (out / "dataset.json").read_text() == manifest  # nothing touched

    monkeypatch.setattr(ds, "_run_one", _overwriting_render(calls))
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1", "--overwrite"]) == 0
    assert len(calls) == 5 and (out / "dataset.json").read_text() != manifest


def _overwriting_render(calls):
    render = _fake_render(calls)

    def again(scene, job, out, overwrite=False):
        import shutil

        assert overwrite
        shutil.rmtree(out / job.name)
        render(scene, job, out)

    return again


def test_render_rerun_same_spec_skips_changed_spec_refuses(tmp_path, capsys):
    pytest.importorskip("mitsuba")
    out = tmp_path / "p"
    args = ["render", "--width", "32", "--height", "24", "--spp", "1", "--out", str(out)]
    assert main(args) == 0
    stamp = (out / "meta.json").stat().st_mtime_ns
    assert main(args) == 0
    assert "nothing to do" in capsys.readouterr().out
    assert (out / "meta.json").stat().st_mtime_ns == stamp
    assert main([*args, "--depth", "0.7"]) == 2
    assert "different scene, press or seed" in capsys.readouterr().err
    assert main([*args, "--depth", "0.7", "--overwrite"]) == 0
    assert json.loads((out / "meta.json").read_text())["provenance"]["press"]["depth"] == 0.7


def test_press_from_before_spec_hashes_is_recognised():
    """Folders written before spec_hash existed: the hash is recomputed from their provenance."""
    from nlipscalib.config import to_mapping
    from nlipscalib.sim.indent import PressConfig
    from nlipscalib.sim.press import recorded_spec_hash, render_spec_hash
    from nlipscalib.sim.scene import load_scene

    scene, press = load_scene(), PressConfig(depth=0.8)
    old = {"scene": scene.replace(render={"threads": 7}).to_dict(), "press": to_mapping(press), "seed": 42}
    assert recorded_spec_hash(old) == render_spec_hash(scene, press, 42)
    assert recorded_spec_hash({**old, "seed": 43}) != render_spec_hash(scene, press, 42)
    assert recorded_spec_hash({"source": "device"}) is None
