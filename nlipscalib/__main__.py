"""``python -m nlipscalib ARGS``: the ``nlips`` command (for a Python without the venv's scripts on PATH)."""

import sys

from .cli import main

sys.exit(main(sys.argv[1:]))
