"""The command line as a new user meets it: examples under each command's help, `nlips` alone, a mistyped command
or option answered with its close match, `--version` for a bug report, the exit statuses written down."""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from nlipscalib.cli import build_parser, main
from nlipscalib.cli.help import EXAMPLES, EXIT_STATUS

ROOT = Path(__file__).resolve().parents[2]


def _commands() -> dict[str, argparse.ArgumentParser]:
    subs = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return subs.choices


def _error(capsys, *argv: str) -> str:
    """stderr of ``nlips ARGV``, which must end as a usage error (exit 2)."""
    with pytest.raises(SystemExit) as stop:
        main(list(argv))
    assert stop.value.code == 2
    return capsys.readouterr().err


@pytest.mark.parametrize("name", sorted(_commands()))
def test_every_command_shows_examples_that_it_accepts(name):
    """No command's help had an example to copy; each example must parse, or the help teaches a usage error."""
    text = _commands()[name].format_help()
    assert "\nexamples:\n" in text
    for line, _ in EXAMPLES[name]:
        assert f"  {line}  " in text  # kept on one line, as typed, not filled into the paragraph
        argv = shlex.split(line)
        assert argv[:2] == ["nlips", name]
        parsed = build_parser().parse_args(argv[1:])
        assert parsed.command == name


def test_examples_fit_a_wide_terminal():
    for name, rows in EXAMPLES.items():
        width = max(len(line) for line, _ in rows)
        assert all(len(f"  {line:<{width}}  # {what}") <= 110 for line, what in rows), name


def test_a_mistyped_command_is_answered_with_the_close_one(capsys):
    err = _error(capsys, "slove", "PRESS")
    assert "invalid choice: 'slove' (did you mean 'solve'?)" in err


def test_a_job_typed_as_a_command_names_the_command_that_does_it_in_one_line(capsys):
    """`nlips coverage` (a new lab looking for the where-to-press-next report) got argparse's usage and a bare
    "invalid choice" list (s41-userwalk); a mistyped command keeps its close match."""
    err = _error(capsys, "coverage", "out/small")
    assert err.startswith("nlips: no command 'coverage': ") and err.count("\n") == 1, err
    assert "written by nlips calibrate (coverage.png" in err and "commands: render, dataset, " in err
    assert "invalid choice" not in err and "usage:" not in err
    err = _error(capsys, "slove", "PRESS")
    assert "no command" not in err and "did you mean 'solve'?" in err


def test_a_mistyped_option_names_the_close_one_under_its_commands_usage(capsys):
    """argparse said "nlips: error: unrecognized arguments: --rio" under nlips's own usage line."""
    err = _error(capsys, "solve", "PRESS", "--rio", "auto")
    assert "usage: nlips solve" in err
    # the hint after the option's value, not between them ("--rio (did you mean '--roi'?) auto")
    assert "nlips solve: error: unrecognized arguments: --rio auto (did you mean '--roi'?)\n" in err
    err = _error(capsys, "eval", "PRESS", "--regoin=contact")
    assert "--regoin=contact (did you mean '--region'?)" in err


def test_several_mistyped_options_are_named_after_all_the_arguments(capsys):
    err = _error(capsys, "solve", "PRESS", "--rio", "auto", "--overwirte", "--zzzzzz")
    assert (
        "unrecognized arguments: --rio auto --overwirte --zzzzzz "
        "(did you mean '--roi' for --rio, '--overwrite' for --overwirte?)\n" in err
    ), err


def test_an_unknown_option_far_from_any_gets_no_guess(capsys):
    err = _error(capsys, "cache", "--zzzzzz")
    assert "unrecognized arguments: --zzzzzz\n" in err and "did you mean" not in err


def test_a_mistyped_choice_is_answered_with_the_close_one(capsys):
    err = _error(capsys, "solve", "PRESS", "--interreflection", "of")
    assert "argument --interreflection: invalid choice: 'of' (did you mean 'off'?)" in err
    assert "'auto', 'on', 'off'" in err  # the choices are still listed


def test_nlips_alone_shows_the_commands_and_is_a_usage_error():
    """`nlips` alone said only "the following arguments are required: COMMAND", none of the commands."""
    run = subprocess.run([sys.executable, "-m", "nlipscalib"], capture_output=True, text=True, cwd=ROOT)
    assert run.returncode == 2
    assert "calibrate-leds" in run.stderr and "exit status:" in run.stderr and run.stdout == ""


@pytest.mark.parametrize("argv, required", [(("leds", "virtual"), "action"), (("infer",), "model")])
def test_a_missing_argument_names_only_what_is_required(capsys, argv, required):
    """`nlips leds PORT` said "the following arguments are required: action, values" and `nlips infer` "...: model,
    inputs", though `nlips leds PORT info` takes no values and `nlips infer MODEL --camera 0` no inputs (argparse
    calls a positional of nargs="*" without a default required)."""
    last = _error(capsys, *argv).strip().splitlines()[-1]
    assert last.endswith(f"error: the following arguments are required: {required}"), last


def test_help_and_h_are_the_same(capsys):
    texts = []
    for flag in ("-h", "--help"):
        with pytest.raises(SystemExit) as stop:
            main(["solve", flag])
        assert stop.value.code == 0
        texts.append(capsys.readouterr().out)
    assert texts[0] == texts[1] and "examples:" in texts[0]


def test_version_names_python_and_the_libraries_for_a_bug_report(capsys):
    from importlib import metadata

    from nlipscalib import __version__

    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"nlipscalib {__version__}"
    assert lines[1].startswith(f"Python {sys.version.split()[0]} on ")
    assert f"numpy {metadata.version('numpy')}" in lines[2] and f"scipy {metadata.version('scipy')}" in lines[2]


def test_exit_statuses_are_in_the_help_and_the_docs(capsys):
    """No page said which status means what; docs/faults.md now holds the same table as `nlips --help`."""
    with pytest.raises(SystemExit):
        main(["--help"])
    assert EXIT_STATUS in capsys.readouterr().out
    assert EXIT_STATUS in (ROOT / "docs" / "faults.md").read_text(encoding="utf-8")


def test_the_documented_statuses_are_those_the_command_returns(tmp_path, capsys):
    """2 for an error line, as EXIT_STATUS says (a missing press folder)."""
    assert main(["solve", str(tmp_path / "missing")]) == 2
    assert capsys.readouterr().err.startswith("nlips solve: error: ")


@pytest.mark.parametrize("name", sorted(_commands()))
def test_every_command_takes_verbose_log_file_and_no_progress_after_it_too(name, tmp_path):
    """`nlips solve PRESS -v` was "unrecognized arguments: -v"; `nlips demo --no-progress` too, while `nlips solve
    --no-progress` worked. Typed before the command they still hold (the command's own default must not undo
    them)."""
    parser = build_parser()
    required = {"calibrate-camera": ["--pattern", "8x6", "--square", "5", "--out", "c.json", "img"]}
    positionals = {
        "dataset": ["spec", "--out", "o"],
        "calibrate-leds": ["ref", "--out", "l.json"],
        "eval": ["p"],
        "experiment": ["q1"],
        "leds": ["virtual", "info"],
        "capture": ["--out", "o"],
        "calibrate-camera-response": ["--out", "r.json"],
        "calibrate": ["p"],
        "train": ["d", "--out", "m.pt"],
        "lut": ["d", "--out", "t.pt"],
        "export": ["m.pt"],
        "render": ["--out", "o"],
        "infer": ["m.pt"],
        "verify": ["p"],
    }
    rest = required.get(name, positionals.get(name, []))
    after = parser.parse_args([name, *rest, "-v", "--log-file", str(tmp_path / "log"), "--no-progress"])
    assert after.verbose and after.log_file == str(tmp_path / "log")
    assert after.global_no_progress or after.no_progress
    before = parser.parse_args(["-v", "--log-file", "x.log", name, *rest])
    assert before.verbose and before.log_file == "x.log"
    assert not build_parser().parse_args([name, *rest]).verbose


def test_roi_auto_is_explained():
    text = " ".join(_commands()["solve"].format_help().split())
    assert "'auto': the box around the pixels whose images differ from the undeformed dome's" in text


def test_shell_completion_is_handed_to_argcomplete_only_when_the_shell_asks(monkeypatch, capsys):
    """Optional: with argcomplete installed and the shell asking (_ARGCOMPLETE set), it gets nlips's parser."""
    import types

    asked = []

    def autocomplete(parser):
        asked.append(parser)
        raise SystemExit(0)  # as argcomplete does, once it has answered

    monkeypatch.setitem(sys.modules, "argcomplete", types.SimpleNamespace(autocomplete=autocomplete))
    monkeypatch.delenv("_ARGCOMPLETE", raising=False)
    assert main(["cache"]) == 0  # not asked: the command runs
    assert asked == []
    monkeypatch.setenv("_ARGCOMPLETE", "1")
    with pytest.raises(SystemExit):
        main(["cache"])
    assert [p.prog for p in asked] == ["nlips"] and "cache" in asked[0]._subparsers._group_actions[0].choices


def test_shell_completion_without_argcomplete_runs_the_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "argcomplete", None)  # import fails
    monkeypatch.setenv("_ARGCOMPLETE", "1")
    assert main(["cache"]) == 0


def test_completion_of_a_command_name_with_the_real_argcomplete(tmp_path):
    """Skipped where argcomplete is not installed (it is optional)."""
    import os

    pytest.importorskip("argcomplete")
    out = tmp_path / "completions"
    env = {**os.environ, "_ARGCOMPLETE": "1", "COMP_LINE": "nlips sol", "COMP_POINT": "9"}
    # argcomplete writes its answer to file descriptor 8, as the shell's completion function reads it
    line = f'"$0" -m nlipscalib 8>"{out}" 9>/dev/null'
    run = subprocess.run(["bash", "-c", line, sys.executable], env=env, cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert out.read_text(encoding="utf-8").split() == ["solve"]
