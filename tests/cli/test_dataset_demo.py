"""`nlips dataset` and `nlips demo` end to end on tiny images (real Mitsuba renders)."""

import json
import logging

import pytest

from nlipscalib.cli import main
from nlipscalib.core import find_presses, load_press

pytest.importorskip("mitsuba")

SPEC = """
scene = "nlipstac"
seed = 5
[camera]
width = 80
height = 60
[render]
spp = 1
[grid]
indenters = [{ kind = "sphere", size = 6.0 }]
polar_deg = [10.0]
azimuth_deg = [0.0, 180.0]
depth = [1.2]
"""


def test_dataset_renders_in_parallel_then_resumes(tmp_path, capsys):
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC, encoding="utf-8")
    out = tmp_path / "data"
    assert main(["dataset", str(spec), "--out", str(out), "--workers", "2", "--no-progress"]) == 0
    said = capsys.readouterr()  # stdout: the dataset's folder alone (a script's `data=$(nlips dataset ...)`)
    counts = f"{out}: 2 presses and the undeformed reference rendered, 0 already there, 0 failed"
    assert said.out == f"{out}\n" and counts in said.err.splitlines()
    presses = find_presses(out)
    assert [p.name for p in presses] == ["press_0001", "press_0002", "reference"]
    a, b = (load_press(p) for p in presses[:2])
    assert a.camera.shape == (60, 80) and a.ground_truth.contact.any()
    assert a.meta["provenance"]["press"]["azimuth_deg"] != b.meta["provenance"]["press"]["azimuth_deg"]
    assert len(json.loads((out / "dataset.json").read_text(encoding="utf-8"))["presses"]) == 3
    assert main(["dataset", str(spec), "--out", str(out), "--no-progress"]) == 0
    assert "0 rendered, 2 presses and the undeformed reference already there" in capsys.readouterr().err

    # press folders without meta.json (interrupted copies) are removed and rendered again by the
    # worker processes, which say so in the --log-file too
    for name in ("press_0001", "press_0002"):
        (out / name / "meta.json").unlink()
    log = tmp_path / "run.log"
    args = ["--log-file", str(log), "dataset", str(spec), "--out", str(out), "--workers", "2", "--no-progress"]
    assert main(args) == 0
    assert "2 presses rendered, the undeformed reference already there, 0 failed" in capsys.readouterr().err
    text = log.read_text(encoding="utf-8")
    for name in ("press_0001", "press_0002"):
        assert f"{name}: incomplete press folder" in text, text
        assert load_press(out / name).camera.shape == (60, 80)

    # solving the whole dataset folder: the reference is used, not solved; a broken press is
    # reported and the others are still solved
    (out / "press_0002" / "led_03.png").write_bytes(b"broken")
    code = main(["solve", str(out), "--roi", "auto", "--reference", str(out / "reference")])
    assert code == 1
    assert (out / "press_0001" / "nlips" / "result.npz").is_file()
    assert not (out / "press_0002" / "nlips").exists() and not (out / "reference" / "nlips").exists()
    # without --reference, the dataset's own reference/ is the reference: used, not solved
    first = json.loads((out / "press_0001" / "nlips" / "report.json").read_text(encoding="utf-8"))["provenance"]
    assert main(["solve", str(out), "--roi", "auto", "--overwrite"]) == 1
    again = json.loads((out / "press_0001" / "nlips" / "report.json").read_text(encoding="utf-8"))["provenance"]
    assert again["settings"]["reference"] == str(out / "reference") and again["key"] == first["key"]
    assert not (out / "reference" / "nlips").exists()
    capsys.readouterr()
    assert main(["eval", str(out)]) == 0  # scores what was solved, names what was not
    said = capsys.readouterr()  # stdout: the table alone; what was left out, on stderr
    assert "press_0001" in said.out and "press_0002" not in said.out and "skipped" not in said.out
    assert "not solved, skipped: press_0002\n" in said.err  # the reference is no press


def test_dataset_reports_bad_presses_and_bad_specs(tmp_path, capsys, caplog):
    spec = tmp_path / "spec.toml"
    spec.write_text(
        SPEC.replace("depth = [1.2]", "depth = [9.0]").replace("seed = 5", "seed = 5\nreference = false"),
        encoding="utf-8",
    )
    assert main(["dataset", str(spec), "--out", str(tmp_path / "d"), "--workers", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err  # refused before rendering, naming the file and key
    assert "spec.toml" in err and "depth" in err and "thickness" in err
    rim = SPEC.replace("polar_deg = [10.0]", "polar_deg = [80.0]").replace("size = 6.0", "size = 12.0")
    spec.write_text(rim.replace("seed = 5", "seed = 5\nreference = false"), encoding="utf-8")
    assert main(["dataset", str(spec), "--out", str(tmp_path / "d"), "--workers", "1", "--no-progress"]) == 1
    err = capsys.readouterr().err  # found only while rendering: reported per press (ERROR), the others go on
    assert "press_0001" in err and "rim" in caplog.text  # the counts name it; its error is said once, logged
    spec.write_text("[grid]\nindenter = []\n", encoding="utf-8")
    assert main(["dataset", str(spec), "--out", str(tmp_path / "e")]) == 2
    assert "spec.toml" in capsys.readouterr().err


def test_demo_renders_solves_and_draws(tmp_path, capsys, caplog, monkeypatch):
    from nlipscalib.report import figures

    sheets = []
    save = figures.save_png
    monkeypatch.setattr(figures, "save_png", lambda fig, path, dpi: sheets.append(fig) or save(fig, path, dpi))
    spec = tmp_path / "demo.toml"
    spec.write_text(
        SPEC.replace("azimuth_deg = [0.0, 180.0]", "azimuth_deg = [0.0]").replace("80", "96").replace("60", "72"),
        encoding="utf-8",
    )
    out = tmp_path / "demo"
    with caplog.at_level(logging.INFO, logger="nlipscalib"):
        assert main(["demo", "--spec", str(spec), "--out", str(out)]) == 0
    said = capsys.readouterr()  # stdout: the contact sheet alone; the scores' table on stderr
    assert said.out == f"{out / 'contact_sheet.png'}\n"
    text = said.err
    assert (out / "contact_sheet.png").stat().st_size > 10_000
    # the sheet opened alone says what it shows (it had no title)
    title = "nlips demo on the nlipstac twin (96x72 px): NLiPs around each press's contact vs the true normals"
    assert title in [t.get_text() for t in sheets[-1].texts]
    assert "press_0001" in text and "sphere" in text
    assert (out / "press_0001" / "nlips" / "result.npz").is_file()
    aae = float(text.split("press_0001")[1].split()[1].rstrip("°"))
    assert aae < 10.0  # a tiny noisy image still gives a sensible reconstruction
    reused = [r for r in caplog.records if "identical result exists" in r.getMessage()]
    assert not reused  # solved just now: loading it for the scores is not reported as a skip
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="nlipscalib"):
        assert main(["demo", "--spec", str(spec), "--out", str(out)]) == 0
    reused = [r for r in caplog.records if "identical result exists" in r.getMessage()]
    assert len(reused) == 1  # the second run reuses the one press and says so once
    # another spec into the same folder: refused naming --overwrite, which demo takes (it did not)
    spec.write_text(spec.read_text(encoding="utf-8").replace("seed = 5", "seed = 6"), encoding="utf-8")
    assert main(["demo", "--spec", str(spec), "--out", str(out), "--no-solve"]) == 2
    assert "use --overwrite" in capsys.readouterr().err
    assert main(["demo", "--spec", str(spec), "--out", str(out), "--no-solve", "--overwrite"]) == 0
    # --overwrite re-renders only what another spec made: this spec's presses are kept, as its help says (it said
    # "render every press again", and a user waiting for fresh renders got none)
    rendered = (out / "press_0001" / "meta.json").stat().st_mtime_ns
    assert main(["demo", "--spec", str(spec), "--out", str(out), "--no-solve", "--overwrite"]) == 0
    assert (out / "press_0001" / "meta.json").stat().st_mtime_ns == rendered
    for command in ("demo", "dataset"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert "presses of this very spec are kept" in " ".join(capsys.readouterr().out.split())


def test_the_demo_sheet_shows_a_few_presses_of_a_large_spec_and_says_so(tmp_path, capsys, monkeypatch):
    """`nlips demo --spec train50` drew a row per press: a sheet ~11400 px tall. It shows the first SHEET_PRESSES."""
    from nlipscalib.cli import demo
    from nlipscalib.report import figures

    sheets = []
    save = figures.save_png
    monkeypatch.setattr(figures, "save_png", lambda fig, path, dpi: sheets.append(fig) or save(fig, path, dpi))
    monkeypatch.setattr(demo, "SHEET_PRESSES", 1)
    spec = tmp_path / "two.toml"
    spec.write_text(SPEC, encoding="utf-8")  # two presses
    assert main(["demo", "--spec", str(spec), "--out", str(tmp_path / "demo"), "--no-solve"]) == 0
    titles = [t.get_text().replace("\n", " ") for t in sheets[-1].texts]  # a long title is wrapped
    assert "press_0001" in " ".join(titles) and "press_0002" not in " ".join(titles)
    assert any(t.endswith("; the first 1 of 2 presses") for t in titles)
