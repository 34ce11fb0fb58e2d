"""cli/options.py: an option typed at its default value counts as given."""

from __future__ import annotations

import argparse

import pytest

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


@pytest.mark.parametrize(
    "width, height, line",
    [
        (
            160,
            None,
            "--width 160 without --height: the images would be 160x480 pixels (the scene's other side kept, "
            "not its 640x480 shape); give both, e.g. --width 160 --height 120",
        ),
        (
            None,
            90,
            "--height 90 without --width: the images would be 640x90 pixels (the scene's other side kept, "
            "not its 640x480 shape); give both, e.g. --width 120 --height 90",
        ),
    ],
)
def test_one_image_side_alone_is_refused_with_both_to_give(width, height, line):
    from nlipscalib.cli.options import check_size_pair
    from nlipscalib.core.errors import ConfigError

    with pytest.raises(ConfigError) as err:
        check_size_pair(width, height, (640, 480))
    assert str(err.value) == line
    check_size_pair(None, None, (640, 480))  # neither: the scene's size
    check_size_pair(160, 480, (640, 480))  # both, whatever their shape: as typed
