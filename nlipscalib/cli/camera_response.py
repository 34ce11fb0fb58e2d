"""``nlips calibrate-camera-response``: measure a camera's tone curve from an exposure bracket, for a camera that
can neither turn its gamma off nor applies the exact sRGB curve.

Real sensor (the undeformed gel lit by one LED, the exposure stepped)::

    nlips calibrate-camera-response --port /dev/ttyACM0 --camera 0 --out response.json

Emulated sensor (its camera encoding with a vendor curve the tools are not told)::

    nlips calibrate-camera-response --emulate nlipstac --emulate-tone-curve s-curve --out response.json

then ``nlips capture --camera-response response.json ...``: every capture records the curve and is undone by it.
Not ``nlips calibrate-camera`` (the lens: intrinsics and distortion from checkerboards).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import functools
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from .leds import add_baud_argument, check_baud

if TYPE_CHECKING:  # named in hints only: imported when a bracket is taken
    import numpy as np

    from ..device.additivity import AdditivityFrames
    from ..device.bracket_times import TimesEstimate
    from ..device.camera import FrameSource
    from ..device.response_fit import ResponseFit

EMULATED_EXPOSURE_MS = 10.0
"""The exposure the emulated camera's frames are made at (its scene's auto exposure): a bracket's exposure over this
scales its light (``EmulatedCamera.exposure_scale``); ``nlips capture``'s default --exposure-ms."""
DEFAULT_EXPOSURES_MS = tuple(round(0.5 * 2 ** (k / 2), 3) for k in range(15))
"""0.5 to 64 ms in half-stop (sqrt 2) steps: with one LED lighting the gel, each code is seen in about five of them
(benchmarks/RESULTS.md, s30-response)."""
TONE_CURVE_CHOICES = ("gamma2.2", "s-curve", "srgb", "rgb-gammas")
"""``emulator.EMULATED_TONE_CURVES``'s names (a test keeps them equal), named without importing numpy for --help."""
ADDITIVITY_PARTNERS = (1, 0.5)
"""The LEDs lit apart and with --led for the additivity check (``device.additivity``), as offsets from it in the
board's order (wrapping): whole numbers of LEDs, or fractions of the board's count: the next LED and the one
halfway round, so that the pairs light pixels alike (neighbours on a ring) and unalike (opposite LEDs)."""
SHOWN_MOVE = 0.01
"""A --bracket folder's estimated time is named in the line when it moved from the one named by more than this
(the others moved by the estimate's noise)."""
STOPPED = "nothing was written (a tone curve is measured from the whole bracket): run it again"
"""What ``nlips calibrate-camera-response`` interrupted or terminated says it left (``cli._stopped``): it writes its
curve once, at the end, so "finished work is kept, run again to resume" promised a resume it does not do."""
DarkFrame = tuple
"""A bracket's frame with every LED off: (its codes above the black level, (H, W, 3) uint8; its exposure, ms, or
None where a --bracket folder's name gives none; the camera's DN per 8-bit code, to name a black level)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    from ..core.tolerances import RESPONSE_ESTIMATE_STEP  # constants only: no numpy for --help

    p = subparsers.add_parser(
        "calibrate-camera-response",
        help="measure the camera's tone curve from an exposure bracket -> response JSON for --camera-response",
        description="Measure how the camera's values relate to light, for a webcam that cannot turn its tone curve "
        "off and does not apply the exact sRGB curve (gamma 2.2, a vendor curve, a contrast setting): the "
        "undeformed gel lit by one LED is taken at several exposures, OpenCV's CalibrateRobertson fits the curve, "
        "and the response file (docs/formats.md, Camera response file) and its figure are written. Give it to "
        "`nlips capture --camera-response FILE`: each capture records the curve and is linearised with it. The "
        "fit takes each frame at the exposure asked, so a bracket whose frames do not brighten with it is refused, "
        "nothing written: a camera that ignores the exposure (auto exposure on: every frame equally bright), "
        "quantises it (two exposures one frame) or whose frames lag the setting (a larger --flush), one whose "
        "frames' light, the curve undone, does not grow as the times (it rounds them to steps of its own), and one "
        "whose frame with every LED off reads above --black-level (it adds a black level). Then LEDs lit apart and "
        "together at one exposure check that light adds with the curve undone: a curve off by a power (real "
        "exposure times a power of the asked ones, which no bracket can see) is raised to the power that makes "
        "them add, said in a line; LEDs that dim each other lit together are refused. Channels that respond "
        "differently keep a curve each. On DirectShow and Media Foundation (whole log2-second steps) the bracket "
        "is taken at the powers of two, said in a line; on V4L2 at whole 100 us steps; each exposure is read back "
        "and the bracket fitted at the times the camera reports (a shutter table's 1/60 s for 16 ms), said in a line.",
    )
    p.add_argument("--out", required=True, help="response JSON to write (for `nlips capture --camera-response`)")
    p.add_argument("--figure", help="PNG of the curve per channel and the measured points (default: OUT with .png)")
    p.add_argument(
        "--exposures-ms",
        help=f"comma-separated exposures, ms, at least 5 (default {DEFAULT_EXPOSURES_MS[0]:g} to "
        f"{DEFAULT_EXPOSURES_MS[-1]:g} in sqrt(2) steps): from the lit gel dark to just clipped",
    )
    p.add_argument(
        "--led",
        type=int,
        default=1,
        help="the LED lit, 1-based (default 1): its light falls off across "
        "the gel, so one frame holds many levels (all LEDs light it evenly)",
    )
    p.add_argument("--level", type=int, default=255, help="that LED's drive, 1-255 (default 255)")
    src = p.add_argument_group("real sensor")
    src.add_argument("--port", help="LED controller: serial port or pyserial URL (/dev/ttyACM0, COM3, ...)")
    src.add_argument("--adalight", type=int, metavar="N", help="the LED board runs stock Adalight with N LEDs")
    add_baud_argument(src)
    src.add_argument("--camera", default="0", help="camera index or device path (default 0)")
    src.add_argument("--gain", type=float, default=0.0, help="fixed analogue gain, camera units (default 0)")
    src.add_argument("--white-balance", type=float, default=5000.0, help="fixed white balance, kelvin (default 5000)")
    src.add_argument("--black-level", type=float, default=0.0, help="camera black level in its own DN (default 0)")
    src.add_argument(
        "--flush",
        type=int,
        default=4,
        help="frames dropped after each exposure change (default 4): more if the "
        "camera's frames lag a new exposure (the bracket is then refused: frames equally bright or darker)",
    )
    src.add_argument("--average", type=int, default=1, help="frames averaged per exposure (default 1)")
    taken = p.add_argument_group("a bracket already taken (a camera OpenCV cannot set the exposure of)")
    taken.add_argument(
        "--bracket",
        metavar="FOLDER",
        help="images of the lit gel the lab took with the vendor's tool, one per exposure, the exposure in each "
        "name (gel_2.5ms.png) or in FOLDER/exposures.csv (file,exposure_ms rows); --black-level as captured; "
        "optionally dark.png, every LED off (checked against --black-level), and FOLDER/additivity/ of LEDs lit "
        "apart and together at one exposure (dark.png, led_1.png, led_2.png, led_1+2.png, ...: they check the "
        "curve's power, as the command's own frames do); without it the times are estimated from the images and "
        f"the curve fitted at them when one step is more than {RESPONSE_ESTIMATE_STEP * 100:g}%% off the named (a "
        "camera rounding them to a 1/n s table), said in a line (with it, and from a camera, only when the fit at "
        "the times named is refused)",
    )
    emu = p.add_argument_group("emulated sensor")
    emu.add_argument("--emulate", metavar="SCENE", help="measure the emulated sensor of this scene (no hardware)")
    emu.add_argument(
        "--emulate-tone-curve",
        choices=TONE_CURVE_CHOICES,
        help="the tone curve the emulated camera encodes with (default none: linear frames; rgb-gammas: gamma 2.0, "
        "2.2, 2.4 in R, G, B, a camera whose channels differ)",
    )
    emu.add_argument("--width", type=int, help="emulated image width, pixels (default: the scene's camera)")
    emu.add_argument("--height", type=int, help="emulated image height, pixels (default: the scene's camera)")
    emu.add_argument("--spp", type=int, help="emulated render samples per pixel (default: the scene's)")
    emu.add_argument("--seed", type=int, default=0, help="emulated sensor noise seed (default 0)")
    p.set_defaults(func=run, stopped=STOPPED)


def exposures_of(text: str | None) -> tuple[float, ...]:
    """The ``--exposures-ms`` list: numbers > 0, ConfigError naming the option otherwise (the bracket's own checks,
    ``device.response_fit``, count them)."""
    from ..core.errors import ConfigError

    if text is None:
        return DEFAULT_EXPOSURES_MS
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--exposures-ms must be comma-separated numbers of ms, got {text!r}") from None
    if not all(v > 0 and v != float("inf") for v in values):
        raise ConfigError(f"--exposures-ms must all be > 0 ms, got {text!r}")
    return values


def _check(args: argparse.Namespace) -> None:
    from ..core.atomic import check_writable
    from ..core.errors import ConfigError
    from .folders import names_a_folder

    if names_a_folder(args.out):
        example = Path(args.out) / "response.json"
        raise ConfigError(f"--out {args.out}: a folder; give the JSON file to write (e.g. {example})")
    if args.figure and names_a_folder(args.figure):  # found after the capture as "FIGURE: Is a directory"
        example = Path(args.figure) / "response.png"
        raise ConfigError(f"--figure {args.figure}: a folder; give the PNG file to write (e.g. {example})")
    if not 1 <= args.level <= 255:
        raise ConfigError(f"--level must be 1..255, got {args.level}")
    if args.emulate and (args.port or args.adalight is not None):
        raise ConfigError("--port/--adalight are not used with --emulate: the emulated sensor has its own LED board")
    for dest in ("emulate_tone_curve", "width", "height", "spp"):
        if not args.emulate and getattr(args, dest) is not None:
            raise ConfigError(f"--{dest.replace('_', '-')} is only used with --emulate SCENE")
    if args.bracket and (args.emulate or args.port or args.adalight is not None):
        raise ConfigError("--bracket FOLDER is a bracket already taken: no --port, --adalight or --emulate with it")
    if not args.emulate and not args.port and not args.bracket:
        raise ConfigError(
            "give the LED controller's --port and --camera (or --bracket FOLDER of images already taken, or "
            "--emulate SCENE, to run without hardware)"
        )
    if args.average < 1 or args.flush < 0:
        raise ConfigError(f"--average must be >= 1 and --flush >= 0, got {args.average}, {args.flush}")
    args.baud = check_baud(args)
    check_writable(Path(args.out).parent)  # a read-only disk: one line now, not after the bracket is taken


def run(args: argparse.Namespace) -> int:
    _check(args)
    from ..device.response_fit import check_exposures

    if args.bracket:
        frames, exposures, source, black, dark, shots = _folder_bracket(args)
        return _fit_and_write(args, frames, exposures, source, source, black, dark, shots)
    exposures = exposures_of(args.exposures_ms)
    check_exposures(exposures, f"--emulate {args.emulate}" if args.emulate else f"camera {args.camera}")
    if args.emulate:
        frames, source, camera, black, dark, shots = _emulated_bracket(args, exposures)
    else:
        frames, exposures, source, camera, black, dark, shots = _device_bracket(args, exposures)
    return _fit_and_write(args, frames, exposures, source, camera, black, dark, shots)


def take_bracket(
    source: FrameSource,
    light: Callable[[], None],
    set_exposure: Callable[[float], float | None],
    exposures: Sequence[float],
) -> tuple[list[np.ndarray], list[float]]:
    """One frame of the lit gel per exposure, as stored values (``FrameSource.capture``: flushed, averaged), and the
    time each was taken at.

    Parameters
    ----------
    source : the camera
    light : lights the LED (called once, before the first exposure)
    set_exposure : sets the camera's exposure, ms; returns the time the camera reports it took, ms (None: the time
        asked)
    exposures : ms, in the order taken

    Returns
    -------
    frames : list of (H, W, 3) uint16, stored values ``DN << (16 - bit_depth)``
    taken : ms, each frame's exposure as the camera reported it
    """
    from ..progress import track

    light()
    frames, taken = [], []
    for ms in track(exposures, enabled=_bars(), desc="bracket", unit="exposure"):
        reported = set_exposure(ms)
        frames.append(source.capture())
        taken.append(float(ms if reported is None else reported))
    return frames, taken


def as_reported(camera: str, asked: Sequence[float], taken: Sequence[float], frames: list) -> tuple[list, list]:
    """The bracket at the times the camera reports it took (:func:`take_bracket`), said in one line when they are
    not the times asked; a frame whose reported time an earlier frame already has is dropped (a minimum or a table
    step clamped two asked times to one: the same exposure twice says nothing more and would weigh one time twice).

    Returns
    -------
    frames : the frames kept, as given
    times : ms, each kept frame's
    """
    import math

    moved = [(a, t) for a, t in zip(asked, taken, strict=True) if not math.isclose(a, t, rel_tol=1e-6)]
    if not moved:
        return list(frames), list(taken)
    kept = {}
    for frame, ms in zip(frames, taken, strict=True):
        kept.setdefault(ms, frame)
    shown = ", ".join(f"{a:g} -> {t:.4g}" for a, t in moved[:6]) + (", ..." if len(moved) > 6 else "")
    dropped = len(frames) - len(kept)
    print(
        f"camera {camera} reports exposures other than asked ({shown} ms): the bracket is fitted at the times it "
        "reports" + (f" ({dropped} frames at a time already taken dropped)" if dropped else ""),
        file=sys.stderr,
    )
    return list(kept.values()), list(kept)


def take_dark(
    source: FrameSource, lights_off: Callable[[], None], set_exposure: Callable[[float], float | None], ms: float
) -> np.ndarray:
    """One frame with every LED off at ``ms`` (the bracket's shortest exposure: room light adds least there), as
    stored values: what the camera reads for no light (``device.response_fit.check_black``)."""
    lights_off()
    set_exposure(ms)
    return source.capture()


def take_additivity(
    source: FrameSource,
    set_colours: Callable[[np.ndarray], None],
    set_exposure: Callable[[float], float | None],
    n_leds: int,
    led: int,
    level: int,
    exposure_ms: float,
) -> tuple[np.ndarray, dict, tuple] | None:
    """The frames of LEDs lit apart and together at ``exposure_ms`` (``device.additivity``): every LED off, ``led``
    and its :data:`ADDITIVITY_PARTNERS` each alone, then each pair of them together, all at ``level``.

    Returns
    -------
    dark : (H, W, 3) uint16 stored values
    singles : LED number (1-based) -> (H, W, 3) uint16
    pairs : ((LED a, LED b, (H, W, 3) uint16 lit together), ...)
    (None, nothing taken, for a board of one LED)
    """
    import itertools

    import numpy as np

    offsets = [0, *(k if isinstance(k, int) else round(k * n_leds) for k in ADDITIVITY_PARTNERS)]
    leds = list(dict.fromkeys((led - 1 + k) % n_leds + 1 for k in offsets))
    if len(leds) < 2:  # a board of one LED: no pair to light
        return None

    def lit(*which: int) -> np.ndarray:
        colours = np.zeros((n_leds, 3), np.uint8)
        colours[[k - 1 for k in which]] = level
        set_colours(colours)
        return source.capture()

    set_exposure(exposure_ms)
    dark = lit()
    singles = {k: lit(k) for k in leds}
    pairs = tuple((a, b, lit(a, b)) for a, b in itertools.combinations(leds, 2))
    set_colours(np.zeros((n_leds, 3), np.uint8))
    return dark, singles, pairs


def additivity_codes(
    taken: tuple | None, exposure_ms: float, bit_depth: int, black_dn: float
) -> AdditivityFrames | None:
    """:func:`take_additivity`'s frames as ``device.additivity.AdditivityFrames`` of 8-bit codes (:func:`to_codes`)."""
    from ..device.additivity import AdditivityFrames

    if taken is None:
        return None
    dark, singles, pairs = taken
    return AdditivityFrames(
        exposure_ms,
        to_codes(dark, bit_depth, black_dn),
        {k: to_codes(f, bit_depth, black_dn) for k, f in singles.items()},
        tuple((a, b, to_codes(f, bit_depth, black_dn)) for a, b, f in pairs),
    )


def dn_per_code(bit_depth: int, black_dn: float) -> float:
    """The camera's DN per 8-bit code above ``black_dn`` (:func:`to_codes`' scale)."""
    return ((1 << bit_depth) - 1 - black_dn) / 255


def _bars() -> bool:
    from ..progress import bars_enabled

    return bars_enabled()


def to_codes(stored: np.ndarray, bit_depth: int, black_dn: float) -> np.ndarray:
    """8-bit codes of a stored frame as encoded fractions above black, ``rint((DN - black) / (max - black) * 255)``:
    what a response curve's entries stand for (``core.response_curve``); an 8-bit camera with black 0 keeps its DN.

    Parameters
    ----------
    stored : (H, W, 3) uint16, ``DN << (16 - bit_depth)``
    bit_depth : bits of the camera's values
    black_dn : its black level, DN

    Returns
    -------
    (H, W, 3) uint8
    """
    import numpy as np

    dn = (stored >> np.uint16(16 - bit_depth)).astype(np.float32)
    top = float((1 << bit_depth) - 1)
    codes = np.rint((dn - np.float32(black_dn)) * np.float32(255 / (top - black_dn)))
    return np.clip(codes, 0, 255).astype(np.uint8)


def _emulated_bracket(args: argparse.Namespace, exposures: Sequence[float]):
    import numpy as np

    from ..device.additivity import pair_exposure
    from ..device.bracket_watch import BracketWatch
    from ..emulator import open_emulated_sensor
    from ..progress import say
    from ..sim.scene import load_scene
    from .options import check_size_pair

    scene = load_scene(args.emulate)
    check_size_pair(args.width, args.height, (scene.camera.width, scene.camera.height))
    camera = {k: v for k, v in {"width": args.width, "height": args.height}.items() if v}
    scene = scene.replace(camera=camera, render={"spp": args.spp} if args.spp else {})
    n_leds = len(scene.led_models())
    _check_led(args.led, n_leds)
    # no LEDs-off closes the emulated bracket (its board ends with it): a reset that stops it is one with STOPPED
    with (
        _reset_after_the_bracket(f"--emulate {args.emulate}", lambda: False),
        open_emulated_sensor(scene, [], seed=args.seed, tone_curve=args.emulate_tone_curve) as sensor,
    ):
        sensor.camera.show(None, index=0)
        sensor.prerender(progress=_bars())

        def set_exposure(ms: float) -> None:
            sensor.camera.exposure_scale = ms / EMULATED_EXPOSURE_MS

        # its in-process board watched as a real one (its camera renders what the board latched: dark after a reset)
        watch = BracketWatch(sensor.camera, sensor.rig.controller, set_exposure, say)
        lit = np.zeros((n_leds, 3), np.uint8)
        lit[args.led - 1] = args.level
        frames, _ = take_bracket(watch, functools.partial(watch.set_colours, lit), watch.set_exposure, exposures)
        lights_off = functools.partial(watch.set_colours, np.zeros_like(lit))
        dark = take_dark(watch, lights_off, watch.set_exposure, min(exposures))
        noise = scene.noise
        codes = [to_codes(f, noise.bit_depth, noise.black_level) for f in frames]
        at = pair_exposure(codes, exposures)
        taken = take_additivity(watch, watch.set_colours, watch.set_exposure, n_leds, args.led, args.level, at)
    shots = additivity_codes(taken, at, noise.bit_depth, noise.black_level)
    scale = dn_per_code(noise.bit_depth, noise.black_level)
    dark = (to_codes(dark, noise.bit_depth, noise.black_level), min(exposures), scale)
    curve = args.emulate_tone_curve or "linear"
    name = f"emulated ({args.emulate}, tone curve {curve})"
    return codes, f"--emulate {args.emulate}", name, noise.black_level, dark, shots


def _device_bracket(args: argparse.Namespace, exposures: Sequence[float]):
    import numpy as np

    from ..device.additivity import pair_exposure
    from ..device.bracket_watch import BracketWatch
    from ..device.camera import CameraSettings, apply_settings, open_source, report_refusals, reported_exposure_ms
    from ..device.lights_out import lights_out_on_exit
    from ..device.port import BAUD_RATE
    from ..device.response_fit import check_exposures
    from ..device.virtual_board import start_board
    from ..progress import say
    from .capture import open_leds

    settings = CameraSettings(
        exposure_ms=exposures[0],
        gain=args.gain,
        white_balance_k=args.white_balance,
        flush_frames=args.flush,
        average=args.average,
        linear_gamma=False,  # the curve to be measured is the one the camera keeps on
    )
    # --port nlipsemu://ID: a virtual board of the default design's 12 LEDs (or as many as --led needs)
    board = start_board(
        args.port, args.adalight or max(args.led, 12), adalight=args.adalight is not None, baudrate=BAUD_RATE
    )
    taken_whole = False
    with (
        _reset_after_the_bracket(args.port, lambda: taken_whole),
        board if board is not None else contextlib.nullcontext(),
        open_leds(args.port, args.adalight, args.baud) as controller,
        lights_out_on_exit(controller),
        open_source(args.camera, settings) as source,
    ):
        _check_led(args.led, controller.n_leds)
        cap = getattr(source, "cap", None)
        if cap is None or not getattr(source, "live", False):
            from ..core.errors import ConfigError

            raise ConfigError(
                f"--camera {args.camera}: a live camera is needed (its exposure is stepped); images of the lit gel "
                "taken at several exposures with the camera's own tool: --bracket FOLDER, without --port"
            )

        refused: dict[str, None] = {}  # each exposure's readback, said once after the bracket: not a line a step

        def set_exposure(ms: float) -> float:
            settings = CameraSettings(exposure_ms=ms, gain=None, white_balance_k=None, raw=False, linear_gamma=False)
            # an exposure read back other than asked is the time the fit takes (as_reported says it), not a refusal
            lines = apply_settings(cap, settings)
            refused.update(dict.fromkeys(line for line in lines if not line.startswith("exposure:")))
            return reported_exposure_ms(cap, ms)

        # every frame kept once the board answered after it; one a reset may have darkened taken again
        watch = BracketWatch(source, controller, set_exposure, say)
        lit = np.zeros((controller.n_leds, 3), np.uint8)
        lit[args.led - 1] = args.level
        asked = _backend_exposures(args.camera, cap.getBackendName(), exposures)
        frames, taken = take_bracket(watch, functools.partial(watch.set_colours, lit), watch.set_exposure, asked)
        frames, exposures = as_reported(str(args.camera), asked, taken, frames)
        check_exposures(exposures, f"camera {args.camera}")
        lights_off = functools.partial(watch.set_colours, np.zeros_like(lit))
        dark = take_dark(watch, lights_off, watch.set_exposure, min(exposures))
        bits = source.bit_depth
        codes = [to_codes(f, bits, args.black_level) for f in frames]
        at = pair_exposure(codes, exposures)
        n_leds = controller.n_leds
        taken = take_additivity(watch, watch.set_colours, watch.set_exposure, n_leds, args.led, args.level, at)
        fresh = [line for line in refused if line not in source.refused]  # said when the camera opened
        if fresh:
            report_refusals(args.camera, ["; ".join(fresh)])
        taken_whole = True
    dark = (to_codes(dark, bits, args.black_level), min(exposures), dn_per_code(bits, args.black_level))
    shots = additivity_codes(taken, at, bits, args.black_level)
    return codes, exposures, f"camera {args.camera}", f"camera {args.camera}", args.black_level, dark, shots


@contextlib.contextmanager
def _reset_after_the_bracket(port: str, taken_whole: Callable[[], bool]) -> Iterator[None]:
    """A board reset found by the LEDs' OFF as the bracket closes (``lights_out_on_exit``), once ``taken_whole()``:
    said in one warning, and the curve fitted and written, exit 0. One before that goes on (the bracket's own line
    when a reset cut short every attempt at a frame, ``device.bracket_watch``), with :data:`STOPPED`.

    Why a warning: every frame was kept only once the board answered a ``STATE`` after it was read, and the LEDs
    were switched off (acknowledged) after the last one, so the reset darkened no frame; it ended with the driver's
    "... retake any frame captured since the previous command", exit 2, nothing written, until s40."""
    from ..device.errors import BROWN_OUT_ADVICE, UNPLUGGED_REASON, BoardResetError

    try:
        yield
    except BoardResetError as exc:
        if not taken_whole():
            raise BoardResetError(f"{exc}; {STOPPED}", exc.reason) from None
        cable = ", or its USB cable is loose" if exc.reason == UNPLUGGED_REASON else ""
        import logging

        logging.getLogger(__name__).warning(
            "%s: the LED board reset after the bracket's last frame (%s; found as the LEDs were switched off at the "
            "end): each frame was kept once the board answered after it was read, so none was taken with the LEDs "
            "dark and the curve is fitted from them all; the LEDs are off. %s%s",
            port,
            exc.reason,
            BROWN_OUT_ADVICE[0].upper() + BROWN_OUT_ADVICE[1:],
            cable,
        )


def _backend_exposures(camera: str, backend: str, exposures: Sequence[float]) -> tuple[float, ...]:
    """The exposures the camera's backend can be asked (V4L2: whole 100 us steps; DirectShow, Media Foundation: whole
    log2-second steps), each once, said in one line when two fall on one step or one moves by more than
    :data:`~nlipscalib.core.tolerances.CAMERA_SETTING_RTOL`: the fit must use the times the camera took, and two
    exposures asked as one step are one frame twice, which would bend the curve."""
    import math

    from ..core.tolerances import CAMERA_SETTING_RTOL
    from ..device.camera import backend_exposure_ms
    from ..device.response_fit import check_exposures

    steps = [backend_exposure_ms(ms, backend) for ms in exposures]
    taken = tuple(dict.fromkeys(steps))
    moved = any(not math.isclose(a, t, rel_tol=CAMERA_SETTING_RTOL) for a, t in zip(exposures, steps, strict=True))
    if len(taken) < len(exposures) or moved:
        unit = "powers of two seconds" if backend in ("DSHOW", "MSMF") else "whole 100 us steps"
        merged = len(exposures) - len(taken)
        print(
            f"camera {camera} ({backend}) takes exposures in {unit}: the bracket is "
            f"{', '.join(f'{t:g}' for t in taken)} ms"
            + (f" ({merged} of the {len(exposures)} asked fall on a step already taken)" if merged else ""),
            file=sys.stderr,
        )
    check_exposures(taken, f"camera {camera} ({backend})")
    return taken


def _folder_bracket(args: argparse.Namespace):
    """The frames of ``--bracket FOLDER`` as 8-bit codes above ``--black-level``, their exposures (ms), the source
    named in refusals, the folder's dark frame (:data:`DarkFrame`; None when it has none) and its LEDs lit apart and
    together (``device.bracket_folder.read_pair_frames`` as ``AdditivityFrames``; None when it has none: said in one
    line)."""
    from ..core.errors import CaptureError, ConfigError
    from ..device.additivity import AdditivityFrames
    from ..device.bracket_folder import PAIRS_FOLDER, read_bracket_folder, read_pair_frames
    from ..device.response_fit import check_exposures

    if args.exposures_ms is not None:
        raise ConfigError("--exposures-ms is not used with --bracket: each image's exposure is in its name or CSV")
    stored, exposures, bits, dark = read_bracket_folder(args.bracket)
    source = f"--bracket {args.bracket}"
    check_exposures(exposures, source)
    _check_scaled(stored, bits, source)
    if dark is not None:
        dark = (to_codes(dark[0], bits, args.black_level), dark[1], dn_per_code(bits, args.black_level))
    pairs = read_pair_frames(args.bracket)
    shots = None
    if pairs is not None:
        frames, ms = pairs
        if frames["dark"].shape != stored[0].shape:
            raise CaptureError(f"{source}: its {PAIRS_FOLDER}/ images are not the bracket's size: one camera setting")
        codes = {k: to_codes(f, bits, args.black_level) for k, f in frames.items()}
        singles = {k: f for k, f in codes.items() if isinstance(k, int)}
        together = tuple((*k, f) for k, f in codes.items() if isinstance(k, tuple))
        shots = AdditivityFrames(ms, codes["dark"], singles, together)
    codes = [to_codes(f, bits, args.black_level) for f in stored]
    return codes, exposures, source, args.black_level, dark, shots


UNSCALED_TOP = 1 << 12
"""A 16-bit bracket whose values all stay below this holds a camera's 12 (or fewer) bits unscaled."""


def _check_scaled(stored: list, bits: int, source: str) -> None:
    """CaptureError when 16-bit images hold a 10- or 12-bit camera's values as they are, not scaled to 16 bits
    (``DN << 4``): their light would read 16 times dimmer, and the bracket be refused as never reaching white."""
    from ..core.errors import CaptureError

    top = max(int(frame.max()) for frame in stored)
    if bits == 16 and top < UNSCALED_TOP:
        raise CaptureError(
            f"{source}: its 16-bit images reach {top} of 65535 at most, in every exposure: a 10- or 12-bit camera's "
            "values stored unscaled? scale them to 16 bits (a 12-bit camera's times 16) or save them as the camera "
            "gives them to OpenCV"
        )


def _check_led(led: int, n_leds: int) -> None:
    from ..core.errors import ConfigError

    if not 1 <= led <= n_leds:
        raise ConfigError(f"--led {led}: the sensor has LEDs 1..{n_leds}")


def _fit_and_write(
    args: argparse.Namespace,
    frames: list,
    exposures: Sequence[float],
    source: str,
    camera: str,
    black_dn: float,
    dark: DarkFrame | None,
    shots: AdditivityFrames | None,
) -> int:
    from .. import __version__
    from ..core.response_curve import MeasuredResponse, write_response_file
    from ..device.response_fit import check_black, fit_response
    from ..progress import print_result, say
    from ..report.camera_response import response_figure

    dark_code = None if dark is None else check_black(dark[0], dark[1], source, black_dn, dark[2])
    if args.bracket and shots is None:  # nothing checks the curve: fitted at the times its frames say
        estimate = _estimated(frames, exposures, source)
        fit = fit_response(frames, estimate.estimated_ms if estimate.used else exposures, source)
        fit, additivity = _pinned(fit, shots, source, args.bracket)
    else:
        estimate, fit, additivity = _fitted_or_estimated(frames, exposures, source, shots, args.bracket)
    own = fit.kept.ndim == 2
    date = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    provenance = {
        "camera": camera,
        "date": date,
        "exposures_ms": [float(e) for e in exposures],
        "led": None if args.bracket else args.led,  # a bracket already taken: the lab's, not recorded
        "level": None if args.bracket else args.level,
        "black_level_dn": float(black_dn),
        "method": "OpenCV CalibrateRobertson, " + ("a curve per channel" if own else "channels' mean"),
        "codes_seen": list(fit.seen),
        "fit_residual": round(fit.residual, 6),
        "channel_spread": round(fit.channel_spread, 6),
        "channel_difference": round(fit.channel_difference, 6),
        "per_channel": own,
        "exposure_ratio_error": round(fit.ratio_error, 6),
        "dark_median_code": dark_code,
        "additivity": additivity,
        "exposures_estimated": None if estimate is None else _estimate_record(estimate),
        "monotonic": {"max_dip": round(fit.max_dip, 6), "flattened": fit.max_dip > 0},
        "software_version": __version__,
    }
    curve = tuple(tuple(float(v) for v in c) for c in fit.kept) if own else tuple(float(v) for v in fit.kept)
    response = MeasuredResponse(curve, provenance)
    out = write_response_file(args.out, response)
    figure = Path(args.figure) if args.figure else out.with_suffix(".png")
    note = (
        f"codes seen {fit.seen[0]}-{fit.seen[1]}; fit residual {fit.residual:.4f}; channels within "
        f"{fit.channel_spread:.4f} of full scale" + (": a curve per channel kept" if own else "")
    )
    response_figure(fit.kept, fit.channels, fit.points, figure, f"{camera} response, {date}", note)
    print_result(out)  # stdout: the response file alone (scripts); the fit and the next step on stderr
    say(
        f"{out}: {response.name} from {len(exposures)} exposures ({note}); figure {figure}. Capture with "
        f"`nlips capture --camera-response {out}`"
    )
    return 0


def _estimated(frames: list, exposures: Sequence[float], source: str, say: bool = True) -> TimesEstimate:
    """A --bracket folder's times estimated from its frames (``device.bracket_times``), for a folder without the
    LED pairs that would check the curve: said in one line (``say``; else :func:`_say_estimated` says it) when they
    differ from those named enough to be fitted at (a camera that rounds its exposures to steps of its own without
    a word)."""
    from ..device.bracket_times import estimate_times

    estimate = estimate_times(frames, exposures, source)
    if estimate.used and say:
        _say_estimated(estimate, source)
    return estimate


def _say_estimated(estimate: TimesEstimate, source: str) -> None:
    """The line of a fit at the times the frames say (:func:`_estimated`)."""
    moved = [
        f"{n:g} -> {e:.4g}"
        for n, e in sorted(zip(estimate.named_ms, estimate.estimated_ms, strict=True))
        if abs(e / n - 1) > SHOWN_MOVE
    ]
    print(
        f"{source}: its frames' light grows otherwise than the times named (a step {estimate.largest:.1%} off): "
        f"the camera took some exposures at times of its own (a shutter table: 1/60 s for 16 ms); the curve is "
        f"fitted at the times its frames say ({', '.join(moved)} ms, their steps' median ratio kept as named; "
        f"provenance.exposures_estimated)",
        file=sys.stderr,
    )


def _fitted_or_estimated(
    frames: list, exposures: Sequence[float], source: str, shots: AdditivityFrames | None, bracket: str | None
) -> tuple[TimesEstimate | None, ResponseFit, dict | None]:
    """(estimate or None, fit, additivity record) of a live or emulated camera's bracket, or of a --bracket folder
    with LEDs lit apart and together: fitted at the times named, and only when that fit is refused (the exposure
    ratios', or the LED pairs' check) at the times its frames say (:func:`_estimated`), when they differ enough
    from those named and that fit passes the same checks; else the first refusal stands.

    Why only then: the estimate fits the channels' mean, and an emulated camera whose channels' gammas differ
    (rgb-gammas) moved its times by it, a channel's curve 1.76 % off its gamma, over the 1.5 % its test allows (within
    it at the times named). Why at all: a camera that took some exposures at times of its own without a word (a
    shutter table: 16, 32, 64 ms taken as 1/60, 1/30, 1/15 s; 4 ms as 4.3) was refused, naming the times, with no
    way through but to find the times it takes (s35-leftovers)."""
    from ..core.errors import CaptureError
    from ..device.response_fit import fit_response

    try:
        fit = fit_response(frames, exposures, source)
        return (None, *_pinned(fit, shots, source, bracket))
    except CaptureError as refused:
        estimate = _estimated(frames, exposures, source, say=False)
        if not estimate.used:
            raise
        try:
            fit = fit_response(frames, estimate.estimated_ms, source)
            fit, additivity = _pinned(fit, shots, source, bracket)
        except CaptureError:
            raise refused from None
    _say_estimated(estimate, source)
    return estimate, fit, additivity


def _estimate_record(estimate: TimesEstimate) -> dict:
    """What the response file records of a --bracket folder's estimated times (docs/formats.md)."""
    return {
        "used": estimate.used,
        "times_ms": [round(t, 6) for t in estimate.estimated_ms],
        "step_errors": [None if e is None else round(e, 6) for e in estimate.step_errors],
        "largest_step_error": round(estimate.largest, 6),
        "rounds": estimate.rounds,
    }


def _pinned(
    fit: ResponseFit, shots: AdditivityFrames | None, source: str, bracket: str | None
) -> tuple[ResponseFit, dict | None]:
    """``fit`` checked by the LEDs lit apart and together (``device.additivity.pin_power``), its curves raised to
    the power that makes their light add when the curve as fitted does not (said in one line), and what the
    response file records of it (None for a --bracket folder without such frames: said in one line)."""
    import dataclasses

    import numpy as np

    from ..device.additivity import pin_power
    from ..device.bracket_folder import PAIRS_FOLDER

    if shots is None:
        if bracket is not None:
            print(
                f"{source}: no {PAIRS_FOLDER}/ subfolder of LEDs lit apart and together, so the curve's power is "
                "not checked (exposure times a power of those named would bend it unseen): add "
                f"{Path(bracket) / PAIRS_FOLDER}/ with dark.png, led_1.png, led_2.png, led_1+2.png (more pairs "
                "alike) at one exposure (docs/formats.md, Camera response file, in the nlipscalib source distribution)",
                file=sys.stderr,
            )
        return fit, None
    _, check = pin_power(np.broadcast_to(fit.kept, (3, len(fit.curve))), shots, source)
    if not np.isfinite(check.before):
        at = "" if shots.exposure_ms is None else f" at {shots.exposure_ms:g} ms"
        print(
            f"{source}: the frames of LEDs lit apart and together{at} have too few pixels "
            "neither black nor clipped that two LEDs light: the curve is not checked by light adding (a power of "
            "the exposure times would go unseen); kept as fitted",
            file=sys.stderr,
        )
        return fit, None
    record = {
        "exposure_ms": None if shots.exposure_ms is None else float(shots.exposure_ms),
        "pairs": [[a, b] for a, b, *_ in check.errors],
        "error": round(check.before, 6),
        "power": round(check.power, 6),
        "error_after": round(check.after, 6),
        "common": round(check.common, 6),
    }
    if check.power == 1.0:
        _say_common(check.common, source)
        return fit, record
    p = check.power
    print(
        f"{source}: with the curve as fitted, LEDs lit together give {1 + check.signed:.3f} times their light lit "
        f"apart; raised to the power {p:.3f} every pair adds within {check.after:.1%}: the camera's exposure times "
        f"are a power of the asked ones (t ** {p:.2f}), which a bracket alone cannot see; the curve is so raised",
        file=sys.stderr,
    )
    codes, linear = fit.points
    raised = dataclasses.replace(
        fit, curve=fit.curve**p, kept=fit.kept**p, channels=fit.channels**p, points=(codes, linear**p)
    )
    return raised, record


def _say_common(common: float, source: str) -> None:
    """One line when the LED pairs of a curve kept as fitted share a misfit (``common``, their median signed error)
    beyond :data:`~nlipscalib.core.tolerances.RESPONSE_ADDITIVITY_COMMON`: they dim (or brighten) each other as a
    whole by about a percent, which the curve, one LED's bracket, does not see, or the times are a power of the asked
    within 0.98-1.02 (benchmarks/RESULTS.md, s33-bracket)."""
    from ..core.tolerances import RESPONSE_ADDITIVITY_COMMON, RESPONSE_ADDITIVITY_ERROR

    if abs(common) <= RESPONSE_ADDITIVITY_COMMON:
        return
    print(
        f"{source}: with the curve as fitted, LEDs lit together give {1 + common:.3f} times their light lit apart "
        f"in every pair (the median; within the {RESPONSE_ADDITIVITY_ERROR:.1%} allowed, a right camera's within "
        f"{RESPONSE_ADDITIVITY_COMMON:.1%}): the LEDs {'dim' if common < 0 else 'brighten'} each other slightly when "
        "lit together (a shared supply), or the exposure times are a power of those asked within 0.98-1.02 (the "
        "curve then up to ~0.7% off); the curve is kept as fitted",
        file=sys.stderr,
    )
