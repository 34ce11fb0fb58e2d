"""Each experiment's quick variant end to end through the CLI (tiny renders: 96x72 px, 8 spp, the reference at 64)."""

from __future__ import annotations

import json
import math

import pytest

from nlipscalib.cli import main


def _finite_numbers(doc: dict) -> list[float]:
    return [e["aae_deg"] for e in doc["evaluations"] if e["aae_deg"] is not None and math.isfinite(e["aae_deg"])]


def test_q1_quick_writes_report_json_and_passes_the_stored_baseline(q1, capsys):
    out, _, code = q1
    assert code == 0
    report = out / "q1-quick" / "report"
    doc = json.loads((report / "results.json").read_text(encoding="utf-8"))
    assert doc["software"]["nlipscalib"] and doc["machine"]["cores"] >= 1
    assert doc["config"]["twin"]["width"] == 96 and doc["size"] == "quick"
    assert doc["paper"]["aae_deg"] == 7.04
    assert len(_finite_numbers(doc)) == 4  # sphere and cube, true and self-calibrated LEDs
    assert {(e["indenter"], e["leds"]) for e in doc["evaluations"]} == {
        (i, s) for i in ("sphere", "cube") for s in ("true", "calibrated")
    }
    text = (report / "report.md").read_text(encoding="utf-8")
    assert "7.04" in text and "0.0588" in text
    for png in ("q1_aae.png", "q1_mabse.png", "q1_error_maps.png"):
        assert (report / png).stat().st_size > 1000 and f"({png})" in text


def test_q1_quick_calibrates_its_leds_reliably_from_a_reference_rendered_at_more_spp(q1):
    """The quick twin renders presses at 8 spp but its undeformed reference at 64: at 8 spp with one bounce the
    LED self-calibration's residual was 1.40x the images' noise and warned UNRELIABLE in every quick run."""
    out, _, _ = q1
    work = out / "q1-quick"
    doc = json.loads((work / "report" / "results.json").read_text(encoding="utf-8"))
    [calibration] = doc["calibrations"]
    assert calibration["quality"]["reliable"] and calibration["quality"]["median_ratio"] <= 1.1
    assert "LED self-calibration: residual" in (work / "report" / "report.md").read_text(encoding="utf-8")
    [reference] = list(work.glob("refs/*/meta.json"))
    assert json.loads(reference.read_text(encoding="utf-8"))["provenance"]["spp"] == 64
    presses = list(work.glob("presses/*/meta.json"))
    assert presses and all(json.loads(p.read_text(encoding="utf-8"))["provenance"]["spp"] == 8 for p in presses)


def test_a_kept_press_that_other_twin_code_rendered_is_rendered_again(q1):
    """A press task re-run (its result lost, or made by other code) reused any press folder it found (kept by
    --keep-presses): one rendered by other twin code, or another Mitsuba, gave its old images to the new solves."""
    out, argv, _ = q1
    work = out / "q1-quick"
    [task] = [p for p in work.glob("tasks/*.json") if p.stem.startswith("cube")]
    meta_path = work / "presses" / task.stem / "meta.json"
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    here = meta["provenance"]["code"]
    meta["provenance"]["code"] = "0" * 32  # as if an older sim/ had rendered it
    meta_path.write_text(json.dumps(meta), encoding="utf-8")
    task.unlink()
    assert main(argv) == 0
    assert json.loads(meta_path.read_text(encoding="utf-8"))["provenance"]["code"] == here  # rendered anew


def test_a_finished_experiment_resumes_without_redoing_presses(q1, capsys):
    out, argv, _ = q1
    assert main(argv) == 0
    doc = json.loads((out / "q1-quick" / "report" / "results.json").read_text(encoding="utf-8"))
    assert doc["tasks"]["run_now"] == 0 and doc["tasks"]["already_done"] == doc["tasks"]["total"]


def test_presses_are_solved_through_the_pipeline_and_not_solved_again(q1, capsys):
    """Each solve variant is a pipeline reconstruction (PRESS/solves/KEY with provenance); a press task re-run
    after an interruption (its JSON lost, the rendered press kept) reuses them and gives the same numbers."""
    out, argv, _ = q1
    work = out / "q1-quick"
    reports = sorted(work.glob("presses/*/solves/*/report.json"))
    assert len(reports) == 4  # sphere and cube, true and self-calibrated LEDs
    for path in reports:
        assert json.loads(path.read_text(encoding="utf-8"))["provenance"]["key"]
    stamps = {p: p.stat().st_mtime_ns for p in reports}
    before = json.loads((work / "report" / "results.json").read_text(encoding="utf-8"))
    for task in work.glob("tasks/sphere-*.json"):
        task.unlink()
    assert main(argv) == 0
    after = json.loads((work / "report" / "results.json").read_text(encoding="utf-8"))
    assert after["tasks"]["run_now"] == 1
    assert {p: p.stat().st_mtime_ns for p in reports} == stamps  # skipped by the pipeline, not re-solved
    assert [e["aae_deg"] for e in after["evaluations"]] == [e["aae_deg"] for e in before["evaluations"]]


def test_a_worsened_solver_option_fails_the_check(q1, capsys):
    out, argv, _ = q1
    # a heavy depth prior pins the surface to the undeformed dome: the contact comes out too flat
    assert main(argv + ["--solver-option", "prior_weight=100.0"]) == 1
    printed = capsys.readouterr().err
    assert "worse than" in printed and "baseline" in printed


@pytest.mark.parametrize("name, table", [("ablation", "paper AAE"), ("q3", "capsule"), ("studies", "1 bounce")])
def test_quick_variant_writes_its_report(name, table, tmp_path):
    assert main(["experiment", name, "--out", str(tmp_path)]) == 0
    report = tmp_path / f"{name}-quick" / "report"
    doc = json.loads((report / "results.json").read_text(encoding="utf-8"))
    assert doc["experiment"] == name and not doc["tasks"]["failed"]
    assert _finite_numbers(doc) and len(_finite_numbers(doc)) == len(doc["evaluations"])
    text = (report / "report.md").read_text(encoding="utf-8")
    assert table in text
    assert list(report.glob("*.png"))
    if name == "studies":
        assert "nlips experiment presses" in text  # the calibration-press study is its own experiment
    if name == "q3":  # every shipped dome, each with a screw press
        assert {e["shape"] for e in doc["evaluations"]} == {"nlipstac", "fingertip", "oblate", "capsule", "flat"}
        assert {e["indenter"] for e in doc["evaluations"]} == {"screw"}


def _copy_of(q1, tmp_path):
    """A copy of the quick Q1's work folder and the command's argv on it, run once more so that it holds that argv's
    run (a test before may have left another's: other solver options): tests that damage or change it leave the
    session's run as it was."""
    import shutil

    out, argv, _ = q1
    mine = tmp_path / "q1"
    shutil.copytree(out, mine)
    argv = [str(mine) if a == str(out) else a for a in argv]
    assert main(argv) == 0
    return mine, argv


def test_a_damaged_error_map_is_one_line_naming_it(q1, tmp_path, capsys):
    """The report's error-map figure read each map with np.load: a map damaged (a copied folder) stopped the
    run's report with numpy's traceback (zlib's error, or zipfile.BadZipFile for one cut short: that one now runs
    its task again, next test). Damage inside a whole archive is found only as the figure reads it: one line."""
    from tests.core.test_reconstruction import _spoil_deflated_member

    out, argv = _copy_of(q1, tmp_path)
    doc = json.loads((out / "q1-quick" / "report" / "results.json").read_text(encoding="utf-8"))
    damaged = out / "q1-quick" / next(e["map"] for e in doc["evaluations"] if e.get("map"))  # one the figure draws
    _spoil_deflated_member(damaged, "error.npy")
    capsys.readouterr()
    assert main(argv) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip() and "\r" not in line]
    assert len(err) == 1 and str(damaged) in err[0] and "damaged or truncated error map" in err[0], err


@pytest.mark.parametrize("length", [0, 200])
def test_an_error_map_left_empty_or_cut_short_runs_its_task_again(q1, tmp_path, capsys, caplog, length):
    """An error map empty or cut short after its run ended (a power cut before the disk had it: the writes are
    atomic, not synced; a folder copied in part): its task was reused, and every run after it stopped at the
    report, "...npz: damaged or truncated error map", exit 2, with nothing that made the map again. Now the task
    that wrote it runs again (its render kept), and the report is drawn, exit 0; the others are reused."""
    import logging
    import zipfile

    out, argv = _copy_of(q1, tmp_path)
    doc = json.loads((out / "q1-quick" / "report" / "results.json").read_text(encoding="utf-8"))
    damaged = out / "q1-quick" / next(e["map"] for e in doc["evaluations"] if e.get("map"))
    damaged.write_bytes(damaged.read_bytes()[:length])
    capsys.readouterr()
    caplog.set_level(logging.WARNING)
    assert main(argv) == 0
    assert f"{damaged}: error map damaged or cut short" in caplog.text
    assert "4 tasks (1 run now, 3 reused)" in capsys.readouterr().err
    assert zipfile.ZipFile(damaged).testzip() is None


def test_a_solver_change_solves_the_kept_renders_again_without_rendering(q1, tmp_path, monkeypatch):
    """A press task is keyed by all the code it runs, so a change of the solver alone re-runs it; its render was
    deleted after scoring (unless --keep-presses), so every press was rendered again (minutes each at full size) to
    solve the same images. Now the render stays, keyed by the twin's code and renderer: only the solves are redone,
    with the same numbers."""
    from nlipscalib.experiments import adapters, tasks

    out, argv = _copy_of(q1, tmp_path)
    argv = [a for a in argv if a != "--keep-presses"]
    work = out / "q1-quick"
    before = json.loads((work / "report" / "results.json").read_text(encoding="utf-8"))
    made_with, edits = tasks._made_with, ["a"]

    def solver_edited(kind: str, samples: bool) -> str:  # as if solver/ had changed: the kinds that run it differ
        doc = json.loads(made_with(kind, samples))
        if "solver" in tasks.task_code(kind, samples):
            doc["code"] = edits[-1] * 32
        return json.dumps(doc)

    rendered = []
    render = adapters.render
    monkeypatch.setattr(tasks, "_made_with", solver_edited)
    monkeypatch.setattr(
        adapters, "render", lambda scene, press, *a, **k: rendered.append(press) or render(scene, press, *a, **k)
    )
    for edit in ("a", "b"):  # the first run finds the fixture's kept presses; the second, what the first left
        edits.append(edit)
        assert main(argv) == 0
        doc = json.loads((work / "report" / "results.json").read_text(encoding="utf-8"))
        assert rendered == [] and doc["tasks"]["run_now"] == doc["tasks"]["total"] - 1  # all but the reference
        presses = sorted(work.glob("presses/*/meta.json"))
        assert len(presses) == 2 and all((p.parent / "led_01.png").is_file() for p in presses)
        assert not list(work.glob("presses/*/solves"))  # without --keep-presses the reconstructions go
        assert [e["aae_deg"] for e in doc["evaluations"]] == [e["aae_deg"] for e in before["evaluations"]]
    (presses[0].parent / "led_03.png").unlink()  # a kept render missing a file it lists is rendered again
    (work / "tasks" / f"{presses[0].parent.name}.json").unlink()
    assert main(argv) == 0 and len(rendered) == 1 and (presses[0].parent / "led_03.png").is_file()
