"""A live stream's LED board watched at every frame: a board that reset is relit, the frame taken while its LEDs
were dark dropped, and the user told in one warning; a board that keeps resetting ends the stream in one line."""

from __future__ import annotations

import logging
from typing import Protocol

import numpy as np

from .errors import BROWN_OUT_ADVICE, BoardResetError

log = logging.getLogger(__name__)

RESETS_IN_A_ROW = 3
"""Resets found on this many reads in a row, no frame taken with the LEDs lit between them, end the stream (a board
in a boot loop: relighting it again would only repeat the warning)."""


class Source(Protocol):
    """The frame source watched: ``read()`` (``flush()``, ``shape`` and the rest read through)."""

    def read(self) -> np.ndarray: ...


class ResettableBoard(Protocol):
    """What the watch asks: ``LedController`` (``check_reset``, ``url``)."""

    url: str

    def check_reset(self) -> None: ...


class ResetWatch:
    """A frame source whose LED board is asked after each read whether it reset (the bytes it sent; nothing is
    written); the frame of a read that found one is dropped and read again once the LEDs are relit.

    Why after the read: a reset found then may have darkened the frame just read; one found at the next read came
    after this frame was exposed. The driver (``on_reset="raise"``) has relit the last acknowledged colours, the
    tri-colour pattern, when it raises.

    Parameters
    ----------
    source : the frame source (``read``, ``shape``, ``flush``); its other attributes are read through
    board : the LED controller lighting the pattern (``check_reset``)
    """

    def __init__(self, source: Source, board: ResettableBoard):
        self.source, self.board = source, board
        self.resets = 0

    def __getattr__(self, name: str):
        return getattr(self.source, name)

    def read(self) -> np.ndarray:
        for _ in range(RESETS_IN_A_ROW):
            frame = self.source.read()
            try:
                self.board.check_reset()
            except BoardResetError as exc:
                self.resets += 1
                log.warning(
                    "%s: the LED board reset during the stream (%s); the tri-colour pattern is lit again and the "
                    "frame read as it was found dropped (frames read before its boot banner came may still show the "
                    "LEDs dark): %s",
                    self.board.url,
                    exc.reason,
                    BROWN_OUT_ADVICE,
                )
                if callable(flush := getattr(self.source, "flush", None)):
                    flush()  # a camera's buffered frames were exposed while the LEDs were dark
                continue
            return frame
        raise BoardResetError(
            f"{self.board.url}: the LED board reset at each of {RESETS_IN_A_ROW} frames in a row, so the stream "
            f"stopped: {BROWN_OUT_ADVICE}",
            "it reset again and again",
        )
