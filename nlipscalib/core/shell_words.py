"""Paths written into a command a message suggests (``next: nlips train DATASET --out MODEL.pt``), so that the
line copied into a shell runs: a path holding a space, a quote or another character the shell reads is quoted.

Why: a lab's folder is often named with a space or an accent (``mes données/session 1``); the suggested command
printed it bare, and pasted into bash it became two arguments ("nlips train: error: unrecognized arguments").
Paths of safe characters (letters, digits, ``_@%+=:,./-``) are printed as they were, so most lines are unchanged.
"""

from __future__ import annotations

import os
import shlex
from pathlib import PurePath


def shell_word(value: str | PurePath) -> str:
    """``value`` as one word of a command line a user copies: quoted only where the shell would split or read it.

    Parameters
    ----------
    value : a path (or another argument) as the user typed it or the command made it

    Returns
    -------
    str: the value itself when it needs no quoting; else POSIX single quotes (``shlex.quote``), or on Windows
    the double quotes of its command line (``subprocess.list2cmdline``)
    """
    text = str(value)
    if os.name == "nt":  # cmd.exe and PowerShell read double quotes, not POSIX single ones
        import subprocess

        return subprocess.list2cmdline([text])
    return shlex.quote(text)
