"""A stream's LED board watched at every frame: a board that reset is relit, the frames read while its LEDs were
dark dropped and counted, and the user told in one warning; a board that keeps resetting ends the stream in one
line. ``nlips live`` and ``nlips infer`` share it (``cli._stream.open_frames``): a camera, the emulated sensor and a
recording streamed with ``--port`` alike."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Protocol

import numpy as np

from ..core.tolerances import RESET_DARK_FRAME_SHARE
from .errors import BROWN_OUT_ADVICE, BoardResetError

if TYPE_CHECKING:
    from .live import LiveStats

log = logging.getLogger(__name__)

RESETS_IN_A_ROW = 3
"""Resets found on this many reads in a row, no frame taken with the LEDs lit between them, end the stream (a board
in a boot loop: relighting it again would only repeat the warning)."""
DARK_AFTER_RELIGHT = 8
"""Most frames dropped for looking dark after the LEDs were relit (a camera's buffer deeper than its ``flush``
drops, exposed before the relight); a frame still dark after them is handed on (the LEDs dark for another reason)."""
LEVEL_STEP = 16
"""A frame's level is the mean of every LEVEL_STEP-th row and column: 1,200 pixels of a 640x480 frame, ~10 us (every
8th: ~20-70 us on the loaded s38 VM): a dark frame holds the black level, far under a lit one's mean, so the sample's
noise does not matter."""


class Source(Protocol):
    """The frame source watched: ``read()`` (``flush()``, ``shape`` and the rest read through)."""

    def read(self) -> np.ndarray: ...


class ResettableBoard(Protocol):
    """What the watch asks: ``LedController`` (``check_reset``, ``state``, ``url``)."""

    url: str

    def check_reset(self) -> None: ...

    def state(self) -> np.ndarray: ...


def frame_level(frame: np.ndarray) -> float:
    """The mean stored value of a subsample of ``frame`` ((H, W, 3) uint16 or any numeric): how lit it is."""
    return float(frame[::LEVEL_STEP, ::LEVEL_STEP].mean(dtype=np.float64))


class ResetWatch:
    """A frame source whose LED board is asked after each read whether it reset (the bytes it sent; nothing is
    written); the frame of a read that found one is dropped and read again once the LEDs are relit.

    Why after the read: a reset found then may have darkened the frame just read; one found at the next read came
    after this frame was exposed. The driver (``on_reset="raise"``) has relit the last acknowledged colours, the
    tri-colour pattern, when it raises.

    A reset whose boot banner has not come yet (the board still booting, the banner lost on the line) shows first as
    dark frames: a frame under :data:`~nlipscalib.core.tolerances.RESET_DARK_FRAME_SHARE` of the last lit frame's
    level makes the watch ask the board (``state()``, one exchange: ~13 ms for 12 LEDs at 115200), which finds the
    reset by its banner or its lost session (NOSESSION); the frame is then dropped as above. Asked once until a lit
    frame comes again: a board that answers with its LEDs lit leaves the dark frames to the stream (an LED supply
    off, a covered camera), at no cost per frame. Dark frames right after a relight were exposed before it (a
    camera's buffer): dropped, up to :data:`DARK_AFTER_RELIGHT`.

    Parameters
    ----------
    source : the frame source (``read``, ``shape``, ``flush``); its other attributes are read through
    board : the LED controller lighting the pattern (``check_reset``, ``state``)
    lit_by_board : whether the source's frames show the board's light (a camera, the emulated sensor); False for a
        recording streamed with ``--port``: a reset is relit and said, its frames all kept (they were not lit by it)
    stats : the stream's LiveStats, whose ``dropped`` counts the frames read but not handed on: read as a reset was
        found, or dark before its banner came or after the relight (those a camera's ``flush`` discards are not
        counted); default a LiveStats of its own
    """

    def __init__(
        self, source: Source, board: ResettableBoard, lit_by_board: bool = True, stats: LiveStats | None = None
    ):
        from .live import LiveStats

        self.source, self.board, self.lit_by_board = source, board, lit_by_board
        self.stats = LiveStats() if stats is None else stats
        self.resets = 0
        """Resets found during the stream."""
        self._lit_level: float | None = None
        self._asked = self._said_dark = False
        self._after_relight = self._in_a_row = 0

    def __getattr__(self, name: str):
        return getattr(self.source, name)

    def read(self) -> np.ndarray:
        while True:
            frame = self.source.read()
            try:
                self.board.check_reset()
                if self.lit_by_board and self._dark(frame):
                    continue
            except BoardResetError as exc:
                self._relit(exc)
                if self.lit_by_board:
                    continue
                return frame  # a recording's frame: not lit by the board
            self._after_relight = self._in_a_row = 0
            return frame

    def _dark(self, frame: np.ndarray) -> bool:
        """Whether ``frame`` is to be dropped for looking dark; asks the board (BoardResetError: it reset)."""
        level = frame_level(frame)
        if self._lit_level is None or level >= RESET_DARK_FRAME_SHARE * self._lit_level:
            self._lit_level, self._asked = level, False
            return False
        if self._after_relight and self._after_relight <= DARK_AFTER_RELIGHT:
            self._after_relight += 1
            self.stats.dropped += 1
            return True
        if not self._asked:
            self._asked = True
            self.board.state()  # a board that reset says so here (its banner, or NOSESSION): raises
            if not self._said_dark:
                self._said_dark = True
                log.warning(
                    "%s: frames read dark (under %g of the frames before) while the LED board holds the tri-colour "
                    "pattern lit, so they are streamed: is the LEDs' supply on and their cable seated?",
                    self.board.url,
                    RESET_DARK_FRAME_SHARE,
                )
        return False

    def _relit(self, exc: BoardResetError) -> None:
        """Count, say and flush after the reset ``exc`` (the driver relit the pattern); the
        :data:`RESETS_IN_A_ROW`-th reset with no frame handed on between ends the stream."""
        self.resets += 1
        self._in_a_row += 1
        if self._in_a_row >= RESETS_IN_A_ROW:
            raise BoardResetError(
                f"{self.board.url}: the LED board reset at each of {RESETS_IN_A_ROW} frames in a row, so the stream "
                f"stopped: {BROWN_OUT_ADVICE}",
                "it reset again and again",
            )
        if not self.lit_by_board:
            log.warning(
                "%s: the LED board reset during the stream (%s); the tri-colour pattern is lit again (the recorded "
                "frames are all kept: it does not light them): %s",
                self.board.url,
                exc.reason,
                BROWN_OUT_ADVICE,
            )
            return
        self.stats.dropped += 1
        self._after_relight, self._asked = 1, False
        log.warning(
            "%s: the LED board reset during the stream (%s); the tri-colour pattern is lit again and the frames read "
            "while its LEDs were dark dropped (counted in the summary): %s",
            self.board.url,
            exc.reason,
            BROWN_OUT_ADVICE,
        )
        if callable(flush := getattr(self.source, "flush", None)):
            flush()  # a camera's buffered frames were exposed while the LEDs were dark
