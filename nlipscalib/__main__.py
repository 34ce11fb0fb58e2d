"""``python -m nlipscalib ARGS``, and the ``nlips`` console script: the ``nlips`` command, with a Ctrl-C while its
modules load said in one line.

Why here: the command's modules (argparse, the CLI's, NumPy's for some) take ~0.3 s to load on an idle machine and
~1 s under load, before the command sets its own Ctrl-C handling; a Ctrl-C then printed a KeyboardInterrupt
traceback of the imports and ended the process by the signal. This module imports nothing of the package before
that guard (the package's ``__init__`` holds only its version)."""

import sys

INTERRUPTED_EARLY = "nlips: interrupted before the command began; nothing was done"
"""The line of a Ctrl-C while the command's modules load or its arguments are read (exit status 130)."""


def command() -> None:
    """Run the ``nlips`` command (:func:`nlipscalib.cli.command`) in this process, which it ends."""
    try:
        from .cli import command as run
    except KeyboardInterrupt:
        print(INTERRUPTED_EARLY, file=sys.stderr)
        sys.exit(130)
    run()


if __name__ == "__main__":
    command()
