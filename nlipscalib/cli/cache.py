"""``nlips cache``: where the sensor-level results kept between commands are, how much they take; ``--clear``.

Every solve of a press computes some results from the sensor alone (the undeformed surface's shading and
radiosity patches, a whole frame's difference operators, the interreflection fit on an undeformed capture).
They are kept on disk so the next command on the same sensor starts from them (docs/formats.md, "Disk cache
of sensor-level results").
The folder is ``$NLIPS_CACHE_DIR`` (``off`` turns the cache off), else ``$XDG_CACHE_HOME/nlipscalib``,
else ``~/.cache/nlipscalib``; it holds at most ``$NLIPS_CACHE_MB`` megabytes (default 2048).
"""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "cache", help="show (or --clear) the sensor-level results kept between commands", description=__doc__
    )
    p.add_argument("--clear", action="store_true", help="remove every cached result")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import os

    from ..core import diskcache

    if args.clear:
        _check_clearable(diskcache.configured_folder())
    root = diskcache.folder()
    if root is None:
        print(f"cache: off ({diskcache.ENV_DIR}={os.environ.get(diskcache.ENV_DIR)!r})")
        return 0
    if args.clear:
        freed = diskcache.clear(root)
        print(f"cache: {root}: removed {freed / 2**20:.1f} MB")
        return 0
    entries, size = diskcache.usage(root)
    limit = diskcache.limit_bytes() / 2**20
    print(f"cache: {root}: {entries} entries, {size / 2**20:.1f} MB (at most {limit:.0f} MB)")
    return 0


def _check_clearable(root: Path | None) -> None:
    """--clear asked for, and a file where the cache folder should be: an error (solves only warn and go on
    without the cache), naming the variable that says where the cache is."""
    import os

    from ..core import diskcache
    from ..core.errors import ConfigError

    if root is None or not root.exists() or root.is_dir():
        return
    where = f"{diskcache.ENV_DIR}={root}" if os.environ.get(diskcache.ENV_DIR) else f"{root} (the default cache folder)"
    raise ConfigError(
        f"{where}: a file, not a folder; nothing to clear (set {diskcache.ENV_DIR} to a folder, or to 'off')"
    )
