"""Atomic writes: a reader (or a resumed run) never sees a half-written file or folder.

Everything is first written under a temporary name in the same directory, then moved into place with
a rename, which is atomic on POSIX file systems. Temporary names carry their owner
(``.tmp-<name>~<host>~<pid>~<random>``) so that a clean-up run by another process removes only
leftovers whose owner is gone, never a live process's work in progress.
"""

from __future__ import annotations

import contextlib
import errno
import glob
import json
import os
import re
import secrets
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO

from .claims import CLAIM_PREFIX, HOST, holder, pid_alive

TMP_PREFIX = ".tmp-"
"""Prefix of in-progress files and folders; anything starting with it is a write in progress or interrupted."""
OWNER_SEP = "~"
"""Separates the item name, host and pid in a temporary name (hostnames never contain it)."""
SWAP_ATTEMPTS = 20
"""Tries to put an overwriting folder in place while other processes keep publishing theirs."""
STALE_S = 600.0
"""Age (s) after which a temporary entry from another machine, with no live claim, counts as abandoned."""
SCRATCH_MARK = "scratch-"
"""Start of the random part of a :func:`scratch_dir` folder's name: its files are moved *beside* the entry it is
named for, not into a folder of that name, and :func:`named_target` names them there."""
HELD_OPEN_WAITS_S = (0.02, 0.05, 0.1, 0.2, 0.3, 0.35)
"""Waits (s) between tries of a rename that Windows refused because another program holds the file (or a file in the
folder) open: an antivirus scan or a search indexer lets go within a second; a viewer or Excel does not, and the
write then fails naming the file (:data:`HELD_OPEN`). About 1 s in all."""
HELD_OPEN = (
    "could not be replaced: another program holds it open (a viewer, Excel, an antivirus scan?); close it and run again"
)
"""The cause of a write that found its file held open on Windows after :data:`HELD_OPEN_WAITS_S`."""
NO_SPACE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})
"""Errors of a write that found no room: the disk is full, or the user's quota is spent."""


_IN_PROGRESS: set[Path] = set()
"""Temporary folders and files this process is filling now."""


def _umask() -> int:
    mask = os.umask(0)  # the only portable way to read it is to set it
    os.umask(mask)
    return mask


_UMASK = _umask()
# mkstemp/mkdtemp create private (0600/0700) entries; results are shared data, so give them the
# permissions an ordinary open()/mkdir() would have.
FILE_MODE = 0o666 & ~_UMASK
DIR_MODE = 0o777 & ~_UMASK


def tmp_prefix(name: str) -> str:
    """Prefix of this process's temporary entries for item ``name``."""
    return f"{TMP_PREFIX}{name}{OWNER_SEP}{HOST}{OWNER_SEP}{os.getpid()}{OWNER_SEP}"


def _temporary_name(final: Path, mark: str = "") -> Path:
    """A name for this process's new temporary entry of ``final`` (``.tmp-NAME~host~pid~RANDOM`` beside it); no
    entry is made.

    Why not ``tempfile.mkstemp``/``mkdtemp``: they make the entry and only then return its name, so a Ctrl-C
    landing between (its KeyboardInterrupt raised as the mkdir returns) left a temporary no one knew to remove:
    3 of 16 Ctrl-C of `nlips infer FRAMES --out DIR` left a ``.tmp-FRAME~...`` in DIR. Callers register the
    name in :data:`_IN_PROGRESS` and make the entry inside the ``try`` that removes it, so every moment it exists
    it is known. 48 random bits under this process's own prefix: no other entry has the name."""
    return final.parent / (tmp_prefix(final.name) + mark + secrets.token_hex(6))


def named_target(path: str | Path) -> Path:
    """The entry a user asked for, given one of the hidden entries written beside it (a temporary
    ``.tmp-NAME~host~pid~...`` or a claim ``.claim-NAME[.token]``): for error messages, which should name
    what the user knows; a file inside a temporary folder (``.tmp-press~host~pid~.../led_03.png``, a write that
    failed on a full disk) is named inside the folder it becomes (``press/led_03.png``); one inside a
    :func:`scratch_dir` (``.tmp-net.pt~host~pid~scratch-.../net.pt``, a training's files) beside the entry it is named
    for (``net.pt``), where it goes. Any other path is returned as it is."""
    p = Path(path)
    folders = [_item_of(part) or part for part in p.parent.parts if not _is_scratch(part)]
    p = Path(*folders, p.name) if folders else p
    if p.name.startswith(TMP_PREFIX):
        item = _item_of(p.name)
        return p.with_name(item) if item else p.parent  # no item: check_writable's probe of the folder itself
    if p.name.startswith(CLAIM_PREFIX):
        item = re.sub(r"\.(stale\.)?[0-9a-f]{8,16}$", "", p.name[len(CLAIM_PREFIX) :])
        return p.parent if item.startswith("probe.") else p.with_name(item)
    return p


def _item_of(name: str) -> str | None:
    """The item a temporary entry's name ``.tmp-NAME~host~pid~...`` is written for (NAME; "" for a folder's probe),
    or None for any other name."""
    return name[len(TMP_PREFIX) :].split(OWNER_SEP, 1)[0] if name.startswith(TMP_PREFIX) else None


def _is_scratch(name: str) -> bool:
    """Whether ``name`` is a :func:`scratch_dir` folder's (``.tmp-NAME~host~pid~scratch-RANDOM``)."""
    return name.startswith(TMP_PREFIX) and name.rsplit(OWNER_SEP, 1)[-1].startswith(SCRATCH_MARK)


def check_writable(folder: str | Path, longest_name: int = 0) -> None:
    """Fail fast (OSError naming the path) when ``folder`` cannot receive output, before long work.

    Creates and removes a probe folder named like the longest temporary folder an item of
    ``longest_name`` characters will need, so a read-only disk, a permission problem or a name too
    long shows up now, not after minutes of work. (A full disk may still show up later: work must
    stop at the first failed write.)
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    probe = folder / (tmp_prefix("x" * longest_name) + "probe")
    _IN_PROGRESS.add(probe)  # a signal handler exiting meanwhile removes it (remove_in_progress): no finally runs then
    try:
        probe.mkdir()
        probe.rmdir()
    finally:
        _IN_PROGRESS.discard(probe)


def check_can_make(folder: str | Path, longest_name: int = 0) -> None:
    """Fail fast (OSError naming ``folder``) when ``folder`` could not receive output, making nothing: as
    :func:`check_writable`, its probe made in ``folder`` or, where it does not exist yet, in the nearest folder above
    it (a run refused on another input later leaves no folder made for the check). A file in its way is ENOTDIR.

    Why: a run that writes its output as it goes (``nlips infer``'s results, a stream's frames) found a read-only
    disk only at its first result, after loading its model and inferring a frame."""
    folder = Path(folder)
    existing = next((p for p in (folder, *folder.parents) if p.exists()), folder)
    if not existing.is_dir():
        raise OSError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(folder))
    try:
        check_writable(existing, longest_name)
    except OSError as exc:  # name the folder asked for, not the probe (nor the folder above it)
        raise OSError(exc.errno, exc.strerror, str(folder)) from None


def check_free_space(folder: str | Path, need: int, what: str) -> int:
    """Fail fast (OSError ENOSPC naming ``folder``) when its disk has less than ``need`` bytes free, before long work.

    Parameters
    ----------
    folder : an existing folder on the disk to be written
    need : bytes the smallest useful output takes (one press, one LED file), int
    what : that output, for the message ("a press", "the LED file")

    Returns
    -------
    the free bytes, int (for a caller that says how many outputs fit)
    """
    free = shutil.disk_usage(folder).free
    if free < need:
        cause = f"No space left on device ({free >> 10} KiB free, {what} needs ~{need >> 10} KiB)"
        raise OSError(errno.ENOSPC, cause, str(folder))
    return free


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temp file in the same folder, then rename)."""
    return write_with(path, lambda f: f.write(data))


def write_with(path: str | Path, writer: Callable[[BinaryIO], object]) -> Path:
    """Atomically write what ``writer(f)`` writes to the binary file ``f`` (e.g. ``pickle.dump(value, f)``:
    no copy of a large result in memory first) to ``path`` (temp file in the same folder, then rename)."""

    def write_file(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            writer(f)

    return write_by_name(path, write_file)


def write_by_name(path: str | Path, write: Callable[[Path], object]) -> Path:
    """Atomically write the file that ``write(tmp)`` creates at the path ``tmp`` it is given (for writers
    that open the file themselves, e.g. ``imageio.save_npz``); then rename it to ``path``.

    The temporary name carries this process (``.tmp-NAME~host~pid~random``), so concurrent writers of one
    file never write into the same temporary, and a killed writer's leftover is recognised and removed by
    :func:`clean_interrupted`.
    """
    path = Path(path)
    _make_folder(path.parent)
    tmp = _temporary_name(path)
    _IN_PROGRESS.add(tmp)
    try:
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))  # made inside the try: see _temporary_name
        write(tmp)
        os.chmod(tmp, FILE_MODE)
        replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        _raise_with_path(exc, path)
        raise
    finally:
        _IN_PROGRESS.discard(tmp)
    return path


def replace(source: str | Path, target: str | Path) -> None:
    """``os.replace(source, target)``, tried again for about a second (:data:`HELD_OPEN_WAITS_S`) where Windows
    refuses it because another program holds ``target`` open, then PermissionError naming ``target``
    (:data:`HELD_OPEN`, errno EBUSY).

    Why: POSIX replaces a file that others have open (they keep reading the old one); Windows refuses with
    PermissionError while any program has it open without sharing its deletion, as a figure viewer, Excel with a
    CSV, or an antivirus scan of the new file does. A scan ends within a second; the others need the user. On
    other systems a PermissionError is a real permission problem and is raised at once.
    """
    _held_open_retried(lambda: os.replace(source, target), target)


def _held_open_retried(rename: Callable[[], object], target: str | Path) -> None:
    """Run ``rename()``; on Windows, a PermissionError is taken for ``target`` held open by another program, tried
    again after each of :data:`HELD_OPEN_WAITS_S`, then raised as :data:`HELD_OPEN`."""
    for wait in (*HELD_OPEN_WAITS_S, None):
        try:
            rename()
            return
        except PermissionError:
            if sys.platform != "win32":
                raise
            if wait is None:
                raise PermissionError(errno.EBUSY, HELD_OPEN, str(target)) from None
            time.sleep(wait)


def write_text(path: str | Path, text: str) -> Path:
    return write_bytes(path, text.encode("utf-8"))


def write_json(path: str | Path, obj: object) -> Path:
    return write_text(path, json.dumps(obj, indent=2, sort_keys=False) + "\n")


def write_new(path: str | Path, data: bytes) -> bool:
    """Write ``data`` to ``path`` whole and only if there is no file of that name: False (nothing written) when there
    is one, even one another process made meanwhile.

    Written under a temporary name, then hard-linked to ``path`` (``link`` fails where the name exists: atomic
    between processes, also on NFS); on a file system without hard links, created with ``O_EXCL`` and written (a
    reader may then see it partly written for a moment). Why not :func:`write_bytes`: its rename replaces a file
    written meanwhile, e.g. a record of a press folder that another process wrote anew (core.press_checksums)."""
    path = Path(path)
    tmp = _temporary_name(path)
    _IN_PROGRESS.add(tmp)
    try:
        with open(tmp, "xb") as f:
            f.write(data)
        os.chmod(tmp, FILE_MODE)
        try:
            os.link(tmp, path)
        except FileExistsError:
            return False
        except OSError as exc:
            if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK):
                raise
            try:
                fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, FILE_MODE)
            except FileExistsError:
                return False
            with os.fdopen(fd, "wb") as f:
                f.write(data)
        return True
    except BaseException as exc:
        _raise_with_path(exc, path)
        raise
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        _IN_PROGRESS.discard(tmp)


def write_if_changed(path: str | Path, text: str) -> bool:
    """Write ``text`` to ``path`` atomically unless the file already holds exactly it; True if written.

    Lets a finished result on read-only media be re-checked without a write.
    """
    path = Path(path)
    with contextlib.suppress(OSError):
        if path.read_text(encoding="utf-8") == text:
            return False
    write_text(path, text)
    return True


@contextlib.contextmanager
def atomic_dir(final: str | Path, overwrite: bool = False) -> Iterator[Path]:
    """Build a folder under a temporary name and move it to ``final`` only if the block succeeds.

    Yields the temporary folder's path. On error the temporary folder is removed, so an interrupted
    run leaves either the complete folder or nothing. Without ``overwrite``, the final rename never
    replaces an existing complete folder, even one another process published meanwhile
    (:class:`FileExistsError` then, and this process's folder is dropped). A ``final`` that is a symbolic link is
    written where it points, and the link stays (:func:`_link_target`).
    """
    final = _link_target(Path(final))
    if final.exists() and not overwrite:
        raise FileExistsError(errno.EEXIST, "already exists", str(final))
    final.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(OSError):  # leftovers of a killed earlier write of this folder (e.g. PRESS/nlips)
        clean_interrupted(final.parent, item=final.name)
    tmp, held = _temporary_name(final), None
    _IN_PROGRESS.add(tmp)
    try:
        os.mkdir(tmp, 0o700)  # made inside the try: an interrupt right after it still removes it (_temporary_name)
        try:
            held = os.open(tmp, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))  # keeps its inode number its own
            made = None
        except PermissionError:  # Windows opens no folder this way: its file id is kept instead (NTFS reuses none soon)
            made = os.stat(tmp)
        yield tmp
        # never publish a folder that lost what was written into it
        _check_same_folder(tmp, os.fstat(held) if held is not None else made)
        os.chmod(tmp, DIR_MODE)
        if overwrite:
            _swap_in(tmp, final)
        else:
            _rename_no_replace(tmp, final)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        _raise_with_path(exc, final)
        raise
    finally:
        _IN_PROGRESS.discard(tmp)
        if held is not None:
            os.close(held)


def _link_target(final: Path) -> Path:
    """Where a folder given as a symbolic link lives (its target, even one not made yet); any other path as given.

    Why: a folder is published by renaming a new one onto its name, and a rename onto a link replaces the link:
    ``--report reports/latest`` (a link to ``reports/run-7``) turned the link into a real folder and left the run's
    folder as it was. A link that cannot be followed (a loop) is left to fail where it is used.
    """
    if not final.is_symlink():
        return final
    try:
        return final.resolve()
    except (OSError, RuntimeError):  # RuntimeError: a loop of links (Python 3.11)
        return final


@contextlib.contextmanager
def whole_dir(final: str | Path, marker: str) -> Iterator[Path]:
    """Build a folder of one run's files (a report: a page, its data, its figures) under a temporary name and put
    it in place of ``final`` whole when the block succeeds (:func:`atomic_dir` with ``overwrite``).

    Why: a report written file by file into ``final`` kept the files of an earlier run that this one does not
    write (a figure of a config with more figure presses, or whose training then worked) beside the new page, and
    a run killed half way left some new files beside the old page: a copied folder was a mix of runs. Now the
    folder is always one run's complete output: the earlier one until the swap, this one after it (the last to
    finish when two runs swap theirs at once). ``final`` is refused (:func:`check_replaceable`) when it holds
    files of something else, which the swap would remove.

    ``marker``: the file every such folder holds (``results.json``), by which an existing one is recognised.
    """
    final = _link_target(Path(final))
    check_replaceable(final, marker)
    with atomic_dir(final, overwrite=True) as tmp:
        yield tmp


def check_replaceable(final: str | Path, marker: str) -> None:
    """ConfigError unless ``final`` is absent, an empty folder, or a folder holding ``marker`` (one that
    :func:`whole_dir` may replace): a folder of other files (a user's ``--report .``) would be removed whole."""
    from .errors import ConfigError

    final = Path(final)
    if final.is_file():
        raise ConfigError(f"{final}: a file, not a folder")
    if final.is_dir() and not (final / marker).is_file() and any(final.iterdir()):
        raise ConfigError(
            f"{final}: holds files but no {marker}, so it is not a folder this command writes, and writing it "
            "replaces the whole folder; give a new or empty folder"
        )


@contextlib.contextmanager
def scratch_dir(final: str | Path) -> Iterator[Path]:
    """A temporary folder beside ``final`` to assemble several files in, removed when the block ends.

    Named as this process's temporary of ``final`` (``.tmp-NAME~host~pid~...``): a killed run's is removed by
    the next write of ``final`` or :func:`clean_interrupted` once its owner is gone, never a live run's; and a
    SIGTERM'd command removes its own (:func:`remove_in_progress`). Moving files out of it is the caller's.
    """
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temporary_name(final, SCRATCH_MARK)
    _IN_PROGRESS.add(tmp)
    try:
        os.mkdir(tmp, 0o700)  # made inside the try (_temporary_name)
        os.chmod(tmp, DIR_MODE)
        yield tmp
    finally:
        _IN_PROGRESS.discard(tmp)
        shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def system_scratch_dir(name: str) -> Iterator[Path]:
    """:func:`scratch_dir` of ``name`` in the system's temporary folder (``tempfile.gettempdir()``), after removing
    the ones that processes of this machine, gone since, left there.

    Why: nothing writes ``name`` itself there, so no later write removed a killed process's scratch folder: each
    ``kill -9`` (a power cut, the OOM killer) of a render left its Mitsuba log folder, and of a command with
    worker processes its said-once folder (a ``tempfile.TemporaryDirectory`` then), in /tmp for good: 13 and 37 of
    them after a day of this machine's tests and walks."""
    import tempfile

    folder = Path(tempfile.gettempdir())
    with contextlib.suppress(OSError):  # another user's, or one removed meanwhile: left as it is
        # this machine's only (its processes can be checked): another's sharing the folder may idle for hours
        clean_interrupted(folder, stale_s=float("inf"), item=name)
    with scratch_dir(folder / name) as tmp:
        yield tmp


def remove_in_progress() -> None:
    """Remove this process's unfinished temporary folders and files (for a signal handler about to exit).

    A folder is renamed first (its name gains ``.removing``, still this process's temporary name): threads of
    this process may still be writing into it (``write_press``'s image writers), and a file they create while
    ``rmtree`` empties it would keep the folder; under its new name their writes fail and whatever is left
    is a dead process's temporary, which the next write or ``clean_interrupted`` removes."""
    for tmp in list(_IN_PROGRESS):
        if tmp.is_dir():
            doomed = tmp.with_name(tmp.name + ".removing")
            try:
                os.rename(tmp, doomed)
            except OSError:
                doomed = tmp
            shutil.rmtree(doomed, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                tmp.unlink()
    _IN_PROGRESS.clear()


def clean_interrupted(folder: str | Path, stale_s: float = STALE_S, item: str | None = None) -> list[Path]:
    """Remove leftovers of interrupted writes directly inside ``folder``; returns what went.

    ``item``: only those of that entry's name (e.g. after taking over its claim).

    A temporary entry is removed only when its owner is gone: a dead process on this machine, or
    (other machines, whose processes cannot be checked) no live claim on its item and no change for
    ``stale_s`` seconds. Stale claim files go too.
    """
    folder = Path(folder)
    gone = []
    if not folder.is_dir():
        return gone
    now = time.time()
    patterns = ["*"] if item is None else [glob.escape(item) + OWNER_SEP + "*", glob.escape(item) + "-*"]
    for p in {p for pattern in patterns for p in folder.glob(TMP_PREFIX + pattern)}:  # "-": older naming
        if _abandoned(p, now, stale_s):
            shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
            gone.append(p)
    for p in folder.glob(CLAIM_PREFIX + ("*" if item is None else glob.escape(item))):
        target = p.with_name(p.name[len(CLAIM_PREFIX) :])
        if p.suffix == "" and holder(target) is None:
            _remove_stale_claim(p)
            gone.append(p)
    siblings = [CLAIM_PREFIX + ("*" if item is None else glob.escape(item)) + ".*", CLAIM_PREFIX + "probe.*"]
    for p in {p for pattern in siblings for p in folder.glob(pattern)}:
        if _abandoned_claim_sibling(p, now, stale_s):
            p.unlink(missing_ok=True)
            gone.append(p)
    return gone


def removed_leftover(path: str | Path) -> str:
    """What :func:`clean_interrupted` removed at ``path``, for its log line: "an interrupted write" (a temporary) or
    "the claim of a run that ended without releasing it (killed)". The claims of a killed ``nlips calibrate`` were
    logged as "removed an interrupted write", a write that never was."""
    if Path(path).name.startswith(CLAIM_PREFIX):
        return "the claim of a run that ended without releasing it (killed)"
    return "an interrupted write"


# ---------------------------------------------------------------------- internals
VANISHED = "its temporary folder was removed while being written (by another process?); nothing was published"


def _vanished(tmp: Path) -> FileNotFoundError:
    return FileNotFoundError(errno.ENOENT, VANISHED, str(tmp))


def _make_folder(folder: Path) -> None:
    """``folder.mkdir(parents=True, exist_ok=True)``, except that a temporary folder this process is filling
    (:func:`atomic_dir`) is never made again: a file written into one that vanished (removed by a clean-up, a
    user) fails (FileNotFoundError naming it), where re-creating it quietly led to a folder published without
    the files written before."""
    for tmp in list(_IN_PROGRESS):
        if folder == tmp or tmp in folder.parents:
            below = [folder, *folder.parents][: len(folder.parts) - len(tmp.parts)]
            try:
                for level in reversed(below):  # one level at a time: none of them re-creates ``tmp``
                    level.mkdir(exist_ok=True)
            except FileNotFoundError:
                raise _vanished(tmp) from None
            if not tmp.is_dir():
                raise _vanished(tmp)
            return
    folder.mkdir(parents=True, exist_ok=True)


def _check_same_folder(tmp: Path, made: os.stat_result) -> None:
    """FileNotFoundError when ``tmp`` is no longer the folder ``made`` (held open, so that a folder made again
    under its name cannot get its inode number): removed, or removed and made again, by another process, and
    what was written into it gone with it."""
    try:
        now = os.stat(tmp)
    except FileNotFoundError:
        raise _vanished(tmp) from None
    if (now.st_dev, now.st_ino) != (made.st_dev, made.st_ino):
        raise _vanished(tmp)


def _raise_with_path(exc: BaseException, path: Path) -> None:
    """Some writers (file.write, numpy, image libraries) raise OSError without the path: add it."""
    if isinstance(exc, OSError) and exc.filename is None and exc.errno is not None:
        raise type(exc)(exc.errno, exc.strerror or str(exc), str(path)) from exc


def _rename_no_replace(tmp: Path, final: Path) -> None:
    """Rename a folder into place; fails (FileExistsError) if ``final`` is a non-empty folder.

    rename(2) of a directory replaces only an empty one, so this is atomic with respect to other
    processes publishing the same folder.
    """
    try:
        os.rename(tmp, final)
    except OSError as exc:
        if exc.errno in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
            raise FileExistsError(errno.EEXIST, "already exists (written by another process)", str(final)) from None
        raise


def _swap_in(tmp: Path, final: Path) -> None:
    """Put the folder ``tmp`` in place of ``final``, whatever is there (``atomic_dir(overwrite=True)``).

    rename(2) replaces only an empty folder, so a complete ``final`` is first moved aside (under this
    process's temporary name, removed afterwards). Other processes may publish ``final`` at the same
    time (two ``nlips infer`` runs on one press): the first rename failed when another process had just
    moved the folder aside, the second when another had published its own between our two renames,
    and the folder moved aside was then left behind. Now a folder already moved aside is no error, one
    published in between is moved aside in turn, and the swap tried again: the last writer wins, and
    every moment shows a complete folder or, briefly, none.
    """
    for _ in range(SWAP_ATTEMPTS):
        old = final.with_name(tmp_prefix(final.name) + "old-" + secrets.token_hex(4))
        try:  # Windows: refused while a program holds a file inside open (a viewer showing a report's figure)
            _held_open_retried(lambda old=old: os.rename(final, old), final)
        except FileNotFoundError:
            old = None
        try:
            os.rename(tmp, final)
            return
        except OSError as exc:
            if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                raise
        finally:
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
    raise FileExistsError(errno.EEXIST, "replaced by other processes again and again", str(final))


def _abandoned(p: Path, now: float, stale_s: float) -> bool:
    parts = p.name[len(TMP_PREFIX) :].rsplit(OWNER_SEP, 3)
    if len(parts) == 4 and parts[2].isdigit():
        item, host, pid = parts[0], parts[1], int(parts[2])
        if host == HOST:
            return not pid_alive(pid)
        if holder(p.with_name(item)) is not None:
            return False
    try:
        return now - p.stat().st_mtime > stale_s
    except FileNotFoundError:
        return False


def _abandoned_claim_sibling(p: Path, now: float, stale_s: float) -> bool:
    """Whether a short-lived file of core.claims was left by a process killed while it existed: the owner's
    JSON written before linking it as the claim (``.claim-NAME.TOKEN``), a claim moved aside while being
    taken over (``.claim-NAME.stale.HEX``), or a clock probe (``.claim-probe.HOST.PID.HEX``). Each lives
    for microseconds, so one that its owner did not remove is abandoned once the owner is gone (or, from
    another machine, after ``stale_s`` without change)."""
    from .claims import _read_owner

    host, pid = None, None
    if p.name.startswith(CLAIM_PREFIX + "probe."):
        parts = p.name[len(CLAIM_PREFIX + "probe.") :].rsplit(".", 2)
        if len(parts) == 3 and parts[1].isdigit():
            host, pid = parts[0], int(parts[1])
    else:
        owner = _read_owner(p)
        if owner is not None:
            host, pid = owner.host, owner.pid
    if host == HOST and pid is not None:
        return not pid_alive(pid)
    try:
        return now - p.stat().st_mtime > stale_s
    except FileNotFoundError:
        return False


def _remove_stale_claim(path: Path) -> None:
    from .claims import _read_owner, _remove_if_same

    _remove_if_same(path, _read_owner(path))
