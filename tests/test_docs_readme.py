"""README.md: every `nlips` command its code blocks show is one the command line takes, as typed.

A renamed option, a removed choice or a subcommand the README invents would otherwise reach a new user as
"nlips solve: error: unrecognized arguments" on the first copy and paste.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

from nlipscalib.cli import build_parser

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_commands(text: str) -> list[str]:
    """Every `nlips ...` command of the bash code blocks, comments cut off, `&&` chains split."""
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", text, re.S):
        for line in block.splitlines():
            line = re.split(r"\s#", line, maxsplit=1)[0]
            for part in line.split("&&"):
                words = shlex.split(part)
                if words and Path(words[0]).name == "nlips":
                    commands.append(" ".join(words))
    return commands


def parse_problem(command: str) -> str | None:
    """argparse's complaint about ``command`` (an `nlips ...` line), or None when it parses."""
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            build_parser().parse_args(shlex.split(command)[1:])
    except SystemExit as exc:
        if exc.code:
            return err.getvalue().strip().splitlines()[-1]
    return None


def test_every_readme_command_parses():
    commands = readme_commands(README.read_text(encoding="utf-8"))
    assert len(commands) > 40  # the blocks were read (a format change would otherwise pass silently)
    subcommands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    assert {c.split()[1] for c in commands} >= set(subcommands)  # every subcommand is shown
    problems = {c: parse_problem(c) for c in commands}
    assert {c: p for c, p in problems.items() if p} == {}


@pytest.mark.parametrize(
    "line",
    ["nlips solve out/press --roi-auto", "nlips solve out/press --interreflection maybe", "nlips frobnicate out/x"],
)
def test_a_command_the_cli_refuses_is_caught(line):
    (command,) = readme_commands(f"```bash\n{line}   # a comment\n```")
    assert parse_problem(command)


def test_the_readme_led_commands_without_hardware_run_and_do_what_their_comments_say(capsys):
    """The LED section's `nlips leds virtual ...` / `nlipsemu://1` lines run as typed (``--dwell 0``: no waiting)."""
    from nlipscalib.cli import main

    section = README.read_text(encoding="utf-8").split("## LED controller (real sensor)")[1].split("\n## ")[0]
    commands = [c for c in readme_commands(section) if c.split()[2].startswith(("virtual", "nlipsemu://"))]
    assert len(commands) == 3
    said = {}
    for command in commands:
        words = shlex.split(command)[1:]
        assert main(words + (["--dwell", "0"] if words[2] == "test" else [])) == 0, command
        said[command] = capsys.readouterr().out
    info = next(out for c, out in said.items() if " info" in c)
    assert re.search(r"firmware \S+, protocol \d+, 12 LEDs", info)  # "firmware, protocol and LED count"
    adalight = next(out for c, out in said.items() if "--adalight" in c)
    assert "nothing was checked" in adalight and ": lit" not in adalight  # each step only sent, none checked
    assert main(["leds", "virtual", "state", "--adalight", "12"]) == 2  # "`state` is refused"


def test_the_readme_and_setup_sh_quote_the_torch_range_and_pin_that_the_install_uses():
    """The README's install section and setup.sh's comment quote pyproject.toml's torch range, and the README names
    the version setup.sh installs: both were raised by hand when the bound moved (torch>=2.2 -> 2.6, s25)."""
    import tomllib

    root = README.parent
    learn = tomllib.loads((root / "pyproject.toml").read_text(encoding="utf-8"))["project"]["optional-dependencies"][
        "learn"
    ]
    (torch_range,) = [req.replace(" ", "") for req in learn if req.startswith("torch")]
    setup = (root / "setup.sh").read_text(encoding="utf-8")
    readme = README.read_text(encoding="utf-8")
    assert f"`{torch_range}`" in readme
    assert f"({torch_range})" in setup
    (pin,) = set(re.findall(r"torch==[0-9.]+", setup))
    assert f"`{pin}` from PyTorch's CPU index" in readme
    assert re.findall(r"torch>=[0-9][0-9.,<>]*", readme) == [torch_range]  # no other, stale range


def test_every_nlips_command_the_docs_pages_show_parses():
    """s32-docwalk: only README.md's blocks were parsed; docs/experiments/README.md shows nine `nlips experiment`
    lines (--scheduler, --config, --check, --write-baseline, --solver-option, --redraw) that no test read."""
    pages = sorted((README.parent / "docs").rglob("*.md"))
    commands = {c: page.name for page in pages for c in readme_commands(page.read_text(encoding="utf-8"))}
    assert sum(c.startswith("nlips experiment") for c in commands) >= 9  # the experiments page's block was read
    assert {c: (page, parse_problem(c)) for c, page in commands.items() if parse_problem(c)} == {}


def test_the_gpu_frame_rate_of_infer_help_is_the_readmes_and_the_measured_one():
    """`nlips infer --help` quoted ~240-360 frames/s on a GPU (an H200, older code) and the README ~210-350 (the
    H100 re-measure at the current code, benchmarks/RESULTS.md, issue 8): now both quote that one, and it is the
    paper net's and the 64-64-64 net's `--device cuda` rows there, rounded."""
    parser = build_parser()
    infer = next(
        action.choices["infer"] for action in parser._actions if isinstance(action, argparse._SubParsersAction)
    )
    device = next(action.help for action in infer._actions if "--device" in action.option_strings)
    (quoted,) = re.findall(r"~(\d+)-(\d+) frames/s at 640x480 on an? (\w+)", device)
    lines = README.read_text(encoding="utf-8").splitlines()
    readme = next(line for line in lines if line.startswith("nlips infer") and "--device cuda" in line)
    assert f"~{quoted[0]}-{quoted[1]} frames/s at 640x480 on an {quoted[2]}" in readme
    results = (README.parent / "benchmarks" / "RESULTS.md").read_text(encoding="utf-8")
    section = results.split("## NLiPsNet on a GPU re-measured at the current code", 1)[1].split("\n## ", 1)[0]
    assert quoted[2] in section.split("\n", 2)[1]  # the card measured
    measured = [int(v) for v in re.findall(r"\| `--device cuda` \| \*\*(\d+)\*\*", section)]  # 64-64-64, paper
    assert abs(int(quoted[0]) - min(measured)) <= 5 and abs(int(quoted[1]) - max(measured)) <= 5, measured
