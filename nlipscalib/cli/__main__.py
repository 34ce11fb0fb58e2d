"""``python -m nlipscalib.cli ARGS``: the ``nlips`` command."""

import sys

from . import main

sys.exit(main(sys.argv[1:]))
