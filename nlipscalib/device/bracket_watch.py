"""An exposure bracket's LED board watched at every frame: each frame is kept once the board answered a ``STATE``
sent after the frame was read, so none read while a rebooted board's LEDs were dark is kept; a frame a reset may
have darkened is taken again once the driver relit the LEDs, and a colour change a reset cut short is sent again.
``nlips calibrate-camera-response --port`` (its bracket, its dark frame, its LEDs lit apart and together).

Why a ``STATE`` after every frame, not ``check_reset`` (what a stream asks, ``device.live_leds``): the bracket lights
its LED once and then sends nothing while the exposure steps, and a reset whose boot banner is late (a board still in
its bootloader) or lost would be found exposures later, or by the dark frame's LEDs-off, with no way to tell which
frames were dark; their brightness cannot tell either (each exposure is meant to be darker or brighter than the one
before). A rebooted board answers nothing but ``HELLO`` (``E7 NOSESSION``, docs/protocol.md), so an answered
``STATE`` proves the LEDs stayed lit up to it; one exchange, 13 ms for 12 LEDs at 115200 baud (docs/protocol.md,
Timing), against a camera's flushed and averaged frame per exposure."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Protocol

import numpy as np

from .errors import BROWN_OUT_ADVICE, UNPLUGGED_REASON, BoardResetError

log = logging.getLogger(__name__)

RESET_ATTEMPTS = 3
"""Attempts at one frame (or one colour change) that a board reset cuts short before the bracket stops: a board
in a boot loop (its supply browning out as the LEDs light) would only repeat the retake."""


class Camera(Protocol):
    """What the watch takes frames from: ``FrameSource.capture`` (flushed, averaged)."""

    def capture(self) -> np.ndarray: ...


class Board(Protocol):
    """What the watch asks: ``LedController`` (``set_all``, ``state``, ``url``, ``acknowledged``); an Adalight board
    (``acknowledged`` False) answers nothing, so its frames are kept unasked."""

    url: str
    acknowledged: bool

    def set_all(self, colours: np.ndarray) -> None: ...

    def state(self) -> np.ndarray: ...


class BracketWatch:
    """Frames of a bracket whose LED board is asked after each, and the colour changes between them.

    Parameters
    ----------
    source : the camera (``capture``)
    board : the LED controller lighting the gel (``set_all``, ``state``)
    set_exposure : sets the camera's exposure, ms; returns the time the camera reports (None: the time asked)
    say : where a retake is said (one line; ``progress.say``)
    """

    def __init__(
        self,
        source: Camera,
        board: Board,
        set_exposure: Callable[[float], float | None],
        say: Callable[[str], None],
    ):
        self.source, self.board, self._set_exposure, self._say = source, board, set_exposure, say
        self.resets = 0
        """Resets found (and retaken) during the bracket."""
        self._ms: float | None = None
        self._lit: tuple[int, ...] = ()

    def set_exposure(self, ms: float) -> float | None:
        """The camera's exposure set to ``ms`` (named in a retake's line)."""
        self._ms = ms
        return self._set_exposure(ms)

    def set_colours(self, colours: np.ndarray) -> None:
        """``colours : (N, 3) uint8`` latched; sent again after a reset found as it was sent (the driver relit the
        colours before it: no frame was read since the last one the board answered for, so nothing is retaken)."""
        self._lit = tuple(int(k) + 1 for k in np.flatnonzero(np.asarray(colours).any(axis=1)))
        for attempt in range(1, RESET_ATTEMPTS + 1):
            try:
                self.board.set_all(colours)
                return
            except BoardResetError as exc:
                step = f"the LEDs' change to {self._leds()}"
                self._reset(
                    exc, attempt, step, f"at {step}: sent again (no frame was read since the board last answered)"
                )

    def capture(self) -> np.ndarray:
        """One frame, kept once the board answered ``STATE`` after it was read; taken again (the camera's flush
        drops the frames exposed before the relight) when that finds the board reset."""
        for attempt in range(1, RESET_ATTEMPTS + 1):
            frame = self.source.capture()
            if not getattr(self.board, "acknowledged", False):
                return frame
            try:
                self.board.state()  # a rebooted board: its banner or NOSESSION; the driver relights, then raises
                return frame
            except BoardResetError as exc:
                step = f"the {self.frame_name()}"
                self._reset(exc, attempt, step, f"as {step} was taken: the LEDs are set again and it is taken again")
        raise AssertionError("unreachable: _reset raises at the last attempt")

    def frame_name(self) -> str:
        """The frame being taken, as a line names it: "4 ms frame with LED 1 lit", "8 ms frame with LEDs 1+7 lit",
        "0.5 ms frame with every LED off"."""
        at = "" if self._ms is None else f"{self._ms:g} ms "
        return f"{at}frame with {self._leds()}"

    def _leds(self) -> str:
        """The LEDs last set: "LED 1 lit", "LEDs 1+7 lit", "every LED off"."""
        if not self._lit:
            return "every LED off"
        return f"LED{'s' if len(self._lit) > 1 else ''} {'+'.join(str(k) for k in self._lit)} lit"

    def _reset(self, exc: BoardResetError, attempt: int, step: str, said: str) -> None:
        """Count a reset and say ``said`` after the board's URL (the driver warned and relit); BoardResetError in one
        line naming ``step`` at the :data:`RESET_ATTEMPTS`-th attempt at it."""
        self.resets += 1
        cable = ", or its USB cable is loose" if exc.reason == UNPLUGGED_REASON else ""
        if attempt == RESET_ATTEMPTS:
            raise BoardResetError(
                f"{self.board.url}: the LED board reset at each of {RESET_ATTEMPTS} attempts at {step} ({exc.reason}), "
                f"so the bracket stopped: {BROWN_OUT_ADVICE}{cable}",
                exc.reason,
            ) from None
        self._say(f"{self.board.url}: the LED board reset ({exc.reason}) {said}")
