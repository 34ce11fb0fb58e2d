"""The experiment framework without rendering: planning, resume bookkeeping, regression check, CLI errors."""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core.errors import CaptureError
from nlipscalib.core.leds import Led
from nlipscalib.experiments import adapters, check, get
from nlipscalib.experiments.plan import build_tasks
from nlipscalib.experiments.summary import aggregate, clean
from nlipscalib.experiments.tasks import Task, load_result, made_with, result_path


def test_studies_share_one_render_per_distinct_press():
    exp = get("studies")
    cfg = exp.config("quick")
    evaluations = exp.evaluations(cfg)
    tasks = build_tasks(evaluations)
    presses = [t for t in tasks if t.kind == "press"]
    distinct = {json.dumps([s, p], sort_keys=True) for s, p, _, _ in evaluations}
    assert len(presses) == len(distinct) < len(evaluations)
    assert sum(len(t.evaluations) for t in presses) == len(evaluations)
    stages = [t.stage for t in tasks]
    assert stages == sorted(stages)  # references, then calibrations, then presses
    # every scene has its reference; every calibrated LED error its calibration
    assert {t.id for t in tasks if t.kind == "reference"} == {
        f"ref-{k}" for k in {t.id.split("-")[-2] for t in presses}
    }
    assert any(t.kind == "calibration" for t in tasks)


def test_stored_result_is_reused_only_for_the_same_task(tmp_path):
    task = Task(kind="reference", id="ref-x", scene={"a": 1})
    path = result_path(tmp_path, task.id)
    path.parent.mkdir(parents=True)
    record = {"task_hash": task.hash, "status": "done", "made_with": made_with(task.kind)}
    path.write_text(json.dumps(record), encoding="utf-8")
    assert load_result(tmp_path, task) is not None
    changed = Task(kind="reference", id="ref-x", scene={"a": 2})
    assert load_result(tmp_path, changed) is None  # config changed: run again, never reuse stale numbers
    path.write_text(
        '{"task_hash": "', encoding="utf-8"
    )  # torn file (cannot happen with atomic writes, but never trusted)
    assert load_result(tmp_path, task) is None


def test_led_errors_have_the_asked_size():
    leds = (Led(position=(1.0, 2.0, 3.0), direction=(0.0, 0.3, 1.0)), Led(position=(-4.0, 0.0, 2.0)))
    moved = adapters.perturb_leds(leds, position_mm=0.5, direction_deg=5.0, seed=3)
    for a, b in zip(leds, moved):
        assert np.linalg.norm(np.subtract(a.position, b.position)) == pytest.approx(0.5)
        angle = np.degrees(np.arccos(np.clip(np.dot(a.direction, b.direction), -1, 1)))
        assert angle == pytest.approx(5.0, abs=1e-6)
    assert adapters.perturb_leds(leds, 0.5, 5.0, seed=3) == moved  # seeded
    assert adapters.perturb_leds(leds) == leds


def test_aggregate_means_and_failures():
    rows = [
        {"g": "a", "aae_deg": 2.0, "mabse": 0.02, "depth_rmse_mm": 0.1, "roi_aae_deg": 3.0, "error": None},
        {"g": "a", "aae_deg": 4.0, "mabse": 0.04, "depth_rmse_mm": 0.3, "roi_aae_deg": 5.0, "error": None},
        {"g": "a", "aae_deg": float("nan"), "mabse": np.nan, "depth_rmse_mm": np.nan, "error": "no contact"},
    ]
    (row,) = aggregate(rows, ("g",))
    assert (row["n"], row["failed"]) == (2, 1)
    assert row["aae_deg"] == pytest.approx(3.0) and row["aae_deg_std"] == pytest.approx(1.0)
    assert clean({"x": float("nan")}) == {"x": None}


def test_check_flags_only_what_got_worse_beyond_tolerance():
    base = check.baseline_document("q1", "quick", {"s: aae_deg": 5.0, "s: mabse": 0.04, "c: aae_deg": 5.0})
    now = {"s: aae_deg": 5.4, "s: mabse": 0.1, "c: aae_deg": float("nan")}  # within 0.5 deg; worse; missing
    worse = check.compare(now, base)
    assert [w["figure"] for w in worse] == ["s: mabse", "c: aae_deg"]
    assert "s: mabse" in check.format_worse(worse)
    assert check.compare({"s: aae_deg": 1.0, "s: mabse": 0.01, "c: aae_deg": 2.0}, base) == []  # better is fine


def test_a_baseline_of_another_size_is_refused(tmp_path, capsys):
    """A quick run checked against a medium baseline passed without a word (other figures, other numbers)."""
    import json

    base = tmp_path / "base.json"
    base.write_text(json.dumps({"experiment": "q1", "size": "medium", "figures": {}}), encoding="utf-8")
    assert main(["experiment", "q1", "--check", str(base), "--out", str(tmp_path), "--plan"]) == 2
    assert "baseline of size 'medium', this run is 'quick'" in capsys.readouterr().err


def test_a_shipped_baseline_is_named_by_its_name(tmp_path, capsys):
    """--check took a path only: an installed wheel's user had no path to give for the shipped baseline."""
    import argparse

    from nlipscalib.cli import build_parser

    from .conftest import BASELINE

    assert check.baseline_path("q1_quick").read_bytes() == BASELINE.read_bytes()
    assert main(["experiment", "q1", "--check", "q1_quick", "--out", str(tmp_path), "--plan"]) == 0
    capsys.readouterr()
    assert main(["experiment", "q1", "--check", "q1_slow", "--out", str(tmp_path), "--plan"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["nlips experiment: error: baseline 'q1_slow': no such file, nor a shipped baseline (q1_quick)"]
    subs = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert "shipped with nlipscalib (q1_quick)" in " ".join(subs.choices["experiment"].format_help().split())


@pytest.mark.parametrize(
    "argv, message",
    [
        (["experiment", "nope"], "unknown experiment 'nope'"),
        (["experiment", "presses", "--size", "huge"], "unknown size 'huge'"),
        (["experiment", "q1", "--size", "huge"], "unknown size 'huge'"),
        # a mistyped name listed the known ones without the close match (s35-walk)
        (["experiment", "ablaton"], "unknown experiment 'ablaton' (did you mean 'ablation'?) (known: q1, q2,"),
        (["experiment", "q1", "--size", "quik"], "unknown size 'quik' (did you mean 'quick'?) (known: quick,"),
        (["experiment", "q1", "--solver-option", "max_iter=3"], "--solver-option 'max_iter=3'"),
        (["experiment", "q1", "--solver-option", "max_iters=0"], "max_iters"),
        (["experiment", "q1", "--solver-option", "max_iters=abc"], "--solver-option max_iters: expected an integer"),
        (["experiment", "q1", "--scheduler", "local:zero"], "local:N"),
        (["experiment", "q1", "--scheduler", "nowhere"], "tcp://HOST:PORT"),
        (["experiment", "q1", "--check", "/nonexistent/base.json"], "no such baseline file"),
        (["experiment", "q1", "--workers", "0"], "--workers: must be an integer >= 1"),
        # --config replaces --size: both refused, also with --size at its default value
        (["experiment", "q1", "--size", "full", "--config", "q1.toml"], "--size full and --config q1.toml"),
        (["experiment", "q1", "--size", "quick", "--config", "q1.toml"], "--size quick and --config q1.toml"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(argv, message, capsys, tmp_path):
    assert main(argv + ["--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


@pytest.mark.parametrize("scheduler, message", [("garbage", "give tcp://HOST:PORT or local:N"), ("local:0", ">= 1")])
def test_a_malformed_scheduler_is_refused_up_front_with_plan_too(scheduler, message, tmp_path, monkeypatch, capsys):
    """With --plan a malformed --scheduler exited 0 (the run refused it, once its tasks started)."""
    from nlipscalib.experiments import framework

    def ran(*args, **kwargs):
        raise AssertionError("the experiment ran")

    monkeypatch.setattr(framework, "run_experiment", ran)
    for plan in ([], ["--plan"]):
        assert main(["experiment", "q1", "--scheduler", scheduler, "--out", str(tmp_path / "work"), *plan]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("nlips experiment: error: --scheduler") and message in err[0], err
    assert not (tmp_path / "work").exists()


@pytest.mark.parametrize(
    "option, value, message",
    [
        ("--out", "afile", "--out {}: is a file, not a folder"),
        ("--out", "afile/sub", "--out {}: {} is a file, not a folder"),
        ("--report", "afile", "--report {}: is a file, not a folder"),
        ("--report", "apress", "--report {}: is a press folder; choose another --report"),
        ("--write-baseline", ".", "--write-baseline {}: is a folder; give a file name"),
    ],
)
def test_an_output_that_cannot_be_written_is_refused_before_any_work(
    option, value, message, tmp_path, monkeypatch, capsys
):
    """--report onto a file used to fail only when the report was written, after the whole run (hours at full size),
    and --out onto a file named a folder inside it ("afile/q1-quick/tasks: Not a directory")."""
    from nlipscalib.experiments import framework

    def ran(*args, **kwargs):
        raise AssertionError("the experiment ran")

    monkeypatch.setattr(framework, "run_experiment", ran)
    (tmp_path / "afile").write_text("not a folder", encoding="utf-8")
    (tmp_path / "apress").mkdir()
    (tmp_path / "apress" / "meta.json").write_text(
        "{}", encoding="utf-8"
    )  # a capture: its images and the report would mix
    given = tmp_path / value
    argv = ["experiment", "q1", "--out", str(tmp_path / "work"), option, str(given)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"nlips experiment: error: {message.format(given, tmp_path / 'afile')}"]


def test_help_says_what_each_experiment_measures_and_how_long_each_size_takes(capsys):
    from nlipscalib.experiments import EXPERIMENTS, GUIDE

    assert set(GUIDE) == set(EXPERIMENTS)  # a new experiment comes with its line
    with pytest.raises(SystemExit):
        main(["experiment", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for name, (what, took) in GUIDE.items():
        assert f"{name} {' '.join(what.split())}" in text
        assert " / ".join(took[size] for size in ("quick", "medium", "full")) in text


def test_config_file_with_a_typo_names_file_and_key(tmp_path, capsys):
    cfg = tmp_path / "q1.toml"
    cfg.write_text("[twin]\nwidht = 64\n", encoding="utf-8")
    assert main(["experiment", "q1", "--config", str(cfg), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "q1.toml" in err and "widht" in err


@pytest.mark.parametrize(
    "name, text, message",
    [
        ("q1", 'leds = ["trueish"]\n', "leds: must be one of ['true', 'design', 'calibrated'], got 'trueish'"),
        ("q1", 'roi = "bogus"\n', "roi: must be one of ['truth', 'auto', 'full'], got 'bogus'"),
        ("studies", 'correction = "x"\n', "interreflection: must be one of ['off', 'reference', 'dent'], got 'x'"),
        ("ablation", "counts = [1]\n", "the sensor needs 3 to 24 LEDs, got 1"),
        ("ablation", "[presses]\ndepth = [-1.0]\n", "press depth must be > 0 mm, got -1.0"),
        ("q1", "[presses]\npolar_deg = [95.0]\n", "presses.polar_deg: must be in [0, 90) deg"),
        ("q1", "[presses]\ndepth = [50.0]\n", "presses.depth: 50.0 mm exceeds the gel thickness"),
        ("ablation", "counts = []\n", "nothing to run"),
        ("q2", "[train]\nindenters = []\n", "50 presses need at least one indenter, got none"),
        ("q2", "[train]\ncount = -3\n", "count: must be an integer >= 0, got -3"),
        # a PressSet's own field named (it was each press's PressConfig "polar_deg: ... got 94.2", a field not written)
        ("q2", "[unseen]\npolar_max_deg = 120.0\n", ".unseen: polar_max_deg: must be in [0, 90) deg (90 is the"),
    ],
)
def test_a_config_value_the_tasks_cannot_use_is_refused_naming_the_file(name, text, message, tmp_path, capsys):
    """Such values used to pass --plan and the start of a run: an unknown word failed every press after its render
    (leds, roi, interreflection), a scene error did not name the file, an empty indenter list was a traceback."""
    cfg = tmp_path / "exp.toml"
    cfg.write_text(text, encoding="utf-8")
    assert main(["experiment", name, "--config", str(cfg), "--out", str(tmp_path), "--plan"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"nlips experiment: error: {cfg}") and message in err[0], err


def test_a_press_set_past_the_dome_names_its_own_field_from_python():
    """PressSet(polar_max_deg=120) was made, and its presses() then refused "polar_deg: ... got 94.2", PressConfig's
    field, naming neither the set's field nor the value written."""
    from nlipscalib.core.errors import ConfigError
    from nlipscalib.experiments.plan import PressSet

    with pytest.raises(ConfigError, match=r"^polar_max_deg: must be in \[0, 90\) deg .*, got 120\.0$"):
        PressSet(polar_max_deg=120.0)
    assert PressSet(polar_max_deg=89.0, count=40).presses()  # up to the rim: taken


def test_press_count_study_config_names_file_and_problem(tmp_path, capsys):
    cfg = tmp_path / "presses.toml"
    cfg.write_text("counts = [1, 4]\n[net]\nhidden = [8]\n", encoding="utf-8")
    assert main(["experiment", "presses", "--config", str(cfg), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "presses.toml" in err and "counts" in err


def test_plan_counts_tasks_without_running(tmp_path, capsys):
    assert main(["experiment", "all", "--size", "full", "--plan", "--out", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 6 and lines[0].startswith("q1 (full): 74 tasks")  # 72 presses + reference + calibration
    assert "= 1 reference + 1 calibration + 72 presses" in lines[0]  # it said "1 references + 1 calibrations"
    assert not any(tmp_path.iterdir())  # nothing rendered or written


def test_two_processes_on_one_folder_run_a_task_once(tmp_path, monkeypatch):
    import threading
    import time

    from nlipscalib.experiments import tasks as tasks_mod

    calls = []

    def slow_reference(task, out, threads, keep):
        calls.append(task.id)
        time.sleep(1.5)
        return {"folder": "refs/x"}

    monkeypatch.setattr(tasks_mod, "_run_reference", slow_reference)
    task = Task(kind="reference", id="ref-y", scene={"b": 1})
    outcomes = []
    threads = [threading.Thread(target=lambda: outcomes.append(tasks_mod.execute(task, tmp_path))) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    assert calls == ["ref-y"]  # the second waited for the first's result
    assert sorted(outcomes) == ["done", "reused"]  # and counts it as reused, not as run by itself
    assert load_result(tmp_path, task)["folder"] == "refs/x"


def test_ctrl_c_inside_a_native_library_stops_the_sweep_instead_of_failing_the_task(tmp_path, monkeypatch):
    """drjit turns Ctrl-C during a render into its own RuntimeError: the task was recorded as failed (a
    .failed.json) and the sweep went on to the next press, so Ctrl-C did not stop the run."""
    from nlipscalib.experiments import tasks as tasks_mod

    def interrupted_render(task, out, threads, keep):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise RuntimeError("drjit.custom(...): error while performing a custom differentiable operation") from exc

    monkeypatch.setattr(tasks_mod, "_run_reference", interrupted_render)
    task = Task(kind="reference", id="ref-z", scene={"c": 1})
    with pytest.raises(KeyboardInterrupt):
        tasks_mod.execute(task, tmp_path)
    assert not list((tmp_path / "tasks").glob("*.failed.json"))


def _trained(best_epoch: int, epochs: int) -> dict:
    """A model record as learning.train_model stores it (best_epoch 0-based, as the trainer counts)."""
    return {
        "train_presses": ["a", "b", "c"],
        "val_presses": ["d"],
        "epochs": epochs,
        "best_epoch": best_epoch,
        "best_val_aae_deg": 1.5,
        "train_seconds": 2.0,
    }


def test_training_tables_number_the_best_epoch_from_1_like_nlips_train():
    from nlipscalib.experiments.markdown import table

    score = {"split": "seen", "method": "NLiPsNet", "contact_samples": 10, "aae_vs_nlips_deg": 1.0}
    score |= {"aae_vs_true_deg": 2.0, "presses": 1}
    q2_learned = {
        "presses": {"train": 3, "seen": 1, "unseen": 0},
        "scores": [dict(score)],
        "models": {"nlipsnet": _trained(0, 9), "upper": _trained(6, 7)},
    }
    count_learned = {
        "presses": {"train": 3, "seen": 1, "unseen": 0},
        "scores": [{"calibration_presses": 3} | score],
        "models": {3: _trained(4, 12)},
    }
    for name, learned, expected in (("q2", q2_learned, [1, 7]), ("presses", count_learned, [5])):
        exp = get(name)
        training = next(t for t in exp.tables(exp.config("quick"), [], learned) if t.name == "training")
        assert [r["best_epoch_from_1"] for r in training.rows] == expected
        assert all("best_epoch" not in r for r in training.rows)  # no stored key with another meaning
        lines = table(training).splitlines()
        col = lines[2].strip("|").split("|").index(" best epoch ")
        assert [int(row.strip("|").split("|")[col]) for row in lines[4:]] == expected
        # the stored model records keep the trainer's 0-based count (old records stay loadable)
        assert [m["best_epoch"] for m in learned["models"].values()] == [e - 1 for e in expected]


def test_table_headers_name_group_columns_in_words():
    """The press-count study's tables were headed by a row key: "| calibration_presses | split | ..."."""
    from nlipscalib.experiments.framework import Table
    from nlipscalib.experiments.markdown import table

    rows = [{"calibration_presses": 4, "split": "seen", "aae": 1.5}]
    text = table(Table("counts", "caption", ("calibration_presses", "split"), rows, columns=(("aae", "AAE", 2),)))
    assert "| calibration presses | split | AAE |" in text


def test_local_workers_that_likely_exceed_memory_are_warned_about(monkeypatch, caplog):
    """``nlips experiment --workers N``: kept, with a warning sized by the tasks' largest images (whole frames)."""
    from types import SimpleNamespace

    from nlipscalib.core import cpus
    from nlipscalib.experiments import framework

    tasks = [SimpleNamespace(scene={"camera": {"width": w, "height": h}}) for w, h in ((96, 72), (1280, 960))]
    monkeypatch.setattr(cpus, "available_memory", lambda: 8 * 10**9)
    caplog.set_level(logging.INFO, logger="nlipscalib.core.cpus")
    framework._check_memory(tasks, 2)  # 2 x 6.8 GB at 1280x960
    assert "--workers 2: each solve, whole frame worker may take ~6.8 GB at 1280x960" in caplog.text
    caplog.clear()
    framework._check_memory(tasks[:1], 8)  # 8 x 0.2 GB at 96x72: nothing said
    assert caplog.text == ""


@pytest.mark.parametrize(
    "error, is_result",
    [(CaptureError("x: --roi auto found no contact"), True), (OSError(28, "No space left on device"), False)],
)
def test_a_variant_that_fails_on_its_data_is_a_result_a_full_disk_fails_the_task(error, is_result, tmp_path):
    """A solve that raised OSError (the disk full while a CI run wrote its results) was recorded like a variant
    that found no contact: the run said "0 failed" and its study had three NaN points."""
    import types

    from nlipscalib.experiments import tasks as tasks_mod

    def solve(*args, **kwargs):
        raise error

    adapters = types.SimpleNamespace(solve=solve, solver_options=lambda options: None)
    press = types.SimpleNamespace(folder=tmp_path / "press")
    spec = {"leds": "true", "interreflection": "auto", "roi": "auto", "options": {}}
    spec |= {"position_error_mm": 0, "direction_error_deg": 0, "error_seed": 0}
    task = Task(kind="press", id="p-1", scene={"a": 1})
    call = lambda: tasks_mod._solve_one(adapters, tmp_path, task, press, tmp_path / "ref", spec, "k")  # noqa: E731
    if is_result:
        assert "no contact" in call()["result"]["error"]
    else:
        with pytest.raises(OSError, match="No space left"):
            call()


def test_a_task_failed_on_a_full_disk_names_the_file_where_it_goes_not_its_temporary(tmp_path, monkeypatch):
    """`nlips experiment` on a full disk (s25 walk, 4 MB tmpfs) warned "ID: failed: OSError: [Errno 28] No space
    left on device: 'OUT/presses/.tmp-ID~HOST~PID~.../tricolor.png'": a Python repr naming a hidden temporary the
    failure had removed. The task's line and its .failed.json now name the press's file and the cause."""
    import errno
    import os

    from nlipscalib.core.atomic import tmp_prefix
    from nlipscalib.experiments import tasks as tasks_mod

    press = tmp_path / "presses" / "sphere-1"
    inside = press.parent / (tmp_prefix(press.name) + "0123abcd") / "tricolor.png"

    def full_disk(task, out, threads, keep):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(inside))

    task = Task(kind="reference", id="ref-full", scene={"c": 1})
    monkeypatch.setattr(tasks_mod, "_run_reference", full_disk)
    outcome = tasks_mod.execute(task, tmp_path)
    expected = f"{press / 'tricolor.png'}: No space left on device (the disk is full: free space, then run again)"
    assert outcome == f"{tasks_mod.NO_SPACE}{expected}"
    assert json.loads((tmp_path / "tasks" / "ref-full.failed.json").read_text(encoding="utf-8"))["error"] == expected
    assert tasks_mod.failure_text(ValueError("bad")) == "ValueError: bad"  # other errors as before


TINY_ABLATION = """
counts = [12]
[twin]
width = 40
height = 30
spp = 2
bounces = 0
[presses]
indenters = [{ kind = "sphere", size = 6.0 }]
polar_deg = [10.0, 20.0, 30.0]
azimuth_deg = [30.0]
"""
"""One reference task (stage 0) and three press tasks (stage 2)."""


@pytest.mark.parametrize("errno_name", ["ENOSPC", "EDQUOT"])
def test_a_full_disk_stops_the_experiment_after_the_tasks_under_way(errno_name, tmp_path, monkeypatch, capsys):
    """`nlips experiment` on a full disk went on after the first failed task: every later press rendered (seconds
    to minutes each) and then failed too (s25 walk). Now no other task starts, and the run ends with one line
    naming the folder and what to do, exit 2. The run again after freeing space reuses the finished tasks."""
    import errno
    import os

    from nlipscalib.experiments import tasks as tasks_mod

    code = getattr(errno, errno_name)
    started = []

    def full_disk(task, out, threads, keep):
        started.append(task.id)
        raise OSError(code, os.strerror(code), str(out / "refs" / "x" / "led_01.png"))

    def press(task, out, threads, keep):
        started.append(task.id)
        raise AssertionError("no press may start after a full disk")

    monkeypatch.setattr(tasks_mod, "_run_reference", full_disk)
    monkeypatch.setattr(tasks_mod, "_run_press", press)
    config = tmp_path / "tiny.toml"
    config.write_text(TINY_ABLATION, encoding="utf-8")
    out = tmp_path / "out"
    assert main(["--no-progress", "experiment", "ablation", "--config", str(config), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(started) == 1 and started[0].startswith("ref"), started  # the presses never rendered
    assert err[-1] == (
        f"nlips experiment: error: {out / 'ablation-custom'}: no space left on device: free space, then run the "
        "same command again (finished tasks are kept)"
    ), err
    assert not (out / "ablation-custom" / "report" / "report.md").exists()  # no report of a run cut short


def test_other_task_failures_let_the_sweep_go_on(tmp_path, monkeypatch, capsys):
    """Only a full disk stops the sweep: a press that fails for its own reason is one failed task of many."""
    from nlipscalib.experiments import tasks as tasks_mod

    started = []

    def broken_press(task, out, threads, keep):
        started.append(task.id)
        raise ValueError("this press only")

    monkeypatch.setattr(tasks_mod, "_run_reference", lambda task, out, threads, keep: {"folder": "refs/x"})
    monkeypatch.setattr(tasks_mod, "_run_press", broken_press)
    config = tmp_path / "tiny.toml"
    config.write_text(TINY_ABLATION, encoding="utf-8")
    out = tmp_path / "out"
    assert main(["--no-progress", "experiment", "ablation", "--config", str(config), "--out", str(out)]) == 1
    assert len(started) == 3, started  # every press tried
    said = capsys.readouterr()  # stdout: the report's folder; the failures, on stderr (kept by --quiet)
    assert "3 failed" in said.err and said.out == f"{out / 'ablation-custom' / 'report'}\n"


def test_one_process_starts_no_task_of_its_stage_after_a_full_disk(tmp_path, monkeypatch):
    import errno

    from nlipscalib.experiments import tasks as tasks_mod
    from nlipscalib.experiments.runner import run_tasks

    started = []

    def full_disk(task, out, threads, keep):
        started.append(task.id)
        raise OSError(errno.ENOSPC, "No space left on device", str(out / "refs" / task.id / "dark.png"))

    monkeypatch.setattr(tasks_mod, "_run_reference", full_disk)
    status = run_tasks(
        [Task(kind="reference", id=f"ref-{i}", scene={"i": i}) for i in range(3)], tmp_path, progress=False
    )
    assert started == ["ref-0"] and status.no_space and list(status.failed) == ["ref-0"]


def test_local_workers_start_no_task_after_one_failed_on_a_full_disk(tmp_path):
    """`--workers N`: the task another worker runs when one fails on a full disk is finished and recorded; the
    tasks still queued never start."""
    import queue

    from nlipscalib.experiments import runner
    from nlipscalib.experiments.tasks import NO_SPACE

    outcomes = {"t0": f"{NO_SPACE}OUT/presses/t0/led_01.png: No space left on device", "t1": "done"}
    given = []

    class Worker:  # runs its task at once, in this process: the order of the results is the test's
        def __init__(self, slot: int, results: queue.Queue):
            self.slot, self.results, self.alive = slot, results, True

        def put(self, task: Task | None) -> None:
            if task is None:  # the runner's "no more tasks"
                self.alive = False
                return
            given.append(task.id)
            self.results.put((self.slot, task.id, outcomes.get(task.id, "done")))

        def is_alive(self) -> bool:
            return self.alive

        def join(self, timeout: float) -> None:
            pass

    slots = runner._WorkerSlots.__new__(runner._WorkerSlots)
    slots.n, slots.results = 2, queue.Queue()
    slots._start = lambda i: (worker := Worker(i, slots.results), worker)
    status = runner.RunStatus()
    tasks = [Task(kind="press", id=f"t{i}", scene={"i": i}) for i in range(5)]
    slots.run(tasks, status, bar=_NoBar())
    assert given == ["t0", "t1"]  # the two under way when the disk filled; t2-t4 never started
    assert status.no_space and status.done == ["t1"] and list(status.failed) == ["t0"]


class _NoBar:
    def update(self, n: int) -> None:
        pass


def _stored(out: Path, task: Task, made: dict | None, maker: dict | None = None) -> None:
    """A finished result of ``task`` recording ``made`` as its ``made_with`` (None: none, as before 2026-12-06)."""
    path = result_path(out, task.id)
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {"id": task.id, "kind": task.kind, "task_hash": task.hash, "status": "done", "folder": "refs/x"}
    record |= {"made_with": made} if made is not None else {}
    path.write_text(json.dumps(record | ({"made_by": maker} if maker else {})), encoding="utf-8")


def test_a_rerun_after_an_upgrade_makes_again_the_tasks_other_code_or_libraries_made(tmp_path, monkeypatch, caplog):
    # A task's hash holds what it computes, not the code: after an upgrade (new solver, a NumPy release) a rerun
    # reused the old code's numbers beside the new code's in one table, said only in a warning. Now a result made
    # with other code or libraries of its kind, or recording none (before 2026-12-06), is made again, said in one
    # line; --keep-old keeps them, and the report names them.
    from nlipscalib.experiments import framework, markdown
    from nlipscalib.experiments import tasks as tasks_mod
    from nlipscalib.experiments.runner import run_tasks

    ran = []
    monkeypatch.setattr(tasks_mod, "_run_reference", lambda task, out, threads, keep: ran.append(task.id) or {})
    same, unrecorded, code, lib = (Task(kind="reference", id=f"ref-{n}", scene={"n": n}) for n in range(4))
    here = made_with("reference")
    _stored(tmp_path, same, here)
    _stored(tmp_path, unrecorded, None)
    _stored(tmp_path, code, here | {"code": "0" * 32}, {"nlipscalib": "0.1.0", "git_commit": "202cd61"})
    _stored(tmp_path, lib, here | {"libraries": here["libraries"] | {"mitsuba": "3.0.0"}})
    every = [same, unrecorded, code, lib]

    kept = [dataclasses.replace(t, keep_old=True) for t in every]
    assert all(load_result(tmp_path, t) is not None for t in kept)  # --keep-old: all four reused
    with caplog.at_level(logging.WARNING):
        named = framework._made_by_other_software(kept, tmp_path)
    assert set(named) == {"ref-1", "ref-2", "ref-3"}  # the one this code made is not named
    assert "code and libraries unrecorded" in named["ref-1"]
    assert named["ref-2"] == "nlipscalib 0.1.0 at 202cd61: other code (core, sim)"
    assert "mitsuba 3.0.0 (now " in named["ref-3"]
    assert "3 of 4 tasks kept by --keep-old were made by other code or libraries" in caplog.text
    assert "were made by other code or libraries** (kept by `--keep-old`" in markdown._other_software_lines(named)[0]

    caplog.clear()
    with caplog.at_level(logging.WARNING):
        status = run_tasks(every, tmp_path, progress=False)
    assert sorted(ran) == sorted(status.done) == ["ref-1", "ref-2", "ref-3"] and status.skipped == ["ref-0"]
    lines = [r.getMessage() for r in caplog.records if "other code or libraries" in r.getMessage()]
    assert len(lines) == 1 and "3 of 4 tasks made by other code or libraries" in lines[0], lines
    assert "re-running them (--keep-old keeps them)" in lines[0]
    assert all(load_result(tmp_path, t)["made_with"] == here for t in every)  # now all this code's
    assert framework._made_by_other_software(every, tmp_path) == {}


def test_the_plan_counts_tasks_other_code_made_as_to_run_again(tmp_path, capsys):
    # --plan said "N done" of tasks the run would then make again
    from nlipscalib.experiments import get

    exp = get("q1")
    tasks = exp.tasks(exp.config("quick"))
    work = tmp_path / "q1-quick"
    here = made_with(tasks[0].kind)
    _stored(work, tasks[0], here)
    _stored(work, tasks[1], None)  # written before 2026-12-06
    assert main(["experiment", "q1", "--out", str(tmp_path), "--plan"]) == 0
    out = capsys.readouterr().out
    assert "; 1 done in" in out and "(1 more made by other code or libraries: run again; --keep-old" in out
    assert main(["experiment", "q1", "--out", str(tmp_path), "--plan", "--keep-old"]) == 0
    out = capsys.readouterr().out
    assert "; 2 done in" in out and "more made by" not in out


def test_a_task_a_worker_of_other_code_made_is_failed_not_dropped_from_the_tables(tmp_path, monkeypatch):
    # a remote Dask worker with another installation writes its own made_with, which this command does not take:
    # the task counted as done and its rows were missing from the tables without a word
    from nlipscalib.experiments import runner
    from nlipscalib.experiments import tasks as tasks_mod

    monkeypatch.setattr(tasks_mod, "_run_reference", lambda task, out, threads, keep: {})

    def other_worker(task, out, threads=0, keep=False):
        outcome = tasks_mod.execute(task, out, threads, keep)
        path = result_path(out, task.id)
        record = json.loads(path.read_text(encoding="utf-8"))
        record["made_with"]["libraries"]["mitsuba"] = "3.0.0"
        path.write_text(json.dumps(record), encoding="utf-8")
        return outcome

    monkeypatch.setattr(runner, "execute", other_worker)
    task = Task(kind="reference", id="ref-w", scene={})
    status = runner.run_tasks([task], tmp_path, progress=False)
    assert status.done == [] and "made by a worker of other code or libraries (mitsuba 3.0.0" in status.failed["ref-w"]


def test_each_kind_of_task_is_made_again_only_for_the_code_and_libraries_it_depends_on():
    # a solver change must keep the references (renders: the most expensive tasks of a scene); a render change
    # makes everything built on the reference again (calibrations fit its images, presses read it)
    from nlipscalib.experiments.tasks import TASK_CODE, TASK_LIBRARIES

    assert "solver" not in TASK_CODE["reference"] and {"core", "sim"} <= set(TASK_CODE["reference"])
    assert set(TASK_CODE["reference"]) < set(TASK_CODE["calibration"]) < set(TASK_CODE["press"])
    assert {"solver", "pipeline"} <= set(TASK_CODE["press"]) and "learn" not in TASK_CODE["press"]
    assert made_with("press", samples=True)["code"] != made_with("press")["code"]  # NLiPsNet's samples: + learn/
    assert set(TASK_LIBRARIES["reference"]) == {"mitsuba", "drjit"}
    assert {"numpy", "scipy", "pyamg", "mitsuba"} <= set(TASK_LIBRARIES["press"])
    assert made_with("reference")["code"] != made_with("press")["code"]
    assert Task(kind="reference", id="r", scene={}).hash == Task(kind="reference", id="r", scene={}, keep_old=True).hash


def test_error_map_rows_are_titled_with_the_contact_aae_of_the_report(tmp_path):
    """The Q1/Q3 error-map sheets showed maps without a number to read them by: each row's title now ends with its
    evaluation's contact AAE (the report tables' aae_deg); an evaluation without one adds no line."""
    import numpy as np

    from nlipscalib.experiments.common import map_rows

    (tmp_path / "maps").mkdir()
    n = np.zeros((2, 2, 3))
    np.savez(tmp_path / "maps" / "a.npz", true=n, estimate=n, error=np.zeros((2, 2)))
    rows = [
        {"indenter": "sphere", "press": "sphere-p5", "aae_deg": 0.4355, "map": "maps/a.npz"},
        {"indenter": "cube", "press": "cube-p5", "aae_deg": None, "map": "maps/a.npz"},
    ]
    titles = [r[0] for r in map_rows(rows, tmp_path, ("indenter",))]
    assert titles == ["sphere\nsphere-p5\ncontact AAE 0.44 deg", "cube\ncube-p5"]
