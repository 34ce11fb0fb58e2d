"""A folder watched for new frames: each image file read once it has landed whole, in the order they land
(``nlips infer MODEL --watch FOLDER``, ``nlips live --watch FOLDER``: a lab's camera software, or another machine over a
shared folder, writes frames there as they come).

File events come from ``watchdog`` (inotify on Linux, FSEvents on macOS, ReadDirectoryChangesW on Windows; its
polling observer on a network or VM-shared file system, whose writes made elsewhere raise no local event). A file is
taken when it is whole:

- renamed into place (a writer that writes a temporary and renames it: the rename lands whole), or
- closed after writing (inotify's close-write: a writer that writes in place), or
- where neither event can come (polling, macOS, Windows, a file moved in from another folder), its size and
  modification time unchanged for :data:`SETTLE_S` -- except, where closes are reported, a file modified and not
  closed since (a writer that paused mid-file).

A file written again after it was read (its size, modification time or inode changed: a camera that rewrites
``latest.png``) is read again; an unchanged one never is. Files that are not images (by suffix), images that cannot
be decoded or have another size than the model's are skipped with a warning (the first few in full, then counted:
``progress.RepeatedWarning``) and the watch goes on; hidden files and usual temporaries (``.tmp``, ``.part``, ``~``)
are a writer's work in progress and pass without a word.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import itertools
import logging
import os
import queue
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import CaptureError, require
from .camera import IMAGE_SUFFIXES, FrameSource, to_stored

if TYPE_CHECKING:  # named in hints only: watchdog is imported when a folder is watched
    from watchdog.events import FileSystemEvent

log = logging.getLogger(__name__)

SETTLE_S = 1.0
"""Seconds a file's size and modification time must stay unchanged before it is read, where no close or rename
says it is whole (polling, macOS, Windows, a file moved in from another folder)."""
TICK_S = 0.05
"""Longest wait for a file event before :meth:`WatchedFolder.read` looks again (files settling, ``stop``, the folder
still there): a frame's latency is the event's, not this."""
POLL_S = 0.25
"""How often the polling observer lists the folder (a network or VM-shared file system, ``--poll``)."""
TEMPORARY_SUFFIXES = (".tmp", ".temp", ".part", ".partial", ".crdownload", ".download", ".swp", "~")
"""Names of a writer's file in progress (besides hidden ones, ``.name``): not warned about, as they are renamed into
place once whole."""
NETWORK_FILE_SYSTEMS = frozenset(
    {
        "nfs",
        "nfs4",
        "cifs",
        "smb3",
        "smbfs",
        "9p",
        "virtiofs",
        "vboxsf",
        "vmhgfs",
        "fuse.vmhgfs-fuse",
        "fuse.sshfs",
        "fuse.rclone",
        "ceph",
        "fuse.ceph",
        "glusterfs",
        "fuse.glusterfs",
        "lustre",
        "gpfs",
        "afs",
        "drvfs",
    }
)
"""Linux file systems whose files another machine (or the VM's host) writes without a local inotify event: watched by
polling (/proc/self/mountinfo's type of the folder's mount)."""
READ_MEMORY = 4096
"""Files whose version read last is kept (:meth:`WatchedFolder._remember`): a rewritten one of them is told from an
unchanged one even by a rescan."""
EXISTING = ("skip", "infer")
"""What :class:`WatchedFolder` does with the images already in the folder when it starts (``--existing``)."""


@dataclasses.dataclass
class _Landing:
    """A file seen in the folder and not read yet (in its present version)."""

    order: int
    """When it landed (or was last made whole by an event), for the arrival order."""
    signature: tuple[int, int, int] | None = None
    """(size, mtime_ns, inode) when last looked at."""
    since: float = 0.0
    """Monotonic time its signature last changed, s."""
    writing: bool = False
    """Modified and not closed since (known only where closes are reported)."""
    whole: bool = False
    """Closed after writing, or renamed into place, since its last modification."""
    whole_size: int | None = None
    """Its size when it was made whole: a later "modified" event of the same size is a change of its times or
    permissions (``cp -p``, ``touch``; watchdog before 5 reported those as modified), not a writer back at it."""


class WatchedFolder(FrameSource):
    """Frames from image files as they land in ``folder``: :meth:`read` waits for the next whole one.

    Parameters
    ----------
    folder : the folder watched (not its subfolders)
    shape : (H, W) the frames must have (the model's): another size is skipped with a warning; None: the first image
        read sets it (a ``--predictor`` stream, which has no model to go by)
    existing : "skip" (default) the images already there at the start, or "infer" them first, in name order
    poll : list the folder every :data:`POLL_S` instead of waiting for the system's file events; None: by itself on
        a network or VM-shared file system (:func:`network_file_system`), events elsewhere
    tone_curve : undone on each frame (:attr:`FrameSource.tone_curve`)
    stop : asked while waiting; True ends the stream (``device.live.StopLive``): SIGTERM's flag
        (``cli._stream.SigtermEndsStream``), since a read may wait for ever
    settle_s : :data:`SETTLE_S` unless given

    Raises CaptureError, one line naming it, when ``folder`` is not a folder.

    Read on the stream's thread, not ahead on another (``device.live.ReadAhead``): a reader thread a file ahead gained
    neither frame rate nor latency (benchmarks/RESULTS.md, s39-livewatch), and a wait for a file that never comes would
    keep it from being joined.
    """

    bit_depth = 16

    def __init__(
        self,
        folder: str | Path,
        shape: tuple[int, int] | None,
        existing: str = "skip",
        poll: bool | None = None,
        tone_curve: np.ndarray | None = None,
        stop: Callable[[], bool] | None = None,
        settle_s: float = SETTLE_S,
    ) -> None:
        from ..progress import RepeatedWarning

        self.folder = Path(folder)
        if not self.folder.exists():
            raise CaptureError(f"{self.folder}: no such folder to watch")
        if not self.folder.is_dir():
            raise CaptureError(f"{self.folder}: not a folder (--watch takes the folder the frames are written into)")
        if existing not in EXISTING:
            raise CaptureError(f"existing must be one of {', '.join(EXISTING)}, got {existing!r}")
        self._shape = None if shape is None else (int(shape[0]), int(shape[1]))
        self._size_of = "the model's frames are"  # whose size the frames must have, for the warning
        self.tone_curve, self.stop, self.settle_s = tone_curve, stop, float(settle_s)
        self.current: Path | None = None
        """The file of the frame :meth:`read` returned last."""
        self.skipped = 0
        """Files skipped: not images, not readable, or of another size."""
        self._events: queue.SimpleQueue = queue.SimpleQueue()
        self._landing: dict[str, _Landing] = {}
        # the versions read (or skipped) last of the latest READ_MEMORY files; older ones are known by their
        # modification time alone (:meth:`_remember`), which only a rescan asks
        self._read: collections.OrderedDict[str, tuple[int, int, int]] = collections.OrderedDict()
        self._forgotten_ns = -1  # the newest modification time of a file read and forgotten, or skipped at the start
        self._named: set[str] = set()  # files not images, warned about once each
        self._order = itertools.count()
        self._warnings = {
            why: RepeatedWarning(log, f"a watched file {why}", first=3)
            for why in ("that is not an image", "that cannot be read", "of another size")
        }
        self.existing = self._start(existing)
        """Images in the folder when the watch started (read first with ``existing="infer"``, else skipped)."""
        self.polling = self._observe(poll)
        """Whether the folder is listed every :data:`POLL_S` (no file events)."""

    @property
    def shape(self) -> tuple[int, int] | None:
        """(H, W) of the frames; None until the first image is read when none was given."""
        return self._shape

    # ------------------------------------------------------------------ setting up
    def _start(self, existing: str) -> int:
        """Note the images already there: skipped (none newer than them is taken for one of them: only a rescan
        would look at them again, :meth:`_rescan`) or landing, in name order. Done before the observer starts, so
        an image written meanwhile is seen as new (by its event)."""
        names = sorted(e.name for e in os.scandir(self.folder) if e.is_file() and _is_image(e.name))
        for name in names:
            path = str(self.folder / name)
            if existing == "skip":
                signature = _signature(path)
                if signature is not None:
                    self._forgotten_ns = max(self._forgotten_ns, signature[1])
            else:
                self._landing[path] = _Landing(next(self._order))
        return len(names)

    def _observe(self, poll: bool | None) -> bool:
        """Start the observer (events, or listing the folder where ``poll`` or its file system asks): whether it
        polls."""
        require("watchdog", "watchdog", "Watching a folder (--watch)")
        from watchdog.observers import Observer
        from watchdog.observers.polling import PollingObserver

        if poll is None:
            kind = network_file_system(self.folder)
            if kind is not None:
                log.info(
                    "%s: on a %s file system, whose writes from elsewhere raise no event: listed every %.2f s",
                    self.folder,
                    kind,
                    POLL_S,
                )
            poll = kind is not None
        handler = _Handler(self._events)
        observer = PollingObserver(timeout=POLL_S) if poll else Observer()
        try:
            observer.schedule(handler, str(self.folder), recursive=False)
            observer.start()
        except OSError as exc:  # inotify's watch or instance limit reached (ENOSPC, EMFILE): listing still works
            if poll:
                raise CaptureError(f"{self.folder}: cannot be watched ({exc.strerror or exc})") from None
            log.warning(
                "%s: no file events (%s); listing the folder every %.2f s instead",
                self.folder,
                exc.strerror or exc,
                POLL_S,
            )
            observer = PollingObserver(timeout=POLL_S)
            observer.schedule(handler, str(self.folder), recursive=False)
            observer.start()
            poll = True
        self._observer = observer
        # only inotify says when a writer closes a file: elsewhere a file modified and left open cannot be told from
        # one written whole, and the settle rule alone decides
        self._closes = not poll and type(observer).__name__ == "InotifyObserver"
        return bool(poll)

    # ------------------------------------------------------------------ reading
    def read(self) -> np.ndarray:
        """The next whole image landed in the folder: (H, W, 3) uint16, RGB, stored values; waits for one.

        Raises ``device.live.StopLive`` when ``stop()`` says so, CaptureError when the folder was removed."""
        from .live import StopLive

        while True:
            if self.stop is not None and self.stop():
                raise StopLive
            self._take_events()
            for path in self._whole():
                frame = self._load(path)
                if frame is not None:
                    self.current = Path(path)
                    return frame
            if not self.folder.is_dir():
                raise CaptureError(f"{self.folder}: the watched folder was removed")
            with contextlib.suppress(queue.Empty):
                self._note(self._events.get(timeout=TICK_S))

    def _take_events(self) -> None:
        while True:
            try:
                self._note(self._events.get_nowait())
            except queue.Empty:
                return

    def _note(self, event: FileSystemEvent) -> None:
        """One file event into the landing files' state."""
        kind = event.event_type
        if kind == "overflow" or kind == "events_lost":  # inotify's queue overflowed: look at every file again
            self._rescan()
            return
        if event.is_directory or kind not in ("created", "modified", "closed", "moved", "deleted"):
            return  # opened, closed without writing (our own reads among them), attributes: the bytes are as they were
        path = os.fsdecode(event.src_path)
        if kind in ("deleted", "moved"):
            self._landing.pop(path, None)
            self._read.pop(path, None)
            if kind == "moved":
                dest = os.fsdecode(event.dest_path)
                if dest and os.path.dirname(dest) == str(self.folder) and (landing := self._land(dest)) is not None:
                    self._made_whole(landing, dest)  # renamed into place: whole as it lands
            return
        landing = self._land(path)
        if landing is None:
            return
        if kind == "closed":  # close-write (inotify)
            self._made_whole(landing, path)
        elif kind == "modified":
            signature = _signature(path)
            if not (landing.whole and signature is not None and signature[0] == landing.whole_size):
                landing.whole, landing.writing = False, True

    def _made_whole(self, landing: _Landing, path: str) -> None:
        """``path`` closed after writing or renamed into place: whole now, landed now."""
        signature = _signature(path)
        landing.whole, landing.writing = True, False
        landing.whole_size = None if signature is None else signature[0]
        landing.order = next(self._order)

    def _land(self, path: str) -> _Landing | None:
        """The landing state of ``path`` (made when new), or None for a file not taken (warned about once when it is
        not an image and not a writer's temporary)."""
        name = os.path.basename(path)
        if not _is_image(name):
            if not _in_progress(name) and name not in self._named:
                self._named.add(name)
                self.skipped += 1
                self._warnings["that is not an image"](
                    f"{path}: not an image ({', '.join(IMAGE_SUFFIXES)}); skipped, the watch goes on", name
                )
            return None
        landing = self._landing.get(path)
        if landing is None:
            landing = self._landing[path] = _Landing(next(self._order))
        return landing

    def _rescan(self) -> None:
        """Events were lost (inotify's queue overflowed): every image not read yet lands again; one modified no
        later than the newest file forgotten (:meth:`_remember`) or skipped at the start is taken for read."""
        log.warning("%s: file events were lost (too many at once); looking at every file again", self.folder)
        for entry in os.scandir(self.folder):
            if not (entry.is_file() and _is_image(entry.name)) or entry.path in self._landing:
                continue
            signature = _signature(entry.path)
            if signature is not None and entry.path not in self._read and signature[1] <= self._forgotten_ns:
                continue
            self._land(entry.path)

    def _remember(self, path: str, signature: tuple[int, int, int]) -> None:
        """The version of ``path`` just read (or skipped), so that it is not read again; of the latest
        :data:`READ_MEMORY` files only, the others known by the newest modification time among them.

        Why bounded: a watch of hours keeps no entry per frame (30 frames/s for 8 hours: 864,000 files, ~170 MB)."""
        self._read[path] = signature
        self._read.move_to_end(path)
        while len(self._read) > READ_MEMORY:
            _, old = self._read.popitem(last=False)
            self._forgotten_ns = max(self._forgotten_ns, old[1])

    def _whole(self) -> list[str]:
        """The landing files whole now, in the order they landed (name order among equals); those gone, or read in
        this version already, are forgotten."""
        now, whole = time.monotonic(), []
        for path, landing in list(self._landing.items()):
            signature = _signature(path)
            if signature is None or signature == self._read.get(path):
                del self._landing[path]  # removed, or an event of the version read (its close, a touch)
                continue
            if signature != landing.signature:
                landing.signature, landing.since = signature, now
            if signature[0] == 0:  # made, nothing written yet
                continue
            settled = now - landing.since >= self.settle_s and not (self._closes and landing.writing)
            if landing.whole or settled:
                whole.append((landing.order, path))
        return [path for _, path in sorted(whole)]

    def _load(self, path: str) -> np.ndarray | None:
        """The frame of ``path``, or None when it is skipped (a warning); its version counts as read either way."""
        from ..core.imageio import read_image

        landing = self._landing.pop(path)
        self._remember(path, landing.signature)
        try:
            image = read_image(path)
            if image is None:
                raise CaptureError(f"{path}: not a readable image")
            frame, _ = to_stored(image, path, self.tone_curve)
        except (CaptureError, OSError) as exc:
            self.skipped += 1
            self._warnings["that cannot be read"](f"{exc}; skipped, the watch goes on", path)
            return None
        if self._shape is None:  # no model to go by: the first image read sets the stream's size
            self._shape, self._size_of = frame.shape[:2], f"the stream's first frame ({os.path.basename(path)}) is"
        if frame.shape[:2] != self._shape:
            (h, w), (mh, mw) = frame.shape[:2], self._shape
            self.skipped += 1
            self._warnings["of another size"](
                f"{path}: image is {w}x{h}, {self._size_of} {mw}x{mh}; skipped, the watch goes on", path
            )
            return None
        return frame

    def close(self) -> None:
        observer = getattr(self, "_observer", None)
        if observer is not None:
            observer.stop()
            observer.join(timeout=5)
        for warning in self._warnings.values():
            warning.flush()


class _Handler:
    """watchdog's event handler: every event into ``events`` (a queue read by the stream's thread alone)."""

    def __init__(self, events: queue.SimpleQueue) -> None:
        self.events = events

    def dispatch(self, event: FileSystemEvent) -> None:
        self.events.put(event)


def _signature(path: str) -> tuple[int, int, int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_size, st.st_mtime_ns, st.st_ino)


def _is_image(name: str) -> bool:
    return not name.startswith(".") and os.path.splitext(name)[1].lower() in IMAGE_SUFFIXES


def _in_progress(name: str) -> bool:
    """A writer's file in progress by its name: hidden, or a usual temporary suffix."""
    return name.startswith(".") or name.lower().endswith(TEMPORARY_SUFFIXES)


def network_file_system(folder: str | Path, mountinfo: str | None = None) -> str | None:
    """The type of the file system ``folder`` is on when it is one of :data:`NETWORK_FILE_SYSTEMS`, else None.

    ``mountinfo``: the text of Linux's /proc/self/mountinfo (read when None; None is returned where there is none:
    other systems, where the observer's own events are used)."""
    if mountinfo is None:
        if not sys.platform.startswith("linux"):
            return None
        try:
            mountinfo = Path("/proc/self/mountinfo").read_text(encoding="utf-8", errors="replace")
        except OSError:
            return None
    where = os.path.realpath(folder)
    best, kind = "", None
    for line in mountinfo.splitlines():  # "36 35 98:0 /mnt1 /mnt/point rw,noatime master:1 - nfs4 server:/x rw"
        mine, _, theirs = line.partition(" - ")
        fields = mine.split()
        if len(fields) < 5 or not theirs.split():
            continue
        mount = fields[4].replace("\\040", " ")  # the kernel's escape of a space in a mount point
        inside = where == mount or where.startswith(mount.rstrip("/") + "/")
        if inside and len(mount) >= len(best):
            best, kind = mount, theirs.split()[0]
    return kind if kind in NETWORK_FILE_SYSTEMS else None
