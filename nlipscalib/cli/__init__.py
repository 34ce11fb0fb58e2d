"""The ``nlips`` command: the only place where sim/, device/, solver/ and learn/ are wired together.

Each subcommand lives in its own module here exposing ``register(subparsers)``; that function adds
its parser and sets ``func`` to a callable taking the parsed ``args`` and returning an exit code.
Heavy imports happen inside those callables, so ``nlips --help`` is instant.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from .. import __version__
from ..errors import MissingDependencyError, NlipsError

SUBCOMMAND_MODULES = ("render", "dataset", "demo", "solve", "calibrate", "evaluate", "calibration", "train", "infer")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="nlips", description="NLiPsCalib: digital twin, NLiPs solver and NLiPsNet for curved tactile sensors."
    )
    parser.add_argument("--version", action="version", version=f"nlipscalib {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="show debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:
            if exc.name == f"{__name__}.{name}":
                continue  # subcommand not built yet
            raise
        module.register(sub)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(message)s")
    try:
        return int(args.func(args) or 0)
    except (NlipsError, MissingDependencyError, FileExistsError) as exc:
        print(f"nlips {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"nlips {args.command}: interrupted; finished work is kept, run again to resume", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
