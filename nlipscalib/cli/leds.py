"""``nlips leds PORT ACTION``: check and drive the sensor's LED controller from the command line.

PORT is a serial device (``/dev/ttyACM0``, ``COM3``), a pyserial URL (``socket://host:port``), or
``virtual`` / ``virtual:N`` for an in-process virtual board with N LEDs (try the commands without hardware);
``nlipsemu://ID`` is the virtual board of that id (started here unless this process already has one).
``--adalight N`` drives a stock Adalight board with N LEDs instead of the nlips firmware (the virtual board
then runs Adalight too). ``--baud`` sets the line rate when the board's firmware runs at another rate than
the nlips firmware's 115200 (docs/protocol.md, "Line rate"); the virtual boards run at 115200.

LEDs are numbered from 1 here, as in capture files (LED 1 = ``led_01.png``, docs/conventions.md); the wire
protocol and the Python API number them from 0 (docs/protocol.md), translated in this module only.
"""

from __future__ import annotations

import argparse
import contextlib
from typing import TYPE_CHECKING, TypeAlias

if TYPE_CHECKING:  # named in hints only: pyserial is imported when a board is opened
    import numpy as np

    from ..device.adalight import AdalightController
    from ..device.controller import LedController

    LedBoard: TypeAlias = LedController | AdalightController
    """An opened LED board: the nlips firmware, or a stock Adalight board (which acknowledges nothing)."""

ACTIONS = {
    "info": 0,
    "test": 0,
    "state": 0,
    "off": 0,
    "set": 4,
    "all": 3,
}
"""Action -> number of integer values it takes."""
DEFAULT_VIRTUAL_LEDS = 12


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "leds",
        help="check or drive the LED controller (info, test, set, all, off, state)",
        description="Check or drive the LED controller. LEDs are numbered from 1, as in capture files "
        "(LED 1 = led_01.png).",
    )
    p.add_argument(
        "port",
        help="serial device or pyserial URL; 'virtual[:N]' for a virtual board with N LEDs, "
        "'nlipsemu://ID' for the virtual board of that id",
    )
    p.add_argument(
        "action",
        choices=sorted(ACTIONS),
        help="info: firmware and LED count; test: light each LED alone, then all red, green, blue; "
        "set LED R G B (LED 1..N); all R G B; off; state: colours the LEDs show (read back: not with --adalight)",
    )
    # default: not "required" (argparse's word for a bare nargs="*"): info, test, off and state take none
    p.add_argument(
        "values", nargs="*", type=int, default=[], help="LED R G B for set (LED from 1), R G B for all (0..255)"
    )
    p.add_argument("--adalight", type=int, metavar="N", help="the board runs Adalight with N LEDs")
    add_baud_argument(p)
    p.add_argument("--timeout", type=float, default=1.0, help="seconds to wait for each reply (default 1)")
    p.add_argument("--dwell", type=float, default=0.3, help="test: seconds each step stays lit (default 0.3)")
    p.add_argument("--level", type=int, default=64, help="test: brightness 0..255 (default 64)")
    p.set_defaults(func=run, stopped=stopped_line)


def stopped_line(args: argparse.Namespace) -> str:
    """What ``nlips leds`` interrupted or terminated says it left (``cli._stopped``), not "finished work is kept,
    run again to resume": it keeps no work.

    Why: Ctrl-C during ``nlips leds PORT test`` (an LED that stayed dark, the operator stopping to look) ended with
    "finished work is kept, run again to resume", as if a test went on from where it stopped."""
    if args.action == "test":
        return "the test stopped and switched the LEDs off; a test does not resume (run it again from LED 1)"
    return "nothing to resume (the LEDs show what the board last latched)"


def run(args: argparse.Namespace) -> int:
    expected = ACTIONS[args.action]
    if len(args.values) != expected:
        _refuse(f"{args.action} takes {expected} numbers, got {len(args.values)}")
    if not all(0 <= v <= 255 for v in args.values[-3:]):
        _refuse(f"{args.action}: colour values must be 0..255, got {' '.join(map(str, args.values[-3:]))}")
    if not 0 <= args.level <= 255:
        _refuse(f"--level must be 0..255, got {args.level}")
    if args.action == "set" and args.values[0] < 1:
        _refuse(f"set: LEDs are numbered from 1 (LED 1 = led_01.png), got LED {args.values[0]}")
    if args.adalight is not None and args.adalight < 1:
        _refuse("--adalight needs the strip's LED count (>= 1)")
    if args.action == "state" and args.adalight is not None:
        from ..device.controller import FIRMWARE_GUIDE

        _refuse(
            "state: an Adalight board cannot report what its LEDs show (its protocol has no replies); look at the "
            f"LEDs, or flash the nlips LED firmware, which reads them back ({FIRMWARE_GUIDE})"
        )
    if not args.timeout > 0 or not args.dwell >= 0:
        _refuse(f"--timeout must be > 0 and --dwell >= 0 seconds, got {args.timeout:g} and {args.dwell:g}")
    count = args.port.partition(":")[2] if args.port.startswith("virtual:") else str(DEFAULT_VIRTUAL_LEDS)
    from ..device.protocol import MAX_LEDS

    if not count.isdigit() or not 1 <= int(count) <= MAX_LEDS:
        _refuse(f"virtual:N needs an LED count 1..{MAX_LEDS}, got {count!r}")
    if args.port.startswith("virtual:") and args.adalight is not None and int(count) != args.adalight:
        _refuse(
            f"{args.port} has {int(count)} LEDs but --adalight says {args.adalight}: "
            f"give the count once (virtual --adalight {args.adalight})"
        )
    args.baud = check_baud(args)
    url, board = _board(args)  # board: the virtual board, kept alive while the controller uses it
    with _named_as_typed(args.port, url), _connect(args, url) as leds:
        if args.action != "test":
            return _ACTIONS[args.action](leds, args)
        from ..device.lights_out import lights_out_on_exit

        with lights_out_on_exit(leds):  # a test stopped halfway (Ctrl-C, SIGTERM) leaves no LED lit
            return _test(leds, args)


@contextlib.contextmanager
def _named_as_typed(port: str, url: str):
    """Errors and warnings name the port as the user typed it (``virtual``), not the URL of the board started
    for it.

    Why: ``virtual[:N]`` starts a board at ``nlipsemu://<next id>``, a URL the user never typed, and the
    driver's messages begin with the URL it opened (its log lines too: the Adalight driver's "no 'Ada'
    banner" warning named ``nlipsemu://1``).

    Parameters
    ----------
    port : str
        PORT as typed on the command line.
    url : str
        The URL the driver opens for it.
    """
    import logging

    from ..core.errors import NlipsError

    def rename(record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple):  # the drivers log "%s: ..." with the URL as an argument
            record.args = tuple(port if arg == url else arg for arg in record.args)
        return True

    loggers = [logging.getLogger(f"nlipscalib.device.{name}") for name in ("controller", "adalight")]
    if url != port:
        for logger in loggers:
            logger.addFilter(rename)
    try:
        yield
    except NlipsError as exc:
        if url != port and exc.args and isinstance(exc.args[0], str):
            exc.args = (exc.args[0].replace(f"{url}:", f"{port}:"), *exc.args[1:])
        raise
    finally:
        for logger in loggers:
            logger.removeFilter(rename)


def add_baud_argument(p: argparse.ArgumentParser) -> None:
    """``--baud RATE``: the LED board's line rate, shared by every command that opens the LED port."""
    p.add_argument(
        "--baud",
        metavar="RATE",
        help="line rate of the LED board, baud (default 115200: the nlips firmware's and Adalight-FastLED's)",
    )


def check_baud(args: argparse.Namespace) -> int:
    """The rate of ``--baud`` (default the firmware's), or one line naming --baud (ConfigError)."""
    from ..device.port import BAUD_RATE, check_baudrate

    return check_baudrate(BAUD_RATE if args.baud is None else args.baud, "--baud")


def _refuse(message: str):
    """Bad input: one line, exit 2 (the nlips command prints it)."""
    from ..core.errors import ConfigError

    raise ConfigError(message)


def _board(args: argparse.Namespace):
    """The URL to open for PORT, and the virtual board started for it (None for a real port)."""
    from ..device.port import BAUD_RATE
    from ..device.virtual_board import VirtualBoard, start_board

    url = args.port
    n_leds = args.adalight or DEFAULT_VIRTUAL_LEDS
    adalight = args.adalight is not None
    if url == "virtual" or url.startswith("virtual:"):
        board = VirtualBoard(int(url.partition(":")[2] or n_leds), adalight=adalight, baudrate=BAUD_RATE)
        return board.url, board
    # nlipsemu://ID: this process's board of that id, else one started at the firmware's rate
    return url, start_board(url, n_leds, adalight=adalight, baudrate=BAUD_RATE)


def _connect(args: argparse.Namespace, url: str) -> LedBoard:
    from ..device.adalight import AdalightController
    from ..device.controller import LedController

    if args.adalight is not None:
        return AdalightController.open(url, args.adalight, baudrate=args.baud)
    return LedController.open(url, timeout=args.timeout, baudrate=args.baud)


def _info(leds: LedBoard, args: argparse.Namespace) -> int:
    if not leds.acknowledged:
        print(f"Adalight board, {leds.n_leds} LEDs (no acknowledgement: settle delay {leds.settle_s * 1e3:.0f} ms)")
        return 0
    info = leds.info
    print(f"firmware {info.firmware}, protocol {info.protocol}, {info.n_leds} LEDs, session {info.session_id}")
    return 0


def _light_step(leds: LedBoard, frame: np.ndarray, name: str, port: str) -> None:
    """Light one step of ``nlips leds test``; a board that reset meanwhile is a DeviceError naming the step.

    Why: it ended with the driver's "... restored to the last acknowledged colours; retake any frame captured
    since the previous command", a capture's advice, at a test whose likeliest cause is the LEDs' current
    pulling the board's supply down as they light (s36 device walk: the firmware in simavr, reset mid-test)."""
    from ..core.errors import DeviceError
    from ..device.errors import BROWN_OUT_ADVICE, BoardResetError

    try:
        leds.set_all(frame)
    except BoardResetError as exc:
        raise DeviceError(
            f"{port}: the board reset as the test lit {name} ({exc.reason}): {BROWN_OUT_ADVICE}; run the test again "
            "(a lower --level draws less)"
        ) from None


def _test(leds: LedBoard, args: argparse.Namespace) -> int:
    import time

    import numpy as np

    steps = [(f"LED {i + 1}", _one_lit(leds.n_leds, i, args.level)) for i in range(leds.n_leds)]
    for name, channel in (("all red", 0), ("all green", 1), ("all blue", 2)):
        frame = np.zeros((leds.n_leds, 3), np.uint8)
        frame[:, channel] = args.level
        steps.append((name, frame))
    times = []
    for name, frame in steps:
        start = time.perf_counter()
        _light_step(leds, frame, name, args.port)
        times.append(time.perf_counter() - start)
        if not leds.acknowledged:  # nothing to check: the frame went out, whether a board lit it or not
            print(f"{name} (sent; Adalight does not acknowledge)", flush=True)
        elif not np.array_equal(leds.state(), frame):
            print(f"{name}: the board reports other colours than sent")
            return 1
        else:
            print(f"{name}: lit ({times[-1] * 1e3:.1f} ms)", flush=True)
        time.sleep(args.dwell)
    if not leds.acknowledged:
        print(
            f"sent: {len(steps)} steps; Adalight does not acknowledge, so nothing was checked: each LED should have "
            "lit alone, then all red, green and blue"
        )
        return 0
    resends = getattr(leds, "resends", 0)
    print(f"ok: {len(steps)} steps, median {np.median(times) * 1e3:.1f} ms per change, {resends} lines resent")
    return 0


def _one_lit(n_leds: int, index: int, level: int):
    import numpy as np

    frame = np.zeros((n_leds, 3), np.uint8)
    frame[index] = level
    return frame


def _state(leds: LedBoard, args: argparse.Namespace) -> int:
    for number, (r, g, b) in enumerate(leds.state(), 1):
        print(f"LED {number}: {r} {g} {b}")
    return 0


def _off(leds: LedBoard, args: argparse.Namespace) -> int:
    leds.off()
    _done(leds, f"all {leds.n_leds} LEDs off")
    return 0


def _set(leds: LedBoard, args: argparse.Namespace) -> int:
    number, *rgb = args.values
    if number > leds.n_leds:
        from ..device.errors import LedIndexError

        raise LedIndexError(f"set: there is no LED {number}: the board has {leds.n_leds} LEDs (1..{leds.n_leds})")
    leds.set_led(number - 1, rgb)  # the protocol counts from 0
    _done(leds, f"LED {number} set to {' '.join(map(str, rgb))}")
    return 0


def _all(leds: LedBoard, args: argparse.Namespace) -> int:
    import numpy as np

    leds.set_all(np.tile(np.array(args.values, np.uint8), (leds.n_leds, 1)))
    _done(leds, f"all {leds.n_leds} LEDs set to {' '.join(map(str, args.values))}")
    return 0


def _done(leds: LedBoard, what: str) -> None:
    """Confirm a change on one line; an Adalight board acknowledges nothing, so say the frame was only sent."""
    print(what if leds.acknowledged else f"{what} (sent; Adalight does not acknowledge)")


_ACTIONS = {"info": _info, "test": _test, "state": _state, "off": _off, "set": _set, "all": _all}
