"""Press folders found in a tree: whether a folder is a press (:func:`is_press_folder`) or an incomplete one, the
presses at or below a root (:func:`find_presses`) with the undeformed dome's capture kept apart
(:func:`split_reference`), and the error when there is none (:func:`no_presses_error`)."""

from __future__ import annotations

import logging
from pathlib import Path

from .atomic import TMP_PREFIX
from .errors import CaptureError, ConfigError
from .press_meta import META_FILE, REFERENCE_FOLDER, SOURCE_SENSOR, listed_files, press_source, read_meta

log = logging.getLogger(__name__)


def is_press_folder(folder: str | Path) -> bool:
    """True when ``folder`` holds a meta.json (complete press folders are written atomically)."""
    return (Path(folder) / META_FILE).is_file()


def check_render_out(out: str | Path, overwrite: bool, flag: bool = False) -> None:
    """Refuse a render's output ``out`` that is a file or a folder holding other things than a press, with or
    without ``overwrite``, or an empty folder without it (ConfigError naming it and what to do); a new path, a
    twin's press folder, or an empty folder with ``overwrite`` pass. ``flag``: the remedy worded for ``nlips
    render`` (``--out``, ``--overwrite``), else for :func:`nlipscalib.sim.press.render_press` (``out_folder``,
    ``overwrite=True``).

    Why: ``--overwrite`` replaced whatever was there with the rendered press: ``nlips render --out out/train50
    --overwrite`` deleted a whole dataset, ``--out notes.txt --overwrite`` the user's file (``nlips solve --out``
    refuses the same, tests/test_pipeline.py); ``render_press`` into a folder of other things said only
    "FileExistsError: already exists" after the whole render (s36-apileft)."""
    out = Path(out)
    option, again = ("--out", "--overwrite") if flag else ("out_folder", "overwrite=True")
    if not (out.exists() or out.is_symlink()):
        return
    if out.is_dir() and is_press_folder(out) and press_source(out) == SOURCE_SENSOR:
        # it said "rendered from a different scene, press or seed (...: an older nlipscalib rendered it)" and
        # --overwrite then deleted the capture
        raise ConfigError(
            f"{out}: holds a press captured on a sensor (nlips capture), not a twin render; nothing is replaced, "
            f"even with {again} (a press cannot be rendered back): render into another {option}"
        )
    if out.is_dir() and is_press_folder(out):
        return
    if out.is_dir() and not any(out.iterdir()):
        if not overwrite:
            raise ConfigError(f"{out}: exists and is not a press folder; choose another {option} or use {again}")
        return
    if out.is_dir():
        raise ConfigError(
            f"{out}: a folder holding other things than a press (no meta.json); nothing is replaced, even with "
            f"{again}: choose another {option}"
        )
    raise ConfigError(f"{out}: a file where a folder is needed (choose another {option}, or move the file)")


def find_presses(root: str | Path) -> list[Path]:
    """Press folders at ``root`` (itself a press) or directly below it, sorted by name.

    Folders below ``root`` that hold press images but no meta.json (an interrupted or partial write)
    are skipped with a warning naming each, never silently.
    """
    root = Path(root)
    if is_press_folder(root):
        return [root]
    if root.exists() and not root.is_dir():
        raise CaptureError(f"{root}: a file, not a press folder nor a folder of presses")
    if not root.is_dir():
        raise CaptureError(f"{root}: no such folder")
    presses = []
    for p in sorted(root.iterdir()):
        if not p.is_dir() or p.name.startswith(TMP_PREFIX):  # a write in progress or interrupted
            continue
        if is_press_folder(p):
            presses.append(p)
        elif is_incomplete_press(p):
            log.warning("%s: incomplete press folder (no %s; an interrupted write): skipped", p, META_FILE)
    return presses


def missing_capture_files(folder: str | Path) -> dict[str, str]:
    """Files a press folder's meta.json lists (images, reference, ground truth) that are not there, are empty or
    cut short (:func:`.file_checks.file_problem`: what a power cut soon after the folder was published leaves), or
    are of another size than its checksums.json records (another file copied over one), each with its problem in a
    few words (:func:`.press_checksums.press_file_problems`); {} for a whole press.

    CaptureError (naming meta.json) when meta.json itself is missing or malformed."""
    from .press_checksums import press_file_problems

    return press_file_problems(folder, listed_files(read_meta(Path(folder))))


def no_presses_error(root: str | Path) -> CaptureError:
    """The error for a ``root`` in which :func:`find_presses` found no press: a press folder that lacks its
    meta.json says so (not "no press folders found", which sends the user looking for the wrong thing), and so
    does a reconstruction folder."""
    if is_incomplete_press(root):
        return CaptureError(
            f"{Path(root) / META_FILE}: missing; {root} holds press images but no {META_FILE} (an interrupted "
            "write or a deleted file): capture or render it again"
        )
    from .reconstruction import RESULT_FILE

    if (Path(root) / RESULT_FILE).is_file():  # PRESS/nlips given for PRESS: "no press folders found" said no more
        return CaptureError(f"{root}: a reconstruction folder ({RESULT_FILE}), not a press: give the press folder")
    return CaptureError(f"{root}: no press folders found")


def is_incomplete_press(folder: str | Path) -> bool:
    """True when ``folder`` holds press images (dark, tri-colour or LED frames) but no meta.json."""
    folder = Path(folder)
    if is_press_folder(folder) or not folder.is_dir():
        return False
    return any((folder / name).is_file() for name in ("dark.png", "tricolor.png")) or any(folder.glob("led_*.png"))


def split_reference(root: str | Path, reference: str | Path | None = None) -> tuple[list[Path], Path | None]:
    """The presses at ``root`` (:func:`find_presses`) and the undeformed dome's capture, kept apart.

    ``reference``: the capture named by the user; None: ``root/reference`` (:data:`REFERENCE_FOLDER`) when
    ``root`` is a folder of presses that holds one. The reference is never among the presses returned, nor is
    ``root/reference`` when another ``reference`` is named: a folder's own undeformed capture is not a press.
    """
    presses = find_presses(root)
    default = Path(root) / REFERENCE_FOLDER
    if not is_press_folder(root):
        presses = [p for p in presses if p != default]
    if reference is None:
        reference = default if not is_press_folder(root) and is_press_folder(default) else None
    if reference is None:
        return presses, None
    reference = Path(reference)
    return [p for p in presses if p.resolve() != reference.resolve()], reference
