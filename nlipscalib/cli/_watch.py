"""The watched folder of ``nlips live --watch FOLDER`` and ``nlips infer MODEL --watch FOLDER`` (one source for both,
``device.watch_folder.WatchedFolder``, opened by ``cli._stream.open_frames``): its flags and their one-line errors, the
line a watch starts with, the line counting the files it skipped, each frame named by its file in the warnings, and
``OUT/frames.tsv``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from .options import option, typed

if TYPE_CHECKING:  # named in hints only: the watch is imported when a folder is watched
    import numpy as np

    from ..device.watch_folder import WatchedFolder

WATCHED_FILES = "frames.tsv"
"""What a watched folder's stream with ``--out`` writes beside its frames: each saved frame's file
(:class:`WatchedFilesSink`)."""
WATCH_SOURCES = ("camera", "emulate")
"""The other sources' flags, each refused beside ``--watch`` (``nlips infer`` refuses them first in its own words)."""


def add_watch_arguments(p: argparse.ArgumentParser) -> None:
    """``--watch FOLDER``, ``--existing`` and ``--poll``, the same for ``nlips live`` and ``nlips infer``."""
    p.add_argument(
        "--watch",
        metavar="FOLDER",
        help="stream the frames written into FOLDER as they land (a camera's software, or another machine over a "
        "shared folder): each image is read once whole (renamed into place, closed after writing, or unchanged for "
        "1 s), in the order they land, until Ctrl-C or --max-frames; other files, unreadable images and images of "
        "another size are skipped with a warning. Warnings name each frame's file; with --out, frames.tsv names each "
        "saved frame's file",
    )
    p.add_argument(
        "--existing",
        choices=("skip", "infer"),
        help="--watch: the images already in FOLDER when the watch starts are skipped (default) or streamed first, "
        "in name order",
    )
    p.add_argument(
        "--poll",
        action="store_true",
        help="--watch: list FOLDER every 0.25 s instead of waiting for the system's file events (chosen by itself "
        "on NFS, SMB and VM-shared folders, whose writes from another machine raise no event here)",
    )


def check_watch_arguments(args: argparse.Namespace) -> None:
    """One line naming the option for ``--existing`` or ``--poll`` without ``--watch``, ``--watch`` beside another
    source (``--camera``, ``--emulate``), and ``--watch``'s folder missing or not a folder: before the model loads."""
    from ..core.errors import CaptureError, ConfigError

    for dest in typed(args, ("existing",)) + (["poll"] if args.poll else []):
        if not args.watch:
            raise ConfigError(f"{option(dest)} is for --watch FOLDER (a folder watched for frames); drop it")
    if not args.watch:
        return
    for dest in WATCH_SOURCES:
        if getattr(args, dest, None) is not None:
            raise ConfigError(
                f"--watch {args.watch} and {option(dest)} {getattr(args, dest)} are two sources of frames: give one"
            )
    folder = Path(args.watch)
    if not folder.exists():
        raise CaptureError(
            f"--watch {args.watch}: no such folder (make it, or name the one the frames are written into)"
        )
    if not folder.is_dir():
        raise CaptureError(f"--watch {args.watch}: not a folder (--watch takes the folder the frames are written into)")


def open_watched_folder(
    args: argparse.Namespace,
    shape: tuple[int, int] | None,
    tone_curve: np.ndarray | None,
    stop: Callable[[], bool] | None,
) -> WatchedFolder:
    """The folder of ``--watch`` (``--existing``, ``--poll``), for ``cli._stream.open_frames``; ``shape``: the model's
    (H, W), None for a ``--predictor`` (the first image sets it)."""
    from ..device.watch_folder import WatchedFolder

    poll = True if args.poll else None  # None: polled by itself on a network file system
    return WatchedFolder(args.watch, shape, args.existing or "skip", poll, tone_curve=tone_curve, stop=stop)


def frame_files(source: object) -> Callable[[int], str]:
    """Names the frame a stream of ``source`` (a watched folder, as ``open_frames`` returned it: the LED board's
    watch forwards ``current``) read last by its file, ``FOLDER/NAME.png``, for the warnings
    (``learn.watch.MismatchWatch.frame_name``): the file a user can open, where "FOLDER frame 12" said nothing of which
    one (frames.tsv keeps the mapping). The index is not used: the frame being inferred is the one read last (the
    folder is not read ahead)."""
    return lambda index: str(source.current)


def say_watching(source: WatchedFolder, existing: str | None) -> None:
    """The line a watch starts with: what it waits for, what it did with the images already there, how it ends."""
    from ..progress import say

    there = source.existing
    if not there:
        before = ""
    elif existing == "infer":
        before = f"; the {there} image(s) already there first (--existing infer)"
    else:
        before = f"; {there} image(s) already there skipped (--existing infer streams them first)"
    how = "listed every 0.25 s" if source.polling else "file events"
    say(f"watching {source.folder} for frames as they land ({how}){before}; Ctrl-C ends")


def say_skipped(source: WatchedFolder | None) -> None:
    """After a watch's summary: how many files it skipped, each warned about as it came."""
    from ..progress import say

    if source is not None and source.skipped:
        say(f"{source.folder}: {source.skipped} file(s) skipped (not images, unreadable or of another size; see above)")


class WatchedFilesSink:
    """``OUT/frames.tsv``: the file each kept frame of a watched folder was read from (``frame_NNNNNN<TAB>FILE``, a
    line a frame, written as it is saved), since the frames land in no order their names tell.

    Made anew by each run, as its frames are (a stream does not resume); the watched folder's name is in
    ``nlips infer``'s stream.json ``input``. ``source``: the stream's source as ``open_frames`` returned it (its
    ``current``: the file of the frame read last)."""

    def __init__(self, folder: str | Path, every: int, source: object) -> None:
        self.path, self.every, self.source = Path(folder) / WATCHED_FILES, max(int(every), 1), source
        self._file = None

    def __call__(self, index: int, frame: np.ndarray, result: object) -> None:
        if index % self.every:
            return
        if self._file is None:
            self._file = open(self.path, "w", encoding="utf-8", newline="\n")  # open while the stream runs
            self._file.write("frame\tfile\n")
        self._file.write(f"frame_{index:06d}\t{Path(self.source.current).name}\n")
        self._file.flush()  # a line a frame, there when the frame is: a stream stopped by a kill keeps its lines

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
