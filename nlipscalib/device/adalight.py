"""Drive a stock Adalight board (Adalight / Adalight-FastLED firmware), so a lab can start with what it has.

Adalight frame (the de-facto protocol of Adafruit's LEDstream and dmadison's Adalight-FastLED)::

    'A' 'd' 'a'  hi  lo  hi^lo^0x55  R0 G0 B0  R1 G1 B1 ...      with hi, lo = (N - 1) >> 8, (N - 1) & 0xFF

The board prints ``Ada\\n`` when it boots and never answers a frame: there is no acknowledgement, no error
and no state query. This driver therefore waits a settle delay after each frame (transmission at the baud
rate + the WS2812 write + a margin) and the capture code must also flush stale camera frames; ``state()``
returns what was last sent, not what the LEDs show. See docs/protocol.md, "Adalight".
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from ..core.errors import DeviceError, check_kind
from . import protocol as p
from .controller import REPLY_BYTES, _check_colours, _check_index
from .errors import DeviceDisconnectedError, WrongDeviceError
from .port import BAUD_RATE, _serial, check_baudrate, open_port, wire_seconds

if TYPE_CHECKING:  # pyserial is imported where it is used (``_serial``): named for the hints only
    import serial

log = logging.getLogger(__name__)

MAGIC = b"Ada"
BOOT_BANNER = b"Ada\n"
NLIPS_BOOT = b"!BOOT fw="
"""How the nlips LED firmware's boot banner begins (docs/protocol.md): such a board ignores Adalight frames."""
NLIPS_PROBE_S = 0.3
"""How long the driver waits, on top of the line time, for the nlips firmware's answer to the HELLO it sends when no
banner came (the firmware answers within ~15 ms at 115200, s37 simavr paced), s."""
WS2812_US_PER_LED = 30.0
"""Time to clock one LED's 24 bits out at 800 kHz, microseconds."""


def adalight_header(n_leds: int) -> bytes:
    """The 6-byte header for ``n_leds`` LEDs (1..65536)."""
    if not 1 <= n_leds <= 0x10000:
        raise ValueError(f"Adalight frames carry 1 to 65536 LEDs, got {n_leds}")
    hi, lo = (n_leds - 1) >> 8, (n_leds - 1) & 0xFF
    return MAGIC + bytes([hi, lo, hi ^ lo ^ 0x55])


def adalight_frame(colours: np.ndarray) -> bytes:
    """Header + RGB triplets. ``colours : (N, 3) uint8, RGB``."""
    colours = np.ascontiguousarray(colours, dtype=np.uint8)
    return adalight_header(len(colours)) + colours.tobytes()


def _hello_answer(line: bytes) -> str | None:
    """The board description (``fw=1.0.0 proto=1 leds=12 sid=0001``) of a valid nlips reply to HELLO, else None."""
    try:
        marker, body = p.check_frame(line)
        reply = p.decode_reply(body) if marker == p.REPLY_START else None
        if reply is None or not reply.ok:
            return None
        p.decode_info(reply.payload)
    except p.FrameError:
        return None
    return reply.payload


class AdalightController:
    """LedController-like driver for an Adalight board (no acknowledgement: settle delay instead).

    Attributes
    ----------
    n_leds : int
        Number of LEDs (the board cannot tell: the user gives it).
    firmware : str
        Always ``"adalight"``.
    acknowledged : bool
        False: after each call the light is only *probably* latched; flush camera frames as well.
    settle_s : float
        Extra wait after each frame has been transmitted and written to the LEDs, s.
    """

    acknowledged = False
    firmware = "adalight"

    def __init__(
        self,
        url: str,
        port: serial.SerialBase,
        n_leds: int,
        settle_s: float,
        baudrate: int,
        boot_timeout: float,
        reconnect_s: float,
    ):
        self.url, self._port, self.n_leds = url, port, int(n_leds)
        self.settle_s, self.baudrate = float(settle_s), baudrate
        self.boot_timeout, self.reconnect_s = float(boot_timeout), float(reconnect_s)
        self.reconnects = 0
        self._staged = np.zeros((self.n_leds, 3), np.uint8)
        self._shown = self._staged.copy()

    @classmethod
    def open(
        cls,
        url: str,
        n_leds: int,
        *,
        settle_s: float = 0.03,
        baudrate: int = BAUD_RATE,
        boot_timeout: float = 3.0,
        reconnect_s: float = 5.0,
    ) -> AdalightController:
        """Open the port and wait (up to ``boot_timeout`` s) for the ``Ada`` banner of a board that reset.

        Parameters
        ----------
        url : str
            Serial device or pyserial URL.
        n_leds : int
            Number of LEDs on the strip (as configured in the Adalight sketch).
        settle_s : float
            Wait after each frame on top of its transmission and WS2812 write time, s.
        baudrate : int
            Line speed of the sketch (Adalight-FastLED: 115200).
        boot_timeout : float
            How long to wait for ``Ada\\n``; 0 to not wait (boards whose reset on open is disabled).
        reconnect_s : float
            How long to wait for an unplugged board to come back before DeviceDisconnectedError, s.
        """
        check_kind(n_leds, (int, np.integer), "n_leds", "the strip's whole number of LEDs")
        if n_leds < 1:
            raise DeviceError(f"{url}: an Adalight strip needs at least 1 LED, got {n_leds}")
        baudrate = check_baudrate(baudrate, f"{url}: baudrate")  # an int: frame_time_s divides by it
        port = open_port(url, baudrate=baudrate)
        ctrl = cls(url, port, n_leds, settle_s, baudrate, boot_timeout, reconnect_s)
        if boot_timeout > 0:
            ctrl._wait_for_banner(boot_timeout)
        return ctrl

    def _wait_for_banner(self, timeout: float) -> None:
        seen = bytearray()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            seen += self._port.read(max(1, self._port.in_waiting))
            if BOOT_BANNER in seen:
                self._port.reset_input_buffer()
                return
            self._refuse_nlips_board(seen)
        self._probe_nlips_firmware()
        if seen:  # bytes but no banner: what a UART at another rate makes of it
            log.warning(
                "%s: %d bytes but no 'Ada' banner within %g s: is the sketch's line rate %d baud (--baud)? "
                "Sending frames anyway",
                self.url,
                len(seen),
                timeout,
                self.baudrate,
            )
            return
        log.warning("%s: no 'Ada' banner within %g s; sending frames anyway", self.url, timeout)

    def _probe_nlips_firmware(self) -> None:
        """Send the nlips protocol's HELLO once; WrongDeviceError if the nlips LED firmware answers it.

        Why: a board that does not reset when its port opens (the simavr harness, a board with its auto-reset cut,
        DTR kept up since the last command) prints no banner, so ``--adalight`` on the nlips firmware only warned
        and sent frames it ignores. An Adalight sketch skips the line: it holds no ``Ada`` header."""
        command = p.encode_command(1, "HELLO")
        self._port.write(command)
        self._port.flush()
        received = bytearray()
        deadline = time.monotonic() + NLIPS_PROBE_S + wire_seconds(len(command) + REPLY_BYTES, self.baudrate)
        while time.monotonic() < deadline:
            received += self._port.read(max(1, self._port.in_waiting))
            for line in bytes(received).split(b"\n")[:-1]:
                if (info := _hello_answer(line)) is not None:
                    raise self._nlips_board_error(f"{info}, its answer to HELLO")
        self._port.reset_input_buffer()

    def _nlips_board_error(self, description: str) -> WrongDeviceError:
        return WrongDeviceError(
            f"{self.url}: the board runs the nlips LED firmware ({description}), not Adalight: drop --adalight (the "
            "nlips protocol acknowledges every change and reads the LEDs back)"
        )

    def _refuse_nlips_board(self, seen: bytes) -> None:
        """WrongDeviceError once ``seen`` holds the nlips LED firmware's whole boot banner.

        Why: ``--adalight`` on a board flashed with ``firmware/`` waited 3 s, warned "N bytes but no 'Ada' banner:
        is the sketch's line rate ... (--baud)?" and sent frames the firmware ignores (no ``>`` start marker), so
        a capture took frames of dark LEDs."""
        start = seen.find(NLIPS_BOOT)
        end = seen.find(b"\n", start)
        if start < 0 or end < 0:
            return
        raise self._nlips_board_error(seen[start + 1 : end].split(b"*")[0].decode("ascii", "replace"))

    def frame_time_s(self) -> float:
        """Transmission (10 bits per byte) plus WS2812 write time of one frame, s."""
        return wire_seconds(6 + 3 * self.n_leds, self.baudrate) + self.n_leds * WS2812_US_PER_LED * 1e-6

    # --- the LedController interface ------------------------------------------------------------------
    def set_led(self, index: int, rgb: ArrayLike, *, show: bool = True) -> None:
        """Set LED ``index`` (0-based); Adalight has no single-LED command, so the whole frame is resent."""
        self._staged[_check_index(index, self.n_leds)] = _check_colours(np.asarray(rgb).reshape(1, 3), 1)[0]
        if show:
            self.show()

    def set_all(self, colours: ArrayLike) -> None:
        """Send one frame with every LED. ``colours : (N, 3) uint8, RGB``."""
        self._staged[:] = _check_colours(colours, self.n_leds)
        self.show()

    def off(self) -> None:
        self._staged[:] = 0
        self.show()

    def show(self) -> None:
        """Send the staged colours as one frame and wait until they are (probably) latched."""
        self._send(adalight_frame(self._staged))
        self._shown[:] = self._staged

    def state(self) -> np.ndarray:
        """``(N, 3) uint8``: the colours last sent (Adalight cannot report what the LEDs show)."""
        return self._shown.copy()

    def close(self) -> None:
        if self._port is not None:
            self._port.close()
            self._port = None

    def __enter__(self) -> AdalightController:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _send(self, frame: bytes) -> None:
        if self._port is None:
            raise DeviceError(f"{self.url}: the Adalight controller is closed")
        serial = _serial()
        try:
            self._port.write(frame)
            self._port.flush()
        except (serial.SerialException, OSError) as exc:
            self._reconnect(exc)  # the board rebooted (power lost): the frame goes to the new session
            self._port.write(frame)
            self._port.flush()
        time.sleep(self.frame_time_s() + self.settle_s)

    def _reconnect(self, cause: Exception) -> None:
        log.warning("%s: port failed (%s); waiting up to %g s for it to come back", self.url, cause, self.reconnect_s)
        self._port.close()
        deadline = time.monotonic() + self.reconnect_s
        while True:
            try:
                self._port = open_port(self.url, baudrate=self.baudrate)
                break
            except DeviceError as exc:
                if time.monotonic() >= deadline:
                    raise DeviceDisconnectedError(
                        f"{self.url}: the Adalight board disconnected ({cause}) and did not come back within "
                        f"{self.reconnect_s:g} s: {exc}"
                    ) from None
                time.sleep(0.1)
        self.reconnects += 1
        if self.boot_timeout > 0:
            self._wait_for_banner(self.boot_timeout)
