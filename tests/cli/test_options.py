"""cli/options.py: an option typed at its default value counts as given."""

from __future__ import annotations

import argparse

from nlipscalib.cli.options import fill_defaults, option, typed

DEFAULTS = {"seed": 0, "camera": "0"}


def _parse(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    p.add_argument("--seed", type=int)
    p.add_argument("--camera")
    p.add_argument("--port")
    return p.parse_args(argv)


def test_an_option_typed_at_its_default_is_given():
    args = _parse("--seed", "0")
    assert typed(args, ("seed", "camera", "port")) == ["seed"]
    fill_defaults(args, DEFAULTS)
    assert (args.seed, args.camera, args.port) == (0, "0", None)
    # still known after the defaults are in: --seed was typed, --camera was not
    assert typed(args, ("seed", "camera", "port")) == ["seed"]
    assert args.typed_options == {"seed"}


def test_nothing_typed_gets_the_defaults():
    args = _parse()
    fill_defaults(args, DEFAULTS)
    assert (args.seed, args.camera) == (0, "0") and typed(args, DEFAULTS) == []
    fill_defaults(args, {"port": "loop://"})  # a second table keeps what the first recorded
    assert args.port == "loop://" and typed(args, ("seed", "port")) == []


def test_option_spelling():
    assert option("exposure_ms") == "--exposure-ms"


def test_every_command_has_a_description_and_every_option_a_help_text():
    """`nlips capture --help` and `nlips live --help` were a usage line and a list of options: what the command
    does was nowhere."""
    import argparse

    from nlipscalib.cli import build_parser

    missing = []

    def walk(parser, name):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub, subparser in action.choices.items():
                    if not subparser.description:
                        missing.append(f"{name} {sub}: no description")
                    walk(subparser, f"{name} {sub}")
            elif not action.help and action.dest != "help":
                missing.append(f"{name} {action.option_strings or action.dest}: no help")

    walk(build_parser(), "nlips")
    assert not missing
