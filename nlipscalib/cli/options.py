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


SOLVE_WORKERS_HELP = (
    "presses solved at once, one process each (default 0: one per two usable cores, a container's CPU quota "
    "counted: 1 on a 2- or 3-core machine, where one process already solves each press on both cores' threads; "
    "fewer where the memory available holds fewer); the cores are shared out as threads among the workers"
)
"""Help of the solver pool's ``--workers`` of every command that solves presses (``solve``, ``calibrate``, and
``demo --solve-workers``): one default, :func:`nlipscalib.core.cpus.solve_worker_count`."""
RENDER_WORKERS_HELP = (
    "render processes (default 0: one per two usable cores, each rendering on two cores' threads; fewer where the "
    "memory available holds fewer)"
)
"""Help of the render pool's ``--workers`` (``dataset``, ``demo``): one default, :func:`nlipscalib.sim.dataset_pool.
run_dataset`'s ``workers=0``."""


def add_led_model(parser: argparse.ArgumentParser) -> None:
    """``--led-model auto|points|disks`` (dest ``led_model``) of every command that solves presses (``solve``,
    ``calibrate``): one flag, one text, :func:`nlipscalib.pipeline.solve_presses`' ``led_model``."""
    parser.add_argument(
        "--led-model",
        choices=("auto", "points", "disks"),
        default="auto",
        help="how the LEDs are modelled. auto (default): the capture's own LEDs as disks of the size its design "
        "declares where points would miss their light unevenly over the gel (the flat pad, oblate, capsule and "
        "fingertip designs: the flat pad's cube press 0.89 -> 0.24 deg, the fingertip's 1.34 -> 1.23 deg on "
        "average), as points otherwise (the hemisphere); "
        "--leds FILE's by the same rule: its fitted disks there, points elsewhere (a FILE of point LEDs: points, as "
        "given); one INFO line says so where it picks disks (-v: why points). points: always points. disks: --leds "
        "FILE's fitted disks (~1.1x the solve's CPU; for a view that sees the gel beside the LEDs, where points "
        "misplace the whole gel's depth by up to 0.1 mm), or without it the design's disks",
    )


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
    """A ConfigError when only one of ``--width`` and ``--height`` was given, the other side the scene's
    (:func:`nlipscalib.core.config.check_size_pair`; imported when called, as this module's other checks)."""
    from ..core.config import check_size_pair as check

    check(width, height, scene_size)


def add_allow_edited(parser: argparse.ArgumentParser, what: str) -> None:
    """``--allow-edited`` (dest ``allow_edited``) of every command that reads presses (``solve``, ``calibrate``,
    ``calibrate-leds``, ``train``, ``infer``, ``eval``): one flag,
    :data:`nlipscalib.core.press_checksums.EDITED_OPTION`. ``what``: what the command then does with such a press,
    for its help."""
    parser.add_argument(
        "--allow-edited",
        action="store_true",
        help=f"{what} a press whose files are not the size its checksums.json recorded when it was written (images "
        "edited on purpose); default: refused in one line naming the file, as another file copied over one (a "
        "stat per file, no image read)",
    )
