"""A capture session on a recorded camera (a folder of frames, an image sequence or a video given as ``--camera``)
resumed where its earlier runs stopped reading the recording.

Each folder a session captures from a recording records, in its meta.json ``provenance.recording``, which recording
it read (``path``, ``frames``, ``first_frame``: :class:`nlipscalib.device.camera.Recording`) and which of its frames:
``from_frame`` (from 0) and ``frames_read``, every attempt's (a retake's, one a board reset cut short). A folder to
capture continues the recording after the frames of the whole folder before it, when that folder read the same
recording (its path and first frame); another recording, or a folder before it captured from a live camera or by an
nlipscalib before 2026-12-07, starts the recording at its first frame, said in one warning.

Why in the folder's meta.json, not in session.json: the folder is published by one rename (``core.write_press``), its
record with it, so a capture killed at any moment leaves no kept folder without its record, nor a record without its
folder. Why a press cut short is read again from its first frame: a press is a fixed sequence of LED states, and the
recording holds the press's frames there in that order; the attempt cut short was not kept, so the resumed run takes
them for it, and the session is the one an uninterrupted run writes. Skipping what the cut attempt read would start
the press mid-sequence (its tri-colour frame one LED's). Why another recording starts at its first frame rather than
being refused: until 2026-12-07 every run read from the first frame and the way to resume was to give a recording
that begins at the press the session resumes with (docs/faults.md), which is this."""

from __future__ import annotations

from pathlib import Path

from ..core.errors import CaptureError
from .camera import EndOfFrames, FrameSource, Recording

RECORD_KEY = "recording"
"""The key of a press folder's meta.json ``provenance`` holding what it read of a recording."""
RECORDED_SINCE = "2026-12-07"
"""The first day captures record what they read of a recording."""


def recorded(source: FrameSource) -> bool:
    """Whether ``source`` is a recording a resumed capture continues (``FrameSource.recording``)."""
    return getattr(source, "recording", None) is not None


def read_record(source: FrameSource, start: int) -> dict:
    """What a folder captured from the recording ``source``, from its frame ``start`` on, records in its meta.json
    ``provenance``: ``{"recording": {path, frames, first_frame, from_frame, frames_read}}``."""
    rec = source.recording
    read = source.frames_consumed - start
    return {
        RECORD_KEY: {"path": rec.path, "frames": rec.frames, "first_frame": rec.first_frame}
        | {"from_frame": int(start), "frames_read": int(read)}
    }


def continue_recording(source: FrameSource, previous: Path | None, name: str) -> str:
    """Make ``source``, a recording, give folder ``name`` its frames: those after the frames ``previous`` (the whole
    folder before ``name`` in the session, None: none) read when it read the same recording, else from its first.

    Returns
    -------
    "" or the one line saying why the recording starts at its first frame though ``previous`` is captured

    Raises
    ------
    CaptureError
        the recording holds no frame after those ``previous`` read (its end)
    """
    rec = source.recording
    record = _record_of(previous) if previous is not None else None
    if record is None or record.get("path") != rec.path or record.get("first_frame") != rec.first_frame:
        source.skip_to(0)
        if previous is None:
            return ""
        return f"{rec.name}: {_why_from_the_start(rec, previous, record)}: read from its first frame for {name}"
    end = int(record["from_frame"]) + int(record["frames_read"])
    if source.frames_consumed == end:  # read on in this run: its end, if there, is said as the camera's
        return ""
    try:
        source.skip_to(end)
    except EndOfFrames:
        holds = f"it holds {rec.frames}" if rec.frames is not None else "it holds no more"
        raise CaptureError(
            f"{rec.name}: no frame left for {name}: the session's folders up to {previous.name} read its frames "
            f"1-{end} and {holds}; give a recording with more frames (the same first ones), or one that begins at "
            f"{name} (another recording is read from its first frame)"
        ) from None
    return ""


def _record_of(folder: Path) -> dict | None:
    """The ``provenance.recording`` of a whole press ``folder``, None when it records none (a live camera's, the
    emulated sensor's, one captured before :data:`RECORDED_SINCE`) or an unusable one."""
    from ..core.press_meta import read_meta

    try:
        provenance = read_meta(folder).get("provenance")
    except (CaptureError, OSError, ValueError):
        return None
    record = provenance.get(RECORD_KEY) if isinstance(provenance, dict) else None
    if not isinstance(record, dict):
        return None
    whole = all(isinstance(record.get(k), int) and record[k] >= 0 for k in ("from_frame", "frames_read"))
    return record if whole else None


def _why_from_the_start(rec: Recording, previous: Path, record: dict | None) -> str:
    """Why the recording ``rec`` is not continued after ``previous`` (its ``record``), in words."""
    if record is None:
        return (
            f"{previous} records no frames read from a recording (captured from a live camera, or by an nlipscalib "
            f"before {RECORDED_SINCE})"
        )
    end = f"its frame {int(record['from_frame']) + int(record['frames_read'])}"
    if record.get("path") != rec.path:
        return f"another recording than the one {previous} read ({record.get('path')}, up to {end})"
    return f"its first frame is not the one {previous} read from it (recorded again since?)"
