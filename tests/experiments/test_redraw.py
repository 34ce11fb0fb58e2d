"""`nlips experiment NAME --redraw REPORT`: a report's figures and report.md drawn again from its results.json alone.

The committed reports (docs/experiments/*/) have no work folder any more and were drawn by older figure code;
a redraw must draw every figure the numbers give, keep those drawn from the work folder's per-press arrays,
and refuse bad input in one line.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from nlipscalib.cli import main
from nlipscalib.core.config import from_mapping
from nlipscalib.experiments import get
from nlipscalib.experiments.q1 import Q1

DOCS = Path(__file__).resolve().parents[2] / "docs" / "experiments"
COMMITTED = sorted(p.parent.name for p in DOCS.glob("*/results.json"))
NOTE = re.compile(r"^Figures and page redrawn from `results.json` by nlipscalib .*\n\n", re.MULTILINE)
"""The paragraph a redraw adds to report.md (which code drew the figures; which ones it kept)."""


def _figures(text: str) -> list[str]:
    """The PNG files a report.md shows, in order."""
    return re.findall(r"^!\[.*\]\((.+\.png)\)$", text, re.MULTILINE)


def test_a_quick_report_redrawn_without_its_work_folder_comes_out_as_the_run_drew_it(q1, tmp_path, capsys):
    out, _, _ = q1
    work = out / "q1-quick"
    report = tmp_path / "report"
    shutil.copytree(work / "report", report)
    run = {p.name: p.read_bytes() for p in report.glob("*.png")} | {
        "report.md": (report / "report.md").read_text(encoding="utf-8")
    }
    for png in ("q1_aae.png", "q1_mabse.png"):
        (report / png).unlink()
    hidden = out / "hidden"
    work.rename(hidden)  # no work folder: the redraw has only results.json
    try:
        capsys.readouterr()
        assert main(["experiment", "q1", "--redraw", str(report)]) == 0
    finally:
        hidden.rename(work)
    said = capsys.readouterr()  # stdout: the report's folder alone; what was redrawn, on stderr
    assert said.out == f"{report}\n"
    printed = said.err.splitlines()
    assert printed[0].startswith("q1: redrew q1_aae.png, q1_mabse.png, report.md")
    assert printed[1].startswith("q1: kept q1_error_maps.png: drawn from ") and len(printed) == 2
    for png in ("q1_aae.png", "q1_mabse.png", "q1_error_maps.png"):
        assert (report / png).read_bytes() == run[png], png
    text = (report / "report.md").read_text(encoding="utf-8")
    assert "kept as the run drew them (from its work folder): `q1_error_maps.png`" in text
    assert NOTE.sub("", text, count=1) == run["report.md"]


@pytest.mark.parametrize("folder", COMMITTED)
def test_a_committed_report_redraws_every_figure_its_numbers_give(folder, tmp_path, capsys):
    report = tmp_path / folder
    shutil.copytree(DOCS / folder, report)
    name = json.loads((report / "results.json").read_text(encoding="utf-8"))["experiment"]
    listed = _figures((report / "report.md").read_text(encoding="utf-8"))
    kept = {f.file: (report / f.file).read_bytes() for f in get(name).work_figures if (report / f.file).is_file()}
    for png in report.glob("*.png"):
        if png.name not in kept:
            png.unlink()
    assert main(["experiment", name, "--redraw", str(report)]) == 0
    printed = capsys.readouterr().err
    shown = _figures((report / "report.md").read_text(encoding="utf-8"))
    assert sorted(shown) == sorted(listed)  # every figure of the report again: drawn now or kept
    assert all((report / png).stat().st_size > 1000 for png in shown)
    for png, data in kept.items():
        assert (report / png).read_bytes() == data and f"{name}: kept {png}: drawn from " in printed


def test_the_config_comes_from_results_json_not_from_the_default_size(tmp_path, monkeypatch):
    report = tmp_path / "q1"
    shutil.copytree(DOCS / "q1", report)
    doc = json.loads((report / "results.json").read_text(encoding="utf-8"))
    seen = []
    figures = Q1.figures
    monkeypatch.setattr(Q1, "figures", lambda self, cfg, *a: seen.append(cfg) or figures(self, cfg, *a))
    assert main(["experiment", "q1", "--redraw", str(report / "results.json")]) == 0  # the file itself: its folder
    assert seen == [from_mapping(Q1.config_cls, doc["config"])] and doc["size"] == "full"
    assert seen[0] != Q1.sizes["quick"]


def test_a_report_with_a_solve_without_contact_redraws_it_as_failed(tmp_path, capsys):
    """A solve that saw no contact pixel has NaN metrics in the run, null in results.json: read back as NaN,
    the group's mean leaves it out and the table counts it as failed, as the run's report did."""

    def no_contact(doc):
        doc["evaluations"][0] |= {"aae_deg": None, "mabse": None, "depth_rmse_mm": None, "pixels": 0}

    report = _results(tmp_path, no_contact)
    assert main(["experiment", "q1", "--redraw", str(report)]) == 0
    first = json.loads((report / "results.json").read_text(encoding="utf-8"))["evaluations"][0]
    row = next(
        line
        for line in (report / "report.md").read_text(encoding="utf-8").splitlines()
        if line.startswith("| sphere | true")
    )
    assert first["indenter"] == "sphere" and first["leds"] == "true" and "(1 failed)" in row


def _results(tmp_path: Path, edit=None, text: str | None = None) -> Path:
    """A report folder holding the committed Q1 results.json, edited, or ``text`` as its results.json."""
    report = tmp_path / "report"
    report.mkdir()
    doc = json.loads((DOCS / "q1" / "results.json").read_text(encoding="utf-8"))
    if edit:
        edit(doc)
    (report / "results.json").write_text(json.dumps(doc) if text is None else text, encoding="utf-8")
    return report


@pytest.mark.parametrize(
    "argv, expected",
    [
        (lambda r: ["q1", "--redraw", str(r.parent / "nowhere")], "no such folder"),
        (lambda r: ["q1", "--redraw", str(r.parent)], "no results.json here"),
        (lambda r: ["ablation", "--redraw", str(r)], "the results of experiment 'q1', not 'ablation'"),
        (lambda r: ["all", "--redraw", str(r)], "not 'all'"),
        (lambda r: ["q1", "--size", "quick", "--out", "o", "--redraw", str(r)], "drop --size, --out"),
    ],
)
def test_a_redraw_refuses_the_wrong_folder_experiment_or_options_in_one_line(argv, expected, tmp_path, capsys):
    report = _results(tmp_path)
    before = sorted(report.iterdir())
    assert main(["experiment", *argv(report)]) == 2
    err = capsys.readouterr().err.strip()
    assert expected in err and len(err.splitlines()) == 1
    assert sorted(report.iterdir()) == before and not (tmp_path / "nowhere").exists()


@pytest.mark.parametrize(
    "edit, text, expected",
    [
        (None, '{"experiment": "q1", "config": {', "results.json: not valid JSON"),
        (None, "[1, 2]", "not the results of an nlips experiment"),
        (lambda d: d.pop("evaluations"), None, "not a complete results.json of nlips experiment q1 (it lacks"),
        (lambda d: d["config"].update(bogus=1), None, "results.json: config: unknown key(s) ['bogus']"),
    ],
)
def test_a_damaged_results_json_is_one_line_and_draws_nothing(edit, text, expected, tmp_path, capsys):
    report = _results(tmp_path, edit, text)
    assert main(["experiment", "q1", "--redraw", str(report)]) == 2
    err = capsys.readouterr().err.strip()
    assert expected in err and len(err.splitlines()) == 1
    assert [p.name for p in report.iterdir()] == ["results.json"]


def test_the_commit_named_is_the_one_before_the_redraw_wrote(tmp_path, monkeypatch):
    # redrawing a report inside a checkout rewrites tracked files: a commit taken after drawing said "+dirty"
    from nlipscalib.experiments import redraw as module

    report = tmp_path / "q1"
    shutil.copytree(DOCS / "q1", report)
    drawn = []
    figures = Q1.figures
    monkeypatch.setattr(Q1, "figures", lambda self, *a: drawn.append(1) or figures(self, *a))
    monkeypatch.setattr(module, "software", lambda: {"nlipscalib": "0", "git_commit": "after" if drawn else "before"})
    module.redraw(get("q1"), report)
    assert drawn and "at `before`" in (report / "report.md").read_text(encoding="utf-8")


def test_a_redraw_leaves_one_report_no_figure_the_code_no_longer_draws(tmp_path):
    # the redraw rewrote the files it draws into the folder: a figure an older code drew stayed beside the new page
    report = tmp_path / "q1"
    shutil.copytree(DOCS / "q1", report)
    (report / "q1_retired.png").write_bytes(b"drawn by an older nlipscalib")
    done = redraw_module().redraw(get("q1"), report)
    written = [*done.drawn, *(f.file for f in done.kept), "results.json"]
    assert sorted(p.name for p in report.iterdir()) == sorted(written)
    assert (report / "results.json").read_bytes() == (DOCS / "q1" / "results.json").read_bytes()


def test_a_redraw_keeps_the_files_beside_the_report_that_it_does_not_write(tmp_path):
    # the Q2 variants' config.toml lies in their report folder; the redraw replaced the folder whole and lost it
    report = tmp_path / "q1"
    shutil.copytree(DOCS / "q1", report)
    (report / "config.toml").write_text("[net]\nseed = 1\n", encoding="utf-8")
    redraw_module().redraw(get("q1"), report)
    assert (report / "config.toml").read_text(encoding="utf-8") == "[net]\nseed = 1\n"


def test_a_redraw_that_fails_half_way_leaves_the_report_as_it_was(tmp_path, monkeypatch):
    report = tmp_path / "q1"
    shutil.copytree(DOCS / "q1", report)
    for png in ("q1_aae.png", "q1_mabse.png"):  # drawn by an older code: the current one draws them otherwise
        (report / png).write_bytes(b"older drawing")
    before = {p.name: p.read_bytes() for p in report.iterdir()}
    figures = Q1.figures

    def killed(self, cfg, rows, tables, folder, learned):
        figures(self, cfg, rows, tables, folder, learned)  # the figures drawn anew, then report.md never written
        raise KeyboardInterrupt

    monkeypatch.setattr(Q1, "figures", killed)
    with pytest.raises(KeyboardInterrupt):
        redraw_module().redraw(get("q1"), report)
    assert {p.name: p.read_bytes() for p in report.iterdir()} == before
    assert [p.name for p in tmp_path.iterdir()] == ["q1"]  # no temporary folder left


def redraw_module():
    from nlipscalib.experiments import redraw

    return redraw
