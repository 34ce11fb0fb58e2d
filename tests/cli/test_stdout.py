"""stdout holds a command's result paths alone, one a line, for scripts (``press=$(nlips -q render ... --out P)``); what
it made and how it went is said on stderr, which ``--quiet`` leaves to warnings and errors. An output name that would
print over two lines is refused before any work."""

import logging
from pathlib import Path

import pytest

from nlipscalib import progress
from nlipscalib.cli import main

TINY = ["render", "--width", "48", "--height", "36", "--spp", "1"]

RIM_SPEC = """
scene = "nlipstac"
seed = 5
reference = false
[camera]
width = 80
height = 60
[render]
spp = 1
[grid]
indenters = [{ kind = "sphere", size = 12.0 }]
polar_deg = [80.0]
azimuth_deg = [0.0]
depth = [1.2]
"""
"""A dataset whose one press fails while rendering (the indenter reaches past the rim): a failure to say."""


@pytest.mark.parametrize(
    "command",
    [
        [*TINY],
        ["dataset", "spec.toml"],
        ["demo"],
        ["capture", "--emulate", "nlipstac"],
        ["calibrate-leds", "reference"],
        ["calibrate-camera-response", "--emulate", "nlipstac"],
        ["train", "calibration"],
        ["live", "--camera", "frames"],
        ["experiment", "q1"],
    ],
    ids=lambda c: c[0],
)
def test_an_output_name_holding_a_line_break_is_refused_before_any_work(tmp_path, capsys, monkeypatch, command):
    """`nlips render --out $'a\\nb'` wrote the folder and printed its path over two lines: a script reading stdout
    took it for two paths. Now every command refuses such a name in one line, exit 2, nothing written."""
    monkeypatch.chdir(tmp_path)
    assert main([*command, "--out", "a\nb"]) == 2
    captured = capsys.readouterr()
    (line,) = captured.err.strip().splitlines()
    assert line.startswith(f"nlips {command[0]}: error: --out a\\nb: a control character (a line break?) in "), line
    assert "choose a name without one" in line and captured.out == "" and not any(tmp_path.iterdir())


@pytest.mark.parametrize(
    "command, option",
    [
        (["calibrate-camera-response", "--emulate", "nlipstac", "--out", "r.json"], "--figure"),
        (["experiment", "q1"], "--report"),
    ],
    ids=["figure", "report"],
)
def test_another_output_name_holding_a_line_break_is_refused_too(tmp_path, capsys, monkeypatch, command, option):
    monkeypatch.chdir(tmp_path)
    assert main([*command, option, "a\rb"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"{option} a\\rb: a control character" in line and not any(tmp_path.iterdir())


def test_a_result_path_from_elsewhere_with_a_line_break_is_printed_escaped_on_one_line(capsys, caplog):
    """A result inside a folder named elsewhere (a press received in an archive, `nlips solve 'a<LF>b'`): stdout keeps
    one line per path, the line break written as an escape, and a warning says so."""
    with caplog.at_level(logging.WARNING, logger="nlipscalib"):
        progress.print_result(Path("presses/a\nb/nlips"))
        progress.print_result(Path("presses/c/nlips"))
    assert capsys.readouterr().out.splitlines() == ["presses/a\\nb/nlips", "presses/c/nlips"]
    (warned,) = [r.getMessage() for r in caplog.records]
    assert warned.startswith("presses/a\\nb/nlips: a control character (a line break) in the name"), warned


def test_render_prints_the_press_folder_alone_and_quiet_says_nothing_else(tmp_path, capsys):
    """`nlips render` printed "rendered press to OUT" (and "OUT: already rendered ..., nothing to do") on stdout.
    Now stdout is the press folder alone, rendered now or before; with --quiet stderr is empty."""
    out = tmp_path / "p"
    for _ in range(2):  # rendered, then nothing to do: the same folder on stdout
        assert main(["-q", *TINY, "--out", str(out)]) == 0
        assert capsys.readouterr() == (f"{out}\n", "")
    assert main([*TINY, "--out", str(out)]) == 0
    captured = capsys.readouterr()  # without --quiet, the why on stderr
    assert captured.out == f"{out}\n" and "nothing to do" in captured.err


def test_dataset_quiet_keeps_its_failures_and_prints_no_folder_while_a_press_failed(tmp_path, capsys, caplog):
    """A dataset with a press that failed: exit 1, no folder on stdout (it is not whole), and with --quiet stderr
    still says which press failed and the counts (a warning), not the INFO lines."""
    spec = tmp_path / "spec.toml"
    spec.write_text(RIM_SPEC, encoding="utf-8")
    out = tmp_path / "d"
    assert main(["-q", "dataset", str(spec), "--out", str(out), "--workers", "1"]) == 1
    captured = capsys.readouterr()
    err = captured.err.splitlines()
    assert captured.out == "" and f"{out}: 0 rendered, 0 already there, 1 press failed" in err, captured
    # the press's error once, logged as it happened (an ERROR record), and the counts naming the press without
    # repeating it (as a folder solve does; in a process of its own the record is the stderr line "ERROR press_0001
    # failed: ...")
    errors = [r for r in caplog.records if r.levelname == "ERROR" and "press_0001" in r.getMessage()]
    assert len(errors) == 1 and "rim" in errors[0].getMessage(), caplog.records
    assert "  failed, each said above: press_0001" in err and not [line for line in err if "rim" in line], err
    assert not [line for line in err if line.startswith("INFO ")], err


def test_demo_prints_its_contact_sheet_alone_and_quiet_says_nothing_else(tmp_path, capsys):
    """`nlips demo` printed its table of scores and "contact sheet: PATH" on stdout; now stdout is the contact sheet
    (its product) alone, the table on stderr, which --quiet leaves out."""
    spec = tmp_path / "demo.toml"
    spec.write_text(
        RIM_SPEC.replace("size = 12.0", "size = 6.0").replace("polar_deg = [80.0]", "polar_deg = [10.0]"),
        encoding="utf-8",
    )
    out = tmp_path / "demo"
    assert main(["-q", "demo", "--spec", str(spec), "--out", str(out), "--no-solve", "--workers", "1"]) == 0
    assert capsys.readouterr() == (f"{out / 'contact_sheet.png'}\n", "")
    assert (out / "contact_sheet.png").stat().st_size > 1000


def test_capture_prints_the_session_folder_alone_and_quiet_says_nothing_else(tmp_path, capsys):
    """`nlips capture` printed a line per folder, the session's and the next steps on stdout; now stdout is the
    session folder alone, the rest on stderr (the emulated operator's instructions too), which --quiet leaves out."""
    out = tmp_path / "s"
    args = ["capture", "--emulate", "nlipstac", "--width", "48", "--height", "36", "--spp", "1", "--presses", "0"]
    assert main(["-q", *args, "--out", str(out)]) == 0
    assert capsys.readouterr() == (f"{out}\n", "")
    assert main([*args, "--out", str(out)]) == 0  # resumed: kept, said on stderr
    captured = capsys.readouterr()
    assert captured.out == f"{out}\n" and "reference: kept (already captured)" in captured.err
