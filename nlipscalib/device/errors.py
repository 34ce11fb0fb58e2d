"""Errors of the LED board drivers (LedController, AdalightController): one class per thing the user must do
differently, all of them ``DeviceError`` (exit 2, one line)."""

from __future__ import annotations

from ..core.errors import DeviceError


class PortNotFoundError(DeviceError):
    """The serial port (or URL) does not exist."""


class PortPermissionError(DeviceError):
    """The serial port exists but this user may not open it."""


class PortBusyError(DeviceError):
    """Another program holds the serial port."""


class DeviceTimeoutError(DeviceError):
    """The board did not answer (after all retries)."""


class WrongDeviceError(DeviceError):
    """Something answers on the port, but it is not the nlips LED firmware."""


class ProtocolVersionError(DeviceError):
    """The board runs a firmware or protocol version this driver does not speak."""


class LedIndexError(DeviceError):
    """An LED index outside 0..n_leds-1."""


class BoardError(DeviceError):
    """The board answered a command with an error code."""

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = code


BROWN_OUT_ADVICE = (
    "a board that resets as its LEDs light is often browning out (the LEDs powered from the board's 5 V, or a supply "
    "too weak: firmware/README.md, Wiring, in the nlipscalib source distribution or repository)"
)
"""The likeliest cause of a board that resets while LEDs light, said by `nlips leds test` and `nlips capture`."""
UNPLUGGED_REASON = "the board was unplugged and came back"
"""``BoardResetError.reason`` of a port that failed and reopened (the board lost its power with the USB link)."""


class BoardResetError(DeviceError):
    """The board rebooted during the session (its LEDs went dark; frames taken meanwhile may be wrong).

    ``reason`` says how it showed (its boot banner, NOSESSION, unplugged and back), for callers that word their
    own line (``nlips leds test``: the step it reset at)."""

    def __init__(self, message: str, reason: str = ""):
        super().__init__(message)
        self.reason = reason


class DeviceDisconnectedError(DeviceError):
    """The port vanished (cable pulled) and did not come back in time."""
