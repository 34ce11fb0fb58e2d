"""Checks of the folders a command is told to read from or write into, shared by the commands."""

from __future__ import annotations

from pathlib import Path

from ..core.errors import ConfigError
from ..core.press_folders import find_presses, is_press_folder
from ..core.press_meta import META_FILE, REFERENCE_FOLDER


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


def check_one_capture(folder: str | Path, role: str) -> None:
    """A ConfigError when ``folder`` is a folder of presses (a dataset, a session) where one capture is expected.

    Why: ``nlips calibrate-leds out/train50`` and ``nlips solve PRESS --reference out/train50`` said only
    "out/train50/meta.json: missing; out/train50 is not a complete press folder", and left the user to find that
    the folder's undeformed dome is its ``reference/``. ``role`` names what was expected: "the undeformed dome's
    capture". Anything else (a capture, a missing folder, a broken press) is left to the loader's own message.
    """
    folder = Path(folder)
    if is_press_folder(folder) or not folder.is_dir():
        return
    reference = folder / REFERENCE_FOLDER
    if is_press_folder(reference):
        raise ConfigError(f"{folder}: a folder of presses, not {role}; its undeformed dome is {reference} (give that)")
    if find_presses(folder):
        raise ConfigError(f"{folder}: a folder of presses, not {role}; give one capture's folder")
