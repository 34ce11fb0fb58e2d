"""Checks of the folders a command is told to write into, shared by the commands that write many press folders."""

from __future__ import annotations

from pathlib import Path

from ..core.capture import META_FILE, is_press_folder
from ..core.errors import ConfigError


def check_not_in_press(out: Path, what: str) -> None:
    """A ConfigError when ``out`` is, or lies inside, a press folder (nothing written yet).

    Why: ``nlips dataset SPEC --out out/press`` and ``nlips capture --out out/press`` wrote their reference/ and
    press folders among that press's images, exit 0, and every later command took the folder for the one press
    it was. ``what`` ends the message: "render the dataset", "capture the session".
    """
    for part in (out, *out.parents):
        if is_press_folder(part):
            where = "" if part == out else f"lies in {part}, which "
            raise ConfigError(f"{out}: {where}is a press folder (it has {META_FILE}); {what} into another folder")
        if part.exists():
            return
