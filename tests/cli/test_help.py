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
