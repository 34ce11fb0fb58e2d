"""Honest re-runs: the same spec skips, a changed spec is an error (or a re-render with --overwrite)."""

from __future__ import annotations

import json
import logging

import pytest

from nlipscalib.cli import main
from nlipscalib.sim import dataset_pool
from tests.cli.test_faults import SPEC, _fake_render


def test_dataset_rerun_with_changed_spec_is_not_silent(tmp_path, monkeypatch, capsys):
    spec, out = tmp_path / "spec.toml", tmp_path / "out"
    spec.write_text(SPEC, encoding="utf-8")
    calls = []
    monkeypatch.setattr(dataset_pool, "_run_one", _fake_render(calls))
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1", "--limit", "2"]) == 0
    assert calls == ["reference", "press_0001", "press_0002"]  # --limit counts presses; the reference comes too
    manifest = (out / "dataset.json").read_text(encoding="utf-8")
    assert len(json.loads(manifest)["presses"]) == 5  # the whole spec, whatever --limit renders
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 0
    assert "2 presses rendered, 2 presses and the undeformed reference already there" in capsys.readouterr().err

    spec.write_text(SPEC.replace("spp = 1", "spp = 2"), encoding="utf-8")
    calls.clear()
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert str(out) in err and "different scene or spec" in err and "--overwrite" in err
    assert calls == [] and (out / "dataset.json").read_text(encoding="utf-8") == manifest  # nothing touched

    monkeypatch.setattr(dataset_pool, "_run_one", _overwriting_render(calls))
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1", "--overwrite"]) == 0
    assert len(calls) == 5 and (out / "dataset.json").read_text(encoding="utf-8") != manifest


def test_dataset_rerenders_a_press_folder_without_meta_json(tmp_path, monkeypatch, capsys, caplog):
    spec, out = tmp_path / "spec.toml", tmp_path / "out"
    spec.write_text(SPEC, encoding="utf-8")
    calls = []
    monkeypatch.setattr(dataset_pool, "_run_one", _fake_render(calls))
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 0
    (out / "press_0003" / "meta.json").unlink()  # an interrupted copy: images, no meta.json
    (out / "press_0003" / "led_01.png").write_bytes(b"partial")
    calls.clear()
    capsys.readouterr()
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 0
    captured = capsys.readouterr()
    assert "1 press rendered, 3 presses and the undeformed reference already there, 0 failed" in captured.err
    assert calls == ["press_0003"] and (out / "press_0003" / "meta.json").is_file()
    assert not (out / "press_0003" / "led_01.png").exists()  # the old folder went, not merged
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("press_0003" in w and "no meta.json" in w for w in warnings), warnings
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == []  # no temporary or claim left


def test_dataset_leaves_an_incomplete_folder_a_live_process_works_in(tmp_path, monkeypatch, capsys, caplog):
    from nlipscalib.core.claims import claim

    spec, out = tmp_path / "spec.toml", tmp_path / "out"
    spec.write_text(SPEC, encoding="utf-8")
    calls = []
    monkeypatch.setattr(dataset_pool, "_run_one", _fake_render(calls))
    (out / "press_0002").mkdir(parents=True)
    (out / "press_0002" / "dark.png").write_bytes(b"x")
    with claim(out / "press_0002" / "nlips") as mine:  # a live process working inside it
        assert mine
        assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 1
    err = capsys.readouterr().err
    said = err + caplog.text  # the counts name the press; its error is said once, logged (ERROR) as it happens
    assert "press_0002" in err and ".claim-nlips" in said and "run again" in said
    assert "press_0002" not in calls and (out / "press_0002" / "dark.png").read_bytes() == b"x"
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 0  # released: rendered now
    assert calls.count("press_0002") == 1 and (out / "press_0002" / "meta.json").is_file()


def test_dataset_names_a_damaged_meta_json(tmp_path, monkeypatch, capsys):
    spec, out = tmp_path / "spec.toml", tmp_path / "out"
    spec.write_text(SPEC, encoding="utf-8")
    calls = []
    monkeypatch.setattr(dataset_pool, "_run_one", _fake_render(calls))
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 0
    (out / "press_0003" / "meta.json").write_text("{\n", encoding="utf-8")
    (out / "dataset.json").unlink()  # with it, the press is the dataset's own and rendered again (test_dataset.py)
    calls.clear()
    capsys.readouterr()
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert str(out / "press_0003" / "meta.json") in err and "not valid JSON" in err
    assert "different scene or spec" not in err and "--overwrite" in err and "delete" in err
    assert calls == []
    monkeypatch.setattr(dataset_pool, "_run_one", _overwriting_render(calls))
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "1", "--overwrite"]) == 0
    assert calls == ["press_0003"] and json.loads((out / "press_0003" / "meta.json").read_text(encoding="utf-8"))


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
    assert "nothing to do" in capsys.readouterr().err
    assert (out / "meta.json").stat().st_mtime_ns == stamp
    assert main([*args, "--depth", "0.7"]) == 2
    assert "different scene, press or seed" in capsys.readouterr().err
    assert main([*args, "--depth", "0.7", "--overwrite"]) == 0
    assert json.loads((out / "meta.json").read_text(encoding="utf-8"))["provenance"]["press"]["depth"] == 0.7


def test_press_from_before_spec_hashes_is_recognised():
    """Folders written before spec_hash existed: the hash is recomputed from their provenance."""
    from nlipscalib.core.config import to_mapping
    from nlipscalib.sim.indent import PressConfig
    from nlipscalib.sim.press import recorded_spec_hash, render_spec_hash
    from nlipscalib.sim.scene import load_scene

    scene, press = load_scene(), PressConfig(depth=0.8)
    old = {"scene": scene.replace(render={"threads": 7}).to_dict(), "press": to_mapping(press), "seed": 42}
    assert recorded_spec_hash(old) == render_spec_hash(scene, press, 42)
    assert recorded_spec_hash({**old, "seed": 43}) != render_spec_hash(scene, press, 42)
    assert recorded_spec_hash({"source": "device"}) is None
