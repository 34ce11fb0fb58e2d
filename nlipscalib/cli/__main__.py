"""``python -m nlipscalib.cli ARGS``: the ``nlips`` command."""

import sys

from . import command

sys.exit(command())
