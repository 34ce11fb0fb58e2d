"""Checks of the folders a command is told to read from or write into, shared by the commands."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from ..core.errors import ConfigError
from ..core.press_folders import find_presses, is_press_folder
from ..core.press_meta import META_FILE, REFERENCE_FOLDER


def names_a_folder(path: str | os.PathLike) -> bool:
    """Whether ``path``, given for a file to write, is a folder or is typed as one (ends in a path separator).

    Why: ``nlips calibrate-leds REF --out out/leds/`` (a folder meant, not there yet) wrote the LED file as
    ``out/leds`` (pathlib drops the slash) and printed ``out/leds/``; ``--log-file logs/`` said only "logs: Is a
    directory", naming no option.
    """
    text = os.fspath(path)
    return Path(text).is_dir() or text.endswith(tuple(sep for sep in (os.sep, os.altsep) if sep))


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
    from ..core.reconstruction import is_reconstruction_dir

    if is_reconstruction_dir(folder):  # PRESS/nlips: was "PRESS/nlips/meta.json: missing; ... not a complete press"
        made = f": the maps made from {folder.parent}" if is_press_folder(folder.parent) else ""
        raise ConfigError(f"{folder}: a reconstruction folder (result.npz{made}), not {role}")


def check_undeformed(folder: str | Path, role: str, way_out: str, suggest: str | Path | None = None) -> None:
    """A ConfigError when ``folder`` is a twin render of a press (its meta.json records the indenter) where the
    undeformed dome's capture is expected; ``role`` names that ("the undeformed dome's capture (--reference)"),
    ``way_out`` ends the line ("or solve without --reference"), ``suggest`` is the reference/ to name when it holds
    a capture (the solved press's; default: the one beside ``folder``: `nlips solve out/press --reference
    out/other/press_0001` named out/other/reference, of another dataset).

    Why: ``nlips solve PRESS --reference OTHER_PRESS`` and ``nlips calibrate FOLDER --reference FOLDER/press_0002``
    solved against the other press's dented dome, exit 0: its contact and its anchoring came out wrong without a
    word; ``nlips calibrate-leds PRESS`` fitted the LEDs first (minutes at 640x480) and refused after the fit. A
    capture of the real sensor records no press, so only the twin's renders are told apart here; anything else
    (a broken meta.json) is left to the loader's own message.
    """
    from ..core.errors import CaptureError
    from ..core.press_meta import read_meta

    folder = Path(folder)
    if not is_press_folder(folder):
        return
    try:
        provenance = read_meta(folder).get("provenance")
    except CaptureError:
        return
    press = provenance.get("press") if isinstance(provenance, dict) and provenance.get("source") == "sim" else None
    if not isinstance(press, dict):
        return
    candidates = [Path(suggest)] if suggest is not None else []
    sibling = next(
        (c for c in [*candidates, folder.parent / REFERENCE_FOLDER] if c != folder and is_press_folder(c)), None
    )
    given = f"{REFERENCE_FOLDER}/ ({sibling}), " if sibling is not None else ""
    raise ConfigError(
        f"{folder}: a press of the twin ({pressed_words(press)}), not {role}; give {given}an undeformed render "
        f"(`nlips render --undeformed` with the press's scene and options), {way_out}"
    )


def pressed_words(press: dict) -> str:
    """'a sphere of 6 mm pressed 1.50 mm deep' from a twin press's description (meta.json's provenance.press)."""
    indenter = press.get("indenter") if isinstance(press.get("indenter"), dict) else {}
    kind, size, depth = indenter.get("kind"), indenter.get("size"), press.get("depth")
    what = f"a {kind}" if isinstance(kind, str) and kind.isprintable() else "an indenter"
    if isinstance(size, (int, float)):
        what += f" of {size:g} mm"
    return what + (f" pressed {depth:.2f} mm deep" if isinstance(depth, (int, float)) else "")


def remove_if_left_empty(stack: contextlib.ExitStack, folders: Iterable[Path]) -> None:
    """Have ``stack`` remove, as it closes, each of ``folders`` (and their ancestors) that does not exist now and is
    empty then, deepest first; call it before entering what may make them (the run's holds: core.claims makes the
    folder a claim file lies in). A SIGTERM meanwhile removes them too (:func:`remove_all_left_empty`).

    Why: a run's holds on its outputs are taken before its inputs are read, and make the folders their claim files
    lie in (``OUT/PRESS`` for a press's result under --out, a missing parent of --out); a run refused for a bad
    input or model (one line, nothing written) left them empty behind it. A folder another process has put
    something into meanwhile (its claims, results) is kept."""
    stack.enter_context(left_empty_removed(folders))


@contextlib.contextmanager
def left_empty_removed(folders: Iterable[str | os.PathLike], kept: Callable[[], bool] | None = None) -> Iterator[None]:
    """Remove, as the block ends, each of ``folders`` (and their ancestors) that does not exist now and is empty
    then, deepest first; unless ``kept`` (asked as the block ends without an exception) says True: a command that
    succeeded keeps what it made as it made it. A SIGTERM during the block removes them too: the command's
    handler ends the process at once (``cli._end_at_once``, no ``finally`` runs) and calls
    :func:`remove_all_left_empty`.

    Why: a run stopped by SIGTERM before its first write (a scheduler's time limit while ``nlips calibrate`` solved)
    left its empty output folder, which the next run or ``nlips train`` took for a dataset never finished, where
    Ctrl-C removed it (s36-apiwalk)."""
    missing = _missing(folders)
    _LEFT_EMPTY.append(missing)
    ended_well = False
    try:
        yield
        ended_well = True
    finally:
        with contextlib.suppress(ValueError):  # a SIGTERM's handler may have taken it meanwhile
            _LEFT_EMPTY.remove(missing)
        if not (ended_well and kept is not None and kept()):
            _remove_empty(missing)


def remove_all_left_empty() -> None:
    """Remove every folder of the blocks of :func:`left_empty_removed` under way that is empty now (for a SIGTERM
    handler about to end the process, after the claims and temporaries in them were removed)."""
    while _LEFT_EMPTY:
        _remove_empty(_LEFT_EMPTY.pop())


_LEFT_EMPTY: list[list[Path]] = []
"""The folders (deepest first) of each block of :func:`left_empty_removed` under way, innermost last."""


def _missing(folders: Iterable[str | os.PathLike]) -> list[Path]:
    """Those of ``folders`` and their ancestors that do not exist now, deepest first."""
    missing = set()
    for folder in folders:
        for part in (Path(folder), *Path(folder).parents):
            if part.exists():
                break
            missing.add(part)
    return sorted(missing, key=lambda p: len(p.parts), reverse=True)


def _remove_empty(folders: list[Path]) -> None:
    for part in folders:
        with contextlib.suppress(OSError):  # not empty (a result, another run's claim), a file, or gone
            part.rmdir()
