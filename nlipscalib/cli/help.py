"""What ``nlips`` tells a user who has not read the code: examples under each command's help, the exit statuses,
``--version`` with the libraries a bug report needs, and a close match for a mistyped command or option.

Kept apart from the commands' modules so that one table holds every example (tests parse each one) and one text
the exit statuses (docs/faults.md repeats it).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from collections.abc import Sequence
from typing import NoReturn

EXAMPLES: dict[str, tuple[tuple[str, str], ...]] = {
    "render": (
        ("nlips render --out out/press", "the default press: a 6 mm sphere, 1 mm deep"),
        ("nlips render --indenter cube --depth 0.8 --out out/cube", "a cube's face, 0.8 mm deep"),
        ("nlips render --undeformed --out out/reference", "the undeformed dome (for calibrate-leds)"),
    ),
    "dataset": (
        ("nlips dataset train50 --out out/train50", "the shipped ~50-press spec; run again to resume"),
        ("nlips dataset my_spec.toml --out out/mine --limit 5", "the first 5 presses of your own spec"),
    ),
    "demo": (
        ("nlips demo", "render, solve and score a few presses into out/demo"),
        ("nlips demo --out /tmp/demo --no-solve", "only render them"),
    ),
    "solve": (
        ("nlips solve out/demo/press_0001 --roi auto", "around the contact only (fastest)"),
        ("nlips solve out/train50 --workers 2", "every press of a folder (and its reference/)"),
        ("nlips solve PRESS --roi 100 80 320 240 --out res", "a box x0 y0 w h, pixels; written to res/"),
    ),
    "calibrate-leds": (
        ("nlips calibrate-leds session/reference --out leds.json", "then: nlips solve PRESS --leds leds.json"),
    ),
    "eval": (
        ("nlips eval out/demo/press_0001 --region contact", "AAE of PRESS/nlips on the contact's pixels"),
        ("nlips eval out/train50 --method nlipsnet", "every press's NLiPsNet result, then their mean"),
    ),
    "experiment": (
        ("nlips experiment q1", "the Q1 table, quick size (~10 s)"),
        ("nlips experiment q1 --check q1_quick", "exit 1 when accuracy got worse than the shipped baseline"),
    ),
    "leds": (
        ("nlips leds /dev/ttyACM0 info", "firmware and LED count"),
        ("nlips leds /dev/ttyACM0 set 3 255 255 255", "LED 3 white"),
        ("nlips leds virtual test", "a virtual board, no hardware"),
    ),
    "capture": (
        ("nlips capture --out session --port /dev/ttyACM0 --camera 0", "the sensor: reference, 10 presses"),
        ("nlips capture --out session --emulate nlipstac --presses 3 --yes", "the emulated sensor, no prompts"),
        ("nlips capture --out s --port /dev/ttyACM0 --camera-response curve.json", "a measured tone curve"),
    ),
    "calibrate-camera": (
        ("nlips calibrate-camera boards/ --pattern 8x6 --square 5 --out camera.json", "a 9x7-square checkerboard"),
    ),
    "calibrate-camera-response": (
        ("nlips calibrate-camera-response --port /dev/ttyACM0 --out curve.json", "a webcam's tone curve"),
        ("nlips calibrate-camera-response --emulate nlipstac --out curve.json", "the emulated camera's"),
    ),
    "live": (
        ("nlips live --model model.pt --camera 0 --port /dev/ttyACM0", "the sensor, shown in a window"),
        ("nlips live --model model.pt --emulate nlipstac --max-frames 50 --out frames", "the emulator, saved"),
        ("nlips live --model model.pt --watch incoming/", "a capture program's folder"),
    ),
    "calibrate": (("nlips calibrate session --leds leds.json", "NLiPsNet's training data in session/calibration"),),
    "train": (
        ("nlips train session/calibration --out model.pt", "the paper's net"),
        ("nlips train session/calibration --out small.pt --hidden 64,64,64 --dropout 0", "real-time net"),
    ),
    "lut": (
        ("nlips lut session/calibration --out lut.pt", "then: nlips infer lut.pt session"),
        ("nlips lut session/calibration --out lut.pt --exclude press_0050", "a press kept out, to test on"),
    ),
    "export": (("nlips export model.pt", "model.onnx beside it, checked against PyTorch"),),
    "infer": (
        ("nlips infer model.pt session", "every press of a folder: PRESS/nlipsnet"),
        ("nlips infer model.pt frames/ --out results --ply", "tri-colour image files, with point clouds"),
        ("nlips infer model.pt --watch incoming/ --out results", "frames as they land in a folder, until Ctrl-C"),
    ),
    "verify": (
        ("nlips verify session", "every byte of every press against its checksums.json"),
        ("nlips verify old_dataset --record", "folders written before 2026-12-06: checked, then recorded"),
    ),
    "cache": (
        ("nlips cache", "where the cache is and how much it takes"),
        ("nlips cache --clear", "empty it"),
    ),
}
"""Per command: (command line, what it does). Shown under ``nlips COMMAND --help`` (:func:`examples_text`)."""

EXIT_STATUS = """exit status:
  0    done
  1    done in part: some presses, frames or tasks failed (each named), or `experiment --check` found a regression
  2    not done: bad usage (a mistyped command or option) or an error, said in one line "nlips COMMAND: error: ..."
  130  interrupted (Ctrl-C); finished work is kept, run again to resume
  143  terminated (SIGTERM, a scheduler's time limit); as 130"""
"""The exit statuses of every command, under ``nlips --help`` (docs/faults.md, "Exit status", says the same)."""

VERSION_LIBRARIES = (
    "numpy",
    "scipy",
    "pyamg",
    "matplotlib",
    "opencv",
    "mitsuba",
    "drjit",
    "trimesh",
    "torch",
    "onnxruntime",
    "pyserial",
    "dask",
)
"""Libraries whose versions ``nlips --version`` prints: those whose release changes results or errors (opencv: any
of its distributions, core.libraries.DISTRIBUTIONS)."""


def examples_text(command: str) -> str | None:
    """The ``examples:`` block of ``command``'s help, lines kept as typed (:class:`HelpFormatter`); None: none."""
    rows = EXAMPLES.get(command)
    if not rows:
        return None
    width = max(len(line) for line, _ in rows)
    return "examples:\n" + "\n".join(f"  {line:<{width}}  # {what}" for line, what in rows)


def version_text(package_version: str) -> str:
    """``nlips --version``: the package's version, Python's and the platform's, then each library of
    :data:`VERSION_LIBRARIES` installed (read from its metadata: nothing is imported, so it stays instant)."""
    import platform

    from ..core.libraries import library_versions

    found = [f"{name} {version}" for name, version in library_versions(VERSION_LIBRARIES).items() if version]
    return "\n".join(
        (
            f"nlipscalib {package_version}",
            f"Python {platform.python_version()} on {platform.system()} {platform.machine()}",
            ", ".join(found),
        )
    )


class HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, filling each paragraph (blank-line separated) on its own and keeping a paragraph
    whose second line is indented (``examples:``, ``exit status:``) as typed: the default filled an epilog's
    command lines into one run of words."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        paragraphs = text.split("\n\n")
        return "\n\n".join(
            p if _is_block(p) else super(HelpFormatter, self)._fill_text(p, width, indent) for p in paragraphs
        )


def _is_block(paragraph: str) -> bool:
    lines = paragraph.splitlines()
    return len(lines) > 1 and lines[1].startswith("  ")


_INVALID_CHOICE = re.compile(r"invalid choice: '(?P<typed>[^']*)' \(choose from (?P<choices>.*)\)$")


def add_options_of_every_command(command: argparse.ArgumentParser) -> None:
    """``-v``/``--verbose``, ``-q``/``--quiet``, ``--log-file`` and ``--no-progress`` after the command as well as
    before it:
    ``nlips solve PRESS -v`` was "unrecognized arguments: -v", and ``--no-progress`` was taken by four commands
    only. Their default is SUPPRESS: not typed after the command, the value typed before it (or nlips's default)
    stands, as argparse copies every attribute of the command's namespace over nlips's."""
    have = command._option_string_actions
    if "--verbose" not in have and "-v" not in have:
        command.add_argument(
            "-v",
            "--verbose",
            action="store_true",
            default=argparse.SUPPRESS,
            help="debug logging, as `nlips -v COMMAND`",
        )
    if "--quiet" not in have and "-q" not in have:
        command.add_argument(
            "-q",
            "--quiet",
            action="store_true",
            default=argparse.SUPPRESS,
            help="only warnings and errors on stderr, as `nlips -q COMMAND`",
        )
    if "--log-file" not in have:
        command.add_argument(
            "--log-file",
            metavar="FILE",
            default=argparse.SUPPRESS,
            help="also write every log and result line to FILE (appended)",
        )
    if "--no-progress" not in have:
        command.add_argument(
            "--no-progress",
            action="store_true",
            default=argparse.SUPPRESS,
            help="no progress bars, as `nlips --no-progress`",
        )


class VersionAction(argparse.Action):
    """``--version``: :func:`version_text`'s lines as they are (argparse's filled them into one paragraph), read
    when asked for, not each time the parser is built (every command)."""

    def __init__(self, option_strings: Sequence[str], version: str, dest: str = argparse.SUPPRESS, help: str = ""):
        super().__init__(option_strings, dest=dest, default=argparse.SUPPRESS, nargs=0, help=help)
        self.version = version

    def __call__(self, parser, namespace, values, option_string=None) -> NoReturn:  # noqa: ANN001 (argparse's)
        print(version_text(self.version))
        parser.exit()


DONE_BY = {
    "coverage": "the coverage report and where to press next are written by nlips calibrate (coverage.png and "
    "coverage.json beside its dataset)",
    "onnx": "nlips train writes the ONNX export beside the model; nlips export MODEL writes it again or elsewhere",
    "predict": "nlips infer MODEL runs a model on presses, frames or a video",
    "table": "nlips lut builds the lookup-table baseline",
}
"""What a user types for a job that no command of its name does, and the command that does it: said instead of
argparse's bare "invalid choice" (a new lab's first-day walk looked for ``nlips coverage``, s41-userwalk)."""


class Parser(argparse.ArgumentParser):
    """argparse's parser saying the close match of a mistyped command, choice or option ("did you mean
    'solve'?", :func:`difflib.get_close_matches`), and a mistyped option with the usage of the command it was
    typed for (argparse named the unknown option under ``nlips``'s own usage)."""

    def parse_known_args(self, args=None, namespace=None):  # noqa: ANN001, ANN201 (argparse's signature)
        parsed, extras = super().parse_known_args(args, namespace)
        command = self._subcommand(parsed)
        if extras and command is not None:
            # Python 3.11's subparsers hand unknown options up to this parser, which knew nothing of the command's
            # (only the command's own options: nlips's come before the command)
            command.error(_unrecognized(extras, list(command._option_string_actions)))
        return parsed, extras

    def parse_args(self, args=None, namespace=None):  # noqa: ANN001, ANN201 (argparse's signature)
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            self.error(_unrecognized(extras, list(self._option_string_actions)))
        return parsed

    def _subcommand(self, parsed: argparse.Namespace) -> argparse.ArgumentParser | None:
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                return action.choices.get(getattr(parsed, action.dest, None) or "")
        return None

    def error(self, message: str) -> NoReturn:
        match = _INVALID_CHOICE.search(message)
        if match and message.startswith("argument COMMAND:") and match["typed"] in DONE_BY:
            # a word for what a command does, not a command: one line naming that command, not a bare list
            commands = ", ".join(re.findall(r"'([^']*)'", match["choices"]))
            self.exit(
                2, f"{self.prog}: no command '{match['typed']}': {DONE_BY[match['typed']]}; commands: {commands}\n"
            )
        if match:
            hint = _did_you_mean(match["typed"], re.findall(r"'([^']*)'", match["choices"]))
            if hint:  # before the list of choices, which can be long (the commands)
                head = message[: match.start()]
                message = f"{head}invalid choice: '{match['typed']}'{hint}; choose from {match['choices']}"
        super().error(message)


def _unrecognized(extras: Sequence[str], options: Sequence[str]) -> str:
    """argparse's "unrecognized arguments: ..." with the close match of the mistyped options after them all:
    "--rio auto (did you mean '--roi'?)"; several: "(did you mean '--roi' for --rio, '--overwrite' for --overwrit?)".

    Why: the hint was put after each option, between it and its value ("--rio (did you mean '--roi'?) auto")."""
    from ..core.config import closest

    typed = [word.split("=", 1)[0] for word in extras if word.startswith("-")]
    guesses = [(word, close) for word in typed if (close := closest(word, options)) is not None]
    hint = ""
    if len(guesses) == 1:
        hint = f" (did you mean {guesses[0][1]!r}?)"
    elif guesses:
        hint = f" (did you mean {', '.join(f'{known!r} for {typed}' for typed, known in guesses)}?)"
    return f"unrecognized arguments: {' '.join(extras)}{hint}"


def _did_you_mean(typed: str, known: Sequence[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``known`` to ``typed``, or an empty string."""
    from ..core.config import did_you_mean

    return did_you_mean(typed, known)


def complete_if_asked(parser: argparse.ArgumentParser) -> None:
    """Shell completion of commands, options and choices by argcomplete, when it is installed (optional:
    ``pip install argcomplete``, then ``eval "$(register-python-argcomplete nlips)"`` in the shell's rc file).

    Only when the shell asks (argcomplete's ``_ARGCOMPLETE`` in the environment): otherwise nothing is imported, so
    the commands start as fast as before. argcomplete answers and ends the process itself."""
    if "_ARGCOMPLETE" not in os.environ:
        return
    try:
        import argcomplete
    except ImportError:
        return
    argcomplete.autocomplete(parser)


def print_help_for_no_command(parser: argparse.ArgumentParser) -> NoReturn:
    """``nlips`` alone: the whole help (the commands and what each does), on stderr, exit 2 (usage)."""
    parser.print_help(sys.stderr)
    sys.exit(2)
