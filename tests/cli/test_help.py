"""`nlips COMMAND --help` as a user reads it: plain text, with the defaults named."""

import argparse

import pytest

from nlipscalib.cli import build_parser, main, plain_text


def _commands() -> dict:
    subs = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return subs.choices


@pytest.mark.parametrize("name", sorted(_commands()))
def test_help_shows_no_restructuredtext_markup(name):
    """cache, demo, eval and experiment take their description from a docstring: its ``literals`` showed verbatim."""
    text = _commands()[name].format_help()
    assert "``" not in text and ":func:`" not in text and ":class:`" not in text


def test_plain_text_drops_inline_markup_only():
    doc = "``nlips eval PATH``: see :func:`evaluate` and ``PRESS/nlips``; type `nlips solve PRESS`"
    assert plain_text(doc) == "nlips eval PATH: see evaluate and PRESS/nlips; type `nlips solve PRESS`"
    assert plain_text(None) is None


def test_eval_help_names_the_region_default(capsys):
    with pytest.raises(SystemExit):
        main(["eval", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "pixels to score: all (default:" in text


@pytest.mark.parametrize("name", sorted(_commands()))
def test_help_says_where_the_checkout_files_it_names_are(name):
    """Help naming docs/formats.md or firmware/README.md was a dead end for a wheel's user (those come with the
    sdist or the repository only); scenes/ paths and the README have built-in alternatives (a shipped name, the
    text itself)."""
    from nlipscalib.cli import SOURCE_NOTE

    text = " ".join(_commands()[name].format_help().split())
    assert "scenes/" not in text and "README" not in text.replace("firmware/README.md", "")
    if "docs/" in text or "firmware/" in text:
        assert " ".join(SOURCE_NOTE.split()) in text


@pytest.mark.parametrize("name", sorted(_commands()))
def test_every_option_with_a_value_by_default_names_it(name):
    """A user reads only --help: `nlips train --hidden` said "paper 256,256,128", `--threads` "0: all", the
    emulator's --width "emulated image width" (what is used when it is not given?). An option that has a value
    when not given says "default" in its help; one without (None) means "not used" and may say so its own way."""
    quiet = (argparse._StoreTrueAction, argparse._StoreFalseAction, argparse._StoreConstAction, argparse._HelpAction)
    unnamed = [
        action.option_strings[-1]
        for action in _commands()[name]._actions
        if action.option_strings
        and not isinstance(action, quiet)
        and not action.required
        and action.default not in (None, [], argparse.SUPPRESS)
        and "default" not in (action.help or "").lower()
    ]
    assert unnamed == []


def test_live_and_infer_say_alike_what_their_threads_option_does_when_not_given():
    """The same network runtime runs under both (learn.infer.Predictor, threads=0 when not given), but `nlips live
    --threads` said "(0: the library's default)", which names no value, while `nlips infer --threads` said "default
    0: all this process may use" (the check above took "library's default" for a default named)."""
    live, infer = (_commands()[name]._option_string_actions["--threads"] for name in ("live", "infer"))
    assert live.default == infer.default == 0
    assert live.help == infer.help and "default 0: all this process may use" in live.help
