"""Q2 (NLiPsNet on seen and unseen indenters) and the calibration-press study through the CLI, at test size.

Test size: the quick size (96x72 px, a 64-64-64 net for 30 epochs) with 6 presses instead of 13, given as
``--config`` (``TINY``): 3 calibration presses (one of each indenter), one seen-indenter and 2 unseen-indenter
test presses. What is checked does not depend on the number of presses: every method and split scored, the
figures drawn, the net beating no calibration on the seen indenters (4.2° against 7.0° vs truth, with the default
colour ratios; experiments.q2.QUICK_NET says how that regime was measured), resuming, the
press-count study reusing Q2's presses and model. Fewer presses mean fewer training steps too: the quick
size's training was most of its time.
"""

from __future__ import annotations

import dataclasses
import json
import math

import pytest

from nlipscalib.cli import main
from nlipscalib.core.config import to_mapping
from nlipscalib.experiments.q2 import METHODS, QUICK

TINY = dataclasses.replace(
    QUICK,
    train=dataclasses.replace(QUICK.train, count=3),
    seen=dataclasses.replace(QUICK.seen, count=1),
)
"""Q2's quick config with 6 presses instead of 13 (its 2 unseen-indenter presses kept: a split summing two)."""
COUNTS = (2, 3)
"""The press-count study's numbers of calibration presses: k = 2 trains anew, k = 3 is Q2's whole set."""


def _doc(out, name: str) -> dict:
    return json.loads((out / f"{name}-custom" / "report" / "results.json").read_text(encoding="utf-8"))


def _score(doc: dict, split: str, method: str, key: str = "aae_vs_true_deg") -> float:
    rows = [r for r in doc["learned"]["scores"] if r["split"] == split and r["method"] == method]
    assert len(rows) == 1, (split, method)
    return rows[0][key]


def _config(folder, name: str, fields: dict) -> str:
    """A config file for ``--config`` holding ``fields`` (JSON is YAML)."""
    path = folder / f"{name}.yaml"
    path.write_text(json.dumps(fields), encoding="utf-8")
    return str(path)


@pytest.fixture(scope="module")
def q2(tmp_path_factory):
    """The work folder of ``nlips experiment q2 --config`` TINY; OUT/q2-custom holds it, OUT/q2.yaml the config."""
    out = tmp_path_factory.mktemp("q2")
    assert main(["experiment", "q2", "--config", _config(out, "q2", to_mapping(TINY)), "--out", str(out)]) == 0
    return out


def test_q2_quick_writes_report_json_and_figures(q2):
    doc = _doc(q2, "q2")
    assert doc["paper"]["seen_aae_deg"] == 3.33 and doc["paper"]["unseen_aae_deg"] == 3.11
    assert doc["learned"]["presses"] == {"train": 3, "seen": 1, "unseen": 2}
    assert not doc["tasks"]["failed"]
    # every method on both test splits, scored against the NLiPs labels and against the true normals
    for split in ("seen", "unseen"):
        for method in [*METHODS.values(), "NLiPs (the labels)"]:
            for key in ("aae_vs_nlips_deg", "aae_vs_true_deg"):
                assert math.isfinite(_score(doc, split, method, key))
    # the NLiPs labels themselves are scored against the truth per press, by role and indenter
    roles = {(e["role"], e["indenter"]) for e in doc["evaluations"]}
    assert {r for r, _ in roles} == {"train", "seen", "unseen"}
    assert {i for r, i in roles if r == "unseen"}.isdisjoint({i for r, i in roles if r == "train"})
    # and every method per test indenter: the unseen split is the sum of its indenters' samples
    per = doc["learned"]["per_indenter"]
    unseen = {r["indenter"] for r in per if r["split"] == "unseen"}
    assert unseen == {i for r, i in roles if r == "unseen"}
    for method in METHODS.values():
        parts = [r["contact_samples"] for r in per if r["split"] == "unseen" and r["method"] == method]
        total = [
            r["contact_samples"] for r in doc["learned"]["scores"] if r["split"] == "unseen" and r["method"] == method
        ]
        assert sum(parts) == total[0] > 0
    # how steep each group's contact is, from the true normals: every calibration and test indenter
    steep = {(r["split"], r["indenter"]): r for r in doc["learned"]["steepness"]}
    assert set(steep) == {(r, i) for r, i in roles}
    for r in steep.values():
        assert r["contact_samples"] > 0 and 0 < r["tilt_p99_deg"] <= 90
        assert 0 <= r["beyond_45_pct"] <= r["beyond_35_pct"] <= 100
    text = (q2 / "q2-custom" / "report" / "report.md").read_text(encoding="utf-8")
    assert "3.33" in text and "3.11" in text and "AAE vs true normals" in text and "per test indenter" in text
    assert "How steep the contact is" in text
    for png in ("q2_normals.png", "q2_vs_nlips.png", "q2_vs_true.png", "q2_training.png"):
        assert (q2 / "q2-custom" / "report" / png).stat().st_size > 1000 and f"({png})" in text


def test_the_normals_figure_titles_each_press_with_the_tables_contact_aae(q2, tmp_path, monkeypatch):
    """q2_normals.png's presses carry their contact AAE vs the labels and vs the truth: the seen split's one press
    scored as the table scores the split, the unseen presses each their own part of theirs."""
    from nlipscalib.experiments.q2 import Q2
    from nlipscalib.report import experiments

    doc = _doc(q2, "q2")
    drawn = []
    monkeypatch.setattr(experiments, "nlipsnet_maps", lambda rows, path, **kw: drawn.append((rows, kw)) or path)
    assert Q2().draw_work_figures(TINY, doc["evaluations"], q2 / "q2-custom", tmp_path, doc["learned"])
    ((rows, kw),) = drawn
    assert [title for title, _ in rows] == [
        f"{role}: {n.split('-p')[0]}" for role in ("seen", "unseen") for n in doc["learned"]["names"][role]
    ]
    scores = kw["scores"]
    assert len(scores) == len(rows) == 3
    seen = scores[0]
    for key in ("aae_vs_nlips_deg", "aae_vs_true_deg", "contact_samples"):
        assert seen[key] == pytest.approx(_score(doc, "seen", METHODS["nlipsnet"], key), rel=1e-6)
    # the unseen split's samples are its two presses'; their AAEs bracket the split's (a weighted mean of them)
    unseen = _score(doc, "unseen", METHODS["nlipsnet"])
    assert sum(s["contact_samples"] for s in scores[1:]) == _score(
        doc, "unseen", METHODS["nlipsnet"], "contact_samples"
    )
    assert min(s["aae_vs_true_deg"] for s in scores[1:]) <= unseen + 1e-6
    assert max(s["aae_vs_true_deg"] for s in scores[1:]) >= unseen - 1e-6


def test_nlipsnet_learns_the_contact(q2):
    """Trained on NLiPs labels, NLiPsNet predicts the seen indenters' contact better than no calibration."""
    doc = _doc(q2, "q2")
    learned = _score(doc, "seen", METHODS["nlipsnet"])
    nothing = _score(doc, "seen", METHODS["none"])
    assert learned < nothing
    # scored against its own labels on the training indenters it is near the labels, not near chance
    assert _score(doc, "seen", METHODS["nlipsnet"], "aae_vs_nlips_deg") < 0.8 * nothing


def test_q2_resumes_without_rendering_or_training_again(q2):
    before = _doc(q2, "q2")
    assert main(["experiment", "q2", "--config", str(q2 / "q2.yaml"), "--out", str(q2)]) == 0
    after = _doc(q2, "q2")
    assert after["tasks"]["run_now"] == 0
    assert after["learned"]["models"] == before["learned"]["models"]  # same keys, same recorded training
    assert after["learned"]["scores"] == before["learned"]["scores"]


def test_press_count_study_reuses_q2_presses_and_its_model(q2):
    config = _config(q2, "presses", to_mapping(TINY) | {"counts": list(COUNTS)})
    assert main(["experiment", "presses", "--config", config, "--out", str(q2)]) == 0
    doc = _doc(q2, "presses")
    assert doc["tasks"]["run_now"] == 0  # Q2's rendered and solved presses
    assert doc["learned"]["counts"] == list(COUNTS)
    q2_doc = _doc(q2, "q2")
    # k = 3 is Q2's full calibration set: the same model, hence the same numbers
    rows = [r for r in doc["learned"]["scores"] if r["calibration_presses"] == 3 and r["method"] == "NLiPsNet"]
    assert {r["split"] for r in rows} == {"seen", "unseen"}
    for r in rows:
        assert r["aae_vs_true_deg"] == _score(q2_doc, r["split"], METHODS["nlipsnet"])
    text = (q2 / "presses-custom" / "report" / "report.md").read_text(encoding="utf-8")
    assert "| calibration presses | split | method |" in text and "(presses_aae.png)" in text
    assert (q2 / "presses-custom" / "report" / "presses_aae.png").stat().st_size > 1000


def test_all_includes_q2_and_the_press_count_study(tmp_path, capsys):
    assert main(["experiment", "all", "--plan", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    for name in ("q1", "q2", "ablation", "q3", "studies", "presses"):
        assert f"{name} (quick):" in printed


def test_too_few_calibration_presses_are_reported_not_fatal(tmp_path):
    """One calibration press cannot be split into training and validation: the report says so."""
    cfg = tmp_path / "q2_tiny.toml"
    cfg.write_text(
        "[twin]\nwidth = 96\nheight = 72\nspp = 8\n[train]\ncount = 1\n[seen]\ncount = 0\n[unseen]\ncount = 0\n",
        encoding="utf-8",
    )
    assert main(["experiment", "q2", "--config", str(cfg), "--out", str(tmp_path)]) == 0
    report = tmp_path / "q2-custom" / "report"
    doc = json.loads((report / "results.json").read_text(encoding="utf-8"))
    assert "need 2" in doc["learned"]["error"]
    assert "## Not computed" in (report / "report.md").read_text(encoding="utf-8")


def test_label_normals_reach_the_solves_and_the_default_adds_no_option():
    """``normals = "refined"`` solves every label with SolverOptions.normals; the default leaves the solve spec as
    earlier runs wrote it (their kept tasks keep their names)."""
    from nlipscalib.experiments.q2 import Q2, QUICK

    def options(cfg):
        return {tuple(sorted(dict(solve["options"]).items())) for *_, solve in Q2().evaluations(cfg)}

    assert options(QUICK) == {()}
    assert options(dataclasses.replace(QUICK, normals="refined")) == {(("normals", "refined"),)}


def test_a_bad_label_normals_value_is_one_line_naming_the_config_before_any_work(tmp_path, capsys):
    """``normals = "bogus"`` was planned and would have failed every press after its render."""
    cfg = tmp_path / "q2_bad.toml"
    cfg.write_text('normals = "bogus"\n', encoding="utf-8")
    assert main(["experiment", "q2", "--config", str(cfg), "--plan", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(cfg) in err[0] and "normals" in err[0] and "bogus" in err[0], err
    assert not (tmp_path / "out").exists()
