"""``python -m nlipscalib ARGS``: the ``nlips`` command (for a Python without the venv's scripts on PATH)."""

import sys

from .cli import command

sys.exit(command())
