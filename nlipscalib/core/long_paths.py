"""Windows' 260-character path limit: a warning before long work when an output folder is long enough that a path the
command makes below it would pass the limit.

Windows refuses a path of 260 characters or more (``MAX_PATH``, its terminating NUL included) unless long paths are
on: the registry value ``LongPathsEnabled`` (HKLM\\SYSTEM\\CurrentControlSet\\Control\\FileSystem) set to 1, which
Python (3.6+, marked long-path aware) then uses. Past the limit a write fails with FileNotFoundError naming the
path, possibly an hour into an experiment; the warning comes before the work, once per process.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

MAX_PATH = 260
"""Windows' limit on a path's length, its terminating NUL included: 259 characters usable (a folder's 248: room is
kept for a short name; the deepest folders a command makes are shorter by more than 12 than its deepest file)."""
DEEPEST_BELOW_OUT = {"experiment": 200, "dataset": 120}
"""Longest path (characters, the separator after OUT included) a command makes below its ``--out``, temporary and
claim names included. Measured with an audit hook recording every path opened, made or renamed
(benchmarks/RESULTS.md, s27-windows): ``nlips experiment q1`` (quick) 181, a task's solve claim
(``OUT/q1-quick/presses/TASK/solves/.claim-KEY~run~...``, 120 characters of claim name); 200 allows a longer work
folder (``ablation-medium``) and task id (q2's ``cylinder-p23.6-a306.9-d1.55-...``, 46 characters, 35 in q1).
``nlips dataset`` 78 (a press's temporary folder and a file's temporary in it,
``OUT/.tmp-press_0001~vm~15641~RANDOM/.tmp-tricolor.png~vm~15641~RANDOM``: 64 + 2 x (host + pid characters)); 120
allows a Windows host name of 15 characters (``DESKTOP-XXXXXXX``) and a 10-digit process id in both."""

WINDOWS = sys.platform == "win32"
"""Whether the limit holds here (macOS and Linux allow 1024 and 4096 characters)."""

log = logging.getLogger(__name__)
_warned: set[str] = set()
"""Output folders warned about in this process (once each)."""


def long_paths_enabled() -> bool:
    """Whether Windows accepts paths past :data:`MAX_PATH` (``LongPathsEnabled`` is 1); False where unreadable."""
    try:
        import winreg  # Windows only
    except ImportError:
        return False
    try:
        with winreg.OpenKey(winreg.HKEY_LOCAL_MACHINE, r"SYSTEM\CurrentControlSet\Control\FileSystem") as key:
            return winreg.QueryValueEx(key, "LongPathsEnabled")[0] == 1
    except OSError:
        return False


def warn_if_too_long(out: str | Path, command: str, option: str = "--out") -> bool:
    """On Windows without long paths, warn once (one log line naming ``out``) when the deepest path ``command``
    makes below ``out`` (:data:`DEEPEST_BELOW_OUT`) would reach :data:`MAX_PATH`; True if it warned.

    Parameters
    ----------
    out : the command's output folder, as given (made absolute here: the limit counts the whole path)
    command : a key of :data:`DEEPEST_BELOW_OUT`
    option : the flag naming ``out``, for the remedy
    """
    if not WINDOWS:
        return False
    folder = str(Path(out).absolute())
    longest = len(folder) + DEEPEST_BELOW_OUT[command]
    if longest < MAX_PATH or folder in _warned or long_paths_enabled():
        return False
    _warned.add(folder)
    room = MAX_PATH - 1 - DEEPEST_BELOW_OUT[command]
    log.warning(
        "%s: paths up to %d characters will be made below this folder, past Windows' %d-character limit (writes "
        "there fail): choose a %s of at most %d characters, or turn long paths on (registry value LongPathsEnabled = 1 "
        "in HKLM\\SYSTEM\\CurrentControlSet\\Control\\FileSystem)",
        folder,
        longest,
        MAX_PATH - 1,
        option,
        room,
    )
    return True
