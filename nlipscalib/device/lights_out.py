"""The LEDs switched off on the way out: when a block ends (normally, by an error, Ctrl-C or SIGTERM), and best
effort while another error is on its way to the user. For any driver with ``off()``."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Protocol, TypeVar

LIGHTS_OUT_TIMEOUT_S = 0.3
"""How long switching the LEDs off on SIGTERM may wait for the board's acknowledgement, s (one try)."""


class Switchable(Protocol):
    """What the LEDs are switched off through: LedController, AdalightController or anything with ``off()``."""

    def off(self) -> None: ...


C = TypeVar("C", bound=Switchable)
SignalHandler = Callable[[int, FrameType | None], object] | int | None
"""What ``signal.getsignal`` returns: a Python handler, SIG_DFL / SIG_IGN, or None (installed from outside Python)."""


@contextlib.contextmanager
def lights_out_on_exit(controller: C) -> Iterator[C]:
    """Switch the LEDs off when the block ends: normally, by an exception (Ctrl-C too), or by SIGTERM.

    Why: the LEDs keep whatever they show when nothing drives them any more; a capture or a live stream
    stopped halfway would leave the sensor lit (a single WS2812 at full white heats the gel for hours).
    The ``nlips`` command ends a SIGTERM'd process with ``os._exit`` (see cli/__init__.py), which runs no
    ``finally`` block, so a SIGTERM handler is chained in front of the current one for the block: it
    switches the LEDs off (one try, a short timeout: a board that does not answer must not hold the exit
    up), then hands the signal on. Off the main thread no handler can be installed; the other exits still
    switch the LEDs off.

    Parameters
    ----------
    controller : LedController, AdalightController or anything with ``off()``
    """
    if not callable(getattr(controller, "off", None)):  # it failed at the block's end, the LEDs left as they were
        from ..core.errors import ShapeError

        raise ShapeError(
            "controller must be an LED controller (LedController.open(PORT), AdalightController) or anything with "
            f"off(), got {type(controller).__name__}"
        )
    previous = _chain_sigterm(lambda: _off_quickly(controller))
    try:
        yield controller
    except BaseException:
        _restore_sigterm(previous)
        off_quietly(controller)  # the error in flight is the one to report (an unplugged board, Ctrl-C)
        raise
    _restore_sigterm(previous)
    _off_through_a_reset(controller)


def _off_through_a_reset(controller: Switchable) -> None:
    """``controller.off()``; when it finds that the board reset (BoardResetError: the driver relit the last colours
    as it handled it), ``off()`` again before the error goes on, so the LEDs are dark whatever is said.

    Why: a board that reset during ``nlips live`` was found by the OFF at the stream's end, and the LEDs were left
    lit in the tri-colour pattern the driver had restored (s37 device reset walk, virtual board)."""
    from .errors import BoardResetError

    try:
        controller.off()
    except BoardResetError:
        with contextlib.suppress(Exception):
            controller.off()
        raise


def _restore_sigterm(previous: SignalHandler) -> None:
    if previous is not None:
        signal.signal(signal.SIGTERM, previous)


def _chain_sigterm(first: Callable[[], object]) -> SignalHandler:
    """Install a SIGTERM handler that calls ``first()`` and then the handler installed before; returns that."""
    if threading.current_thread() is not threading.main_thread():
        return None
    previous = signal.getsignal(signal.SIGTERM)
    if previous == signal.SIG_IGN:  # the process is not to be terminated: nothing to do on the way out
        return None
    if previous is None:  # installed from outside Python: restoring it is impossible, the default is close
        previous = signal.SIG_DFL

    def handler(signum: int, frame: FrameType | None) -> None:
        with contextlib.suppress(Exception):  # best effort on the way out
            first()
        signal.signal(signal.SIGTERM, previous)
        if callable(previous):
            previous(signum, frame)
        else:  # the default action: terminate, as if this handler had not been there
            signal.raise_signal(signal.SIGTERM)

    signal.signal(signal.SIGTERM, handler)
    return previous


def _off_quickly(controller: Switchable) -> None:
    """``controller.off()`` with one short try (LedController), for a process about to exit."""
    if hasattr(controller, "retries"):
        controller.timeout, controller.retries, controller.reconnect_s = LIGHTS_OUT_TIMEOUT_S, 0, 0.0
    _off_through_a_reset(controller)


def off_quietly(controller: Switchable) -> None:
    """Switch the LEDs off while another error is on its way to the user: best effort, never an error.

    One try with a short timeout (:data:`LIGHTS_OUT_TIMEOUT_S`, no reconnect wait), its own failure
    suppressed; the controller's timeout, retries and reconnect wait are put back afterwards, so a session
    that goes on (a press retaken after a board reset) keeps its patience.

    Why: a clean-up ``off()`` in a ``finally`` replaced the error in flight by its own. After an unplugged
    board did not come back, the capture reported "the LED controller is closed"; after a board went silent,
    "no valid answer to OFF after 4 tries" (the failing command was ALL), having waited the tries a second
    time. The user needs the cause, once.

    Parameters
    ----------
    controller : LedController, AdalightController or anything with ``off()``
    """
    saved = {k: getattr(controller, k) for k in ("timeout", "retries", "reconnect_s") if hasattr(controller, k)}
    try:
        with contextlib.suppress(Exception):
            _off_quickly(controller)
    finally:
        for key, value in saved.items():
            setattr(controller, key, value)
