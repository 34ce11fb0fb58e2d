"""Options whose presence matters, not only their value.

argparse stores an option's default without a trace, so a check that compares an option with its default
(``args.seed != 0``) takes ``--seed 0`` for no ``--seed`` at all: an option typed at its default value
then escapes a conflict check ("not used with --emulate"), or loses to what would win over an absent
option (a press script's length, a config file). Such options are declared with ``default=None`` and a
table of their real defaults: :func:`typed` says which of them the user typed, then
:func:`fill_defaults` puts the real defaults in and records what was typed in ``args.typed_options``.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable

TYPED = "typed_options"
"""Attribute of the parsed arguments: the options (dests) the user typed, recorded by :func:`fill_defaults`."""
DEFAULTED = "defaulted_options"
"""Attribute of the parsed arguments: the options :func:`fill_defaults` gave their default (not typed)."""


def typed(args: argparse.Namespace, dests: Iterable[str]) -> list[str]:
    """The options among ``dests`` that the user typed, in the order of ``dests``.

    Parameters
    ----------
    args : argparse.Namespace; the options in ``dests`` have ``default=None`` (or were recorded by
        :func:`fill_defaults`)
    dests : iterable of option dests (``"exposure_ms"`` for ``--exposure-ms``)

    Returns
    -------
    list of str
    """
    given, defaulted = getattr(args, TYPED, frozenset()), getattr(args, DEFAULTED, frozenset())
    return [d for d in dests if d in given or (d not in defaulted and getattr(args, d, None) is not None)]


def fill_defaults(args: argparse.Namespace, defaults: dict) -> None:
    """Give every option of ``defaults`` that the user did not type its real default, remembering the typed ones.

    Parameters
    ----------
    args : argparse.Namespace, changed in place; ``args.typed_options`` and ``args.defaulted_options``
        (frozensets of dests) gain the options of ``defaults`` that were typed and those that were not, so
        :func:`typed` still answers afterwards
    defaults : dest -> the value the option has when not typed
    """
    given = set(typed(args, defaults))
    setattr(args, TYPED, getattr(args, TYPED, frozenset()) | given)
    setattr(args, DEFAULTED, getattr(args, DEFAULTED, frozenset()) | (set(defaults) - given))
    for dest, value in defaults.items():
        if dest not in given:
            setattr(args, dest, value)


def option(dest: str) -> str:
    """The command-line spelling of an option's dest: ``exposure_ms`` -> ``--exposure-ms``."""
    return "--" + dest.replace("_", "-")


def check_size_pair(width: int | None, height: int | None, scene_size: tuple[int, int]) -> None:
    """A ConfigError when only one of ``--width`` and ``--height`` was given.

    Why: the other side stayed the scene's, so ``nlips render --width 160`` rendered 160x480 images (the dome a
    small disc in a tall black strip) and ``nlips capture --emulate nlipstac --height 120`` 640x120 ones, without a
    word, and every later command took that odd camera for the sensor's.

    Parameters
    ----------
    width, height : int or None
        The typed ``--width`` and ``--height`` (None: not given).
    scene_size : (int, int)
        The scene's image size (width, height), pixels, for the line's example.
    """
    from ..core.errors import ConfigError

    if (width is None) == (height is None):
        return
    scene_w, scene_h = scene_size
    if width is not None:
        given, missing, made = f"--width {width}", "--height", f"{width}x{scene_h}"
        both = f"--width {width} --height {max(1, round(width * scene_h / scene_w))}"
    else:
        given, missing, made = f"--height {height}", "--width", f"{scene_w}x{height}"
        both = f"--width {max(1, round(height * scene_w / scene_h))} --height {height}"
    raise ConfigError(
        f"{given} without {missing}: the images would be {made} pixels (the scene's other side kept, not its "
        f"{scene_w}x{scene_h} shape); give both, e.g. {both}"
    )
