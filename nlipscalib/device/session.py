"""Capture sessions on the real sensor: one press = a fixed LED sequence, many presses with prompts.

One press is captured as (docs/formats.md)::

    tri-colour   LED groups red / green / blue at once (the movement check's first frame)
    dark         all LEDs off
    LED 1 .. L   each LED alone in white
    tri-colour   again: compared with the first; a difference means the object moved, and the press is retaken

The tri-colour frame opens and closes the sequence because it is the one frame lit by every LED, so
any change of the surface shows in it (a dark frame would show none). The first one is stored.

A session writes ``reference/`` (the undeformed sensor, captured first, before anything touches the
gel) and ``press_0001/`` ... into its folder, each atomically with :func:`nlipscalib.core.write_press`;
run it again after an interruption and it continues with the first press not yet written.

The LED controller is anything with ``set_all(colors)``, ``off()`` and ``n_leds`` whose
calls return once the LEDs latched (:class:`nlipscalib.device.controller.LedController`); the frame
source is a :class:`nlipscalib.device.camera.FrameSource`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from ..core.atomic import clean_interrupted, write_json
from ..core.camera import Camera
from ..core.capture import write_press
from ..core.errors import CaptureError, ConfigError, require
from ..core.leds import Led, tricolor_colors
from ..core.press_folders import is_press_folder
from ..core.press_meta import REFERENCE_FOLDER, SOURCE_SENSOR, led_frame_name
from ..core.sensor_record import setting_differences
from ..core.sensor_response import SensorResponse, linearise
from ..core.surface_files import Reference
from ..core.tolerances import CAPTURE_CHECK_BLUR
from ..core.tricolor_check import captured_tricolor_note
from .controller import FIRMWARE_GUIDE

log = logging.getLogger(__name__)

REFERENCE_NAME = REFERENCE_FOLDER  # the name every folder of presses uses (core.capture)
"""Folder of the undeformed sensor's capture inside a session."""
SESSION_FILE = "session.json"
"""The session's description (camera, LEDs, settings), written when the session starts."""


class PressNotCaptured(CaptureError):
    """A session stopped at a folder it could not capture (the camera ran out of frames or stopped, the object kept
    moving, a reference with nothing usable): the cause's message. Raised by :func:`run_session` alone, so the command
    can add what the session kept and where a run again resumes, which it cannot for a refusal before any capture (a
    folder of another sensor's session)."""


def press_name(index: int) -> str:
    """Folder name of press ``index`` (1-based): press_0001."""
    return f"press_{index:04d}"


@dataclasses.dataclass(frozen=True)
class SessionConfig:
    """How a session captures."""

    presses: int = 10
    """Presses to capture after the reference."""
    white_level: int = 255
    """LED drive (0-255 per channel) of the single-LED white frames."""
    tricolor_level: int = 255
    """LED drive of the tri-colour frame: lower it when its channels, each summing a third of the LEDs,
    would saturate at the exposure chosen for single LEDs."""
    movement_threshold: float = 0.02
    """A pixel moved when the repeated tri-colour frame differs by more than this fraction of full scale
    (after the box blur of ``core.tolerances.CAPTURE_CHECK_BLUR``, which averages the sensor noise away)."""
    movement_area: float = 0.001
    """The press moved when more than this fraction of the pixels moved."""
    max_retakes: int = 3
    """Retakes of a press that moved before the session gives up."""

    def __post_init__(self):
        for name in ("white_level", "tricolor_level"):
            if not 1 <= getattr(self, name) <= 255:
                raise ConfigError(f"{name} must be 1..255, got {getattr(self, name)}")
        if self.presses < 0 or self.max_retakes < 0:
            raise ConfigError(f"presses and max_retakes must be >= 0, got {self.presses}, {self.max_retakes}")
        if not (self.movement_threshold > 0 and 0 <= self.movement_area < 1):
            raise ConfigError("movement_threshold must be > 0 and movement_area in [0, 1)")


@dataclasses.dataclass
class Rig:
    """The sensor as the session drives it."""

    controller: object
    """LED controller (``n_leds``, ``set_all``, ``off``)."""
    source: object
    """FrameSource (``capture``, ``shape``, ``bit_depth``)."""
    camera: Camera
    """Intrinsics and lens (from ``nlips calibrate-camera`` or the design)."""
    leds: tuple[Led, ...]
    """LEDs in the camera frame, LED 1 first (from the design or ``nlips calibrate-leds``)."""
    response: SensorResponse
    """How stored values relate to light (bit depth, black and white level, exposure, gain)."""
    reference: Reference | None = None
    """The undeformed surface (``core.dome.reference_surface`` of the design), written with every press."""
    provenance: dict = dataclasses.field(default_factory=dict)
    """Extra metadata for every press (device, firmware, camera settings, design)."""
    design: dict | None = None
    """The sensor design the reference was computed from (``dome``, ``camera``, ``leds`` as in a scene file),
    written into every press's meta.json: without it the solver's interreflection term cannot model the dome
    beyond the view (measured on one render: 0.53 -> 2.37 deg, LED calibration 1.8 -> 5.1 deg)."""
    source_name: str = "the camera"
    """What the frames come from, for messages (``camera 0``, a folder or video path)."""
    camera_origin: str = "its calibration"
    """Where ``camera`` comes from, for messages (``the camera calibration camera.json``, ``the design
    nlipstac's camera``)."""
    leds_origin: str = "the sensor description"
    """Where ``leds`` come from, for messages (``the design ring16.toml``, ``the LED file leds.json``)."""
    response_slope: Callable[[np.ndarray, np.ndarray], float | None] | None = None
    """The tone-curve check of the reference (``device.exposure.ResponseSlope``: how its LED frames grow with the
    light), wired in by the CLI from the solve's (``cli.capture_checks``); None: not judged, a reference's dark frame
    evenly above the black level is then named a black level to declare."""

    def check(self) -> None:
        """Raise CaptureError when the parts do not fit together."""
        n, wanted = int(self.controller.n_leds), len(self.leds)
        if n != wanted:
            # the count is fixed in the board (firmware build or Adalight's N): say both ways out
            raise CaptureError(
                f"the LED board has {n} LEDs but {self.leds_origin} has {wanted}: give the board firmware built for "
                f"{wanted} (`make NLEDS={wanted}`, {FIRMWARE_GUIDE}; stock Adalight: --adalight {wanted}), or "
                f"capture with the design (--design) and LED file (--leds) of its {n} LEDs"
            )
        if tuple(self.source.shape) != self.camera.shape:
            (h, w), (ch, cw) = self.source.shape, self.camera.shape
            raise CaptureError(
                f"{self.source_name} gives {w}x{h} frames but {self.camera_origin} is {cw}x{ch}: calibrate this "
                f"camera at {w}x{h} (`nlips calibrate-camera`, then --camera-calibration), or capture at {cw}x{ch}"
            )


class Operator:
    """The person at the sensor: told what to do before the reference, each press and each retake.

    ``interactive`` waits for Enter after each instruction; otherwise the instruction is only printed
    (scripts, tests, a robot pressing on its own schedule). Either way ``--log-file`` gets each instruction: these
    lines are the session's only word on a retake (a log line said it too, so the operator read it twice).
    """

    def __init__(self, interactive: bool = False, echo: Callable[[str], None] = print):
        self.interactive = interactive
        self.echo = echo

    def _say(self, text: str) -> None:
        with _above_the_bar():
            self._prompt(text)

    def _prompt(self, text: str) -> None:
        if self.interactive:
            from ..progress import ask, file_log

            file_log(logging.INFO, text)  # the prompt is on stderr, which --log-file gets no copy of
            try:
                ask(f"{text} [Enter] ")
            except EOFError:  # Ctrl-D or a closed stdin: stop like Ctrl-C, keeping what is captured
                raise KeyboardInterrupt from None
        else:
            self.echo(text)

    def reference(self) -> None:
        self._say("Do not touch the sensor: capturing the undeformed reference.")

    def press(self, index: int, total: int) -> None:
        self._say(f"Press {index}/{total}: press the object now, hold still.")

    def retake(self, index: int, reason: str) -> None:
        what = "Reference" if index == 0 else f"Press {index}"
        self._say(f"{what}: {reason}; hold still, retaking.")

    def release(self, index: int) -> None:
        with _above_the_bar():
            self.echo(f"Press {index} captured: release.")


def _above_the_bar() -> contextlib.AbstractContextManager:
    """Clear the session's progress bar (a terminal's) while the operator reads a line, then draw it again below.

    Why: the bar leaves the cursor at its end, so on a terminal each prompt was written onto the bar's line
    ("capture:  33%|####      | 1/3 [00:00<00:01, 1.56press/s]Press 1/2: press the object now, hold still.").
    No lock is held: the operator may take a long time to answer."""
    from ..progress import above_the_bars

    return above_the_bars(wait_for_lock=False)


def frame_sequence(n_leds: int, cfg: SessionConfig) -> list[tuple[str, np.ndarray]]:
    """The LED states of one press, in capture order.

    Returns
    -------
    list of (name, colors) with colors (n_leds, 3) uint8: "tricolor", "dark", "led_01" ..., "check"
    """
    tri = (tricolor_colors(n_leds) * cfg.tricolor_level).astype(np.uint8)
    seq = [("tricolor", tri), ("dark", np.zeros((n_leds, 3), np.uint8))]
    for i in range(n_leds):
        colors = np.zeros((n_leds, 3), np.uint8)
        colors[i] = cfg.white_level
        seq.append((led_frame_name(i), colors))
    seq.append(("check", tri))
    return seq


def capture_frames(rig: Rig, cfg: SessionConfig) -> dict[str, np.ndarray]:
    """Light each state of :func:`frame_sequence` and capture it; LEDs off afterwards.

    When the sequence fails (the board unplugged or silent, a camera error, Ctrl-C), the LEDs are switched
    off best effort (:func:`nlipscalib.device.lights_out.off_quietly`: one short try, its failure
    suppressed), so the error reported is the one that stopped the sequence, not the clean-up's.

    Returns
    -------
    dict name -> (H, W, 3) uint16 stored image
    """
    from .lights_out import off_quietly

    frames = {}
    try:
        for name, colors in frame_sequence(len(rig.leds), cfg):
            rig.controller.set_all(colors)  # returns once the LEDs latched
            frames[name] = rig.source.capture()
    except BaseException:
        off_quietly(rig.controller)
        raise
    rig.controller.off()
    return frames


def change_map(first: np.ndarray, last: np.ndarray, response: SensorResponse) -> np.ndarray:
    """How much each pixel changed between two frames of the same LED state, noise smoothed away.

    Parameters
    ----------
    first, last : (H, W, 3) uint16, stored values of the same LED state

    Returns
    -------
    (H, W) float32 map of the box-blurred (:data:`~nlipscalib.core.tolerances.CAPTURE_CHECK_BLUR`) largest channel
    difference, fraction of full scale
    """
    cv2 = require("cv2", "opencv-python-headless", "The movement check")
    # a difference of two linear frames: the dark frame cancels, so ``first`` takes its place
    diff = np.abs(linearise(last, first, response.black_level, response.white_level))
    return cv2.blur(diff, (CAPTURE_CHECK_BLUR, CAPTURE_CHECK_BLUR)).max(axis=2)


def movement(frames: dict[str, np.ndarray], response: SensorResponse, cfg: SessionConfig) -> float:
    """Fraction of pixels that changed between the first and the repeated tri-colour frame."""
    return float((change_map(frames["tricolor"], frames["check"], response) > cfg.movement_threshold).mean())


def capture_press(
    rig: Rig, folder: str | Path, cfg: SessionConfig, operator: Operator, index: int = 0, overwrite: bool = False
) -> dict:
    """Capture one press (retaking it while it moves), check its exposure and write it atomically.

    Exposure (:func:`nlipscalib.device.exposure.check_exposure`): black LED frames and a large saturated share
    are warned about (log lines naming the files); a reference (``index`` 0) with nothing usable, wholly black
    or saturated, raises CaptureError and is not written. A tri-colour frame that does not hold the LED frames'
    light (two LEDs of different colour groups wired in each other's place:
    :func:`nlipscalib.core.tricolor_check.captured_tricolor_note`) is one warning naming the press and the LEDs.

    A recorded camera's frames read by every attempt are recorded in ``provenance.recording``
    (:mod:`nlipscalib.device.recording_resume`).

    Returns
    -------
    dict with ``folder``, ``attempts``, ``moved`` (fraction of moved pixels per attempt; None for an attempt
    cut short by a reset of the LED board), ``seconds``
    """
    from ..core.repeated_frames import model_light
    from .errors import BoardResetError
    from .exposure import check_exposure
    from .recording_resume import read_record, recorded

    start = rig.source.frames_consumed if recorded(rig.source) else None
    moved = []
    for attempt in range(cfg.max_retakes + 1):
        t0 = time.perf_counter()
        try:
            frames = capture_frames(rig, cfg)
        except BoardResetError as exc:
            # the LEDs went dark for a while: frames since the last command may be wrong, so retake all
            if attempt == cfg.max_retakes:
                raise _reset_every_attempt(rig, folder, attempt + 1, exc) from None
            # said once to the operator (the controller logged the reset and its cause): not a third time here
            log.debug("%s: %s", folder, exc)
            moved.append(None)
            operator.retake(index, "the LED board reset")
            continue
        seconds = time.perf_counter() - t0
        moved.append(movement(frames, rig.response, cfg))
        if moved[-1] <= cfg.movement_area:
            break
        if attempt == cfg.max_retakes:
            raise CaptureError(
                f"{folder}: the object kept moving ({moved[-1]:.2%} of the pixels changed in the last of "
                f"{attempt + 1} attempts); hold it still, or raise the pixel change counted as movement "
                f"(`nlips capture --movement-threshold`, SessionConfig.movement_threshold: {cfg.movement_threshold:g})"
            )
        operator.retake(index, f"the object moved ({moved[-1]:.2%} of the pixels changed)")
    provenance = dict(rig.provenance) | {
        "source": SOURCE_SENSOR,
        "captured_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "attempts": len(moved),
        "moved_fraction": moved,
        "capture_seconds": round(seconds, 4),
        "white_level": cfg.white_level,
        "tricolor_level": cfg.tricolor_level,
    }
    if start is not None:
        provenance |= read_record(rig.source, start)
    gel = None if rig.reference is None else np.isfinite(rig.reference.depth)
    expected = (
        None if rig.reference is None else model_light(rig.reference.depth, rig.reference.normals, rig.camera, rig.leds)
    )
    checked = check_exposure(
        frames, rig.response, folder, gel, reference=index == 0, expected=expected, response_slope=rig.response_slope
    )
    # the LED wiring across the tri-colour groups, said before more presses are taken with it (~ms: frames in memory)
    crossed = captured_tricolor_note(folder, frames, rig.camera, rig.leds, rig.response, rig.reference)
    for line in [*checked, *([crossed] if crossed else [])]:
        log.warning("%s", line)
    leds = np.stack([frames[led_frame_name(i)] for i in range(len(rig.leds))])
    write_press(
        folder,
        rig.camera,
        rig.leds,
        rig.response,
        frames["dark"],
        leds,
        frames["tricolor"],
        provenance=provenance,
        reference=rig.reference,
        overwrite=overwrite,
        design=rig.design,
    )
    return {"folder": str(folder), "attempts": len(moved), "moved": moved, "seconds": seconds}


def _reset_every_attempt(rig: Rig, folder: str | Path, attempts: int, exc: Exception) -> Exception:
    """The error of a press whose every attempt the LED board's reset cut short: its likely cause, and that nothing
    of the press was written.

    Why: it ended with the driver's "... restored to the last acknowledged colours; retake any frame captured since
    the previous command", advice to a caller of the driver, after the capture had retaken the press (s37 device
    reset walk: the firmware in simavr reset at each attempt)."""
    from .errors import BROWN_OUT_ADVICE, UNPLUGGED_REASON, BoardResetError

    port = getattr(rig.controller, "url", "the LED board")
    reason = getattr(exc, "reason", "")
    cable = ", or its USB cable is loose" if reason == UNPLUGGED_REASON else ""
    return BoardResetError(
        f"{port}: the LED board reset during each of the {attempts} attempts at {Path(folder).name} "
        f"({reason or exc}), so it was not written: {BROWN_OUT_ADVICE}{cable}",
        reason,
    )


def reset_after_the_session(port: str, exc: Exception, folders: int) -> str:
    """What a session says of a board reset found by the LEDs' OFF as it closed, after its last folder was written
    (``exc``, the BoardResetError; ``folders``, the session's folders, kept or captured): that it darkened no frame,
    so everything is kept, that the LEDs are off, and the likely cause.

    Why none is at risk: every press ends with an OFF (:func:`capture_frames`) that the board acknowledged after the
    last frame was read, and a rebooted board answers no command but HELLO (``E7 NOSESSION``, docs/protocol.md), so a
    reset before that acknowledgement is found there and the press retaken."""
    from .errors import BROWN_OUT_ADVICE, UNPLUGGED_REASON

    reason = getattr(exc, "reason", "") or str(exc)
    cable = ", or its USB cable is loose" if reason == UNPLUGGED_REASON else ""
    kept = f"all {folders} folders are kept" if folders != 1 else "its folder is kept"
    return (
        f"{port}: the LED board reset after the session's last press was captured ({reason}; found as the LEDs were "
        f"switched off at the end): every frame was read before that press's LEDs-off was acknowledged, so none was "
        f"taken with the LEDs dark and {kept}; the LEDs are off. {BROWN_OUT_ADVICE[0].upper()}{BROWN_OUT_ADVICE[1:]}"
        f"{cable}"
    )


def run_session(
    rig: Rig, out: str | Path, cfg: SessionConfig, operator: Operator | None = None, progress: bool = False
) -> dict[str, dict | str]:
    """Capture the reference, then ``cfg.presses`` presses, into ``out``; resumes where a previous run stopped.

    Returns
    -------
    dict folder name -> the :func:`capture_press` record, or "kept" for folders already complete
    """
    from ..progress import track

    rig.check()
    operator = operator or Operator()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    clean_interrupted(out)
    _check_same_session(out, rig, cfg)
    names = [REFERENCE_NAME] + [press_name(k) for k in range(1, cfg.presses + 1)]
    if set(names) - set(captured_folders(out, cfg.presses)) and (line := made_otherwise_line(out, rig)):
        log.warning("%s", line)  # only when a folder is to be captured: a session kept whole mixes nothing
    status: dict[str, dict | str] = {}
    # the project's bar: drawn by its own helper (an interrupt cannot leave it open), only where a person sees it
    for k, name in enumerate(track(names, enabled=progress, desc="capture", unit="press")):
        folder = out / name
        damaged = is_press_folder(folder) and _damaged(folder)
        if is_press_folder(folder) and not damaged:
            status[name] = "kept"
            continue
        if damaged:
            log.warning("%s: %s; capturing it again", folder, damaged)
        try:
            _continue_recording(rig, out, names[:k], name)
            if k == 0:
                operator.reference()
            else:
                operator.press(k, cfg.presses)
            status[name] = capture_press(rig, folder, cfg, operator, index=k, overwrite=bool(damaged))
        except CaptureError as exc:  # the camera ran out of frames or stopped, the object kept moving, ...
            raise PressNotCaptured(str(exc)) from exc
        if k > 0:
            operator.release(k)
    return status


def _continue_recording(rig: Rig, out: Path, before: list[str], name: str) -> None:
    """A recorded camera (``--camera FOLDER`` or a video) made to give folder ``name`` of the session ``out`` its
    frames: after those the whole folder before it (of the names ``before``) read, when it read the same recording
    (:func:`nlipscalib.device.recording_resume.continue_recording`); a warning when it starts anew. A live camera:
    nothing.

    Why: a resumed capture read the recording from its first frame again, so the next press took the reference's
    frames (until 2026-12-07)."""
    from .recording_resume import continue_recording, recorded

    if not recorded(rig.source):
        return
    whole = (out / n for n in reversed(before) if is_press_folder(out / n) and not _damaged(out / n))
    if line := continue_recording(rig.source, next(whole, None), name):
        log.warning("%s", line)


def check_resumable(rig: Rig, out: str | Path, cfg: SessionConfig) -> None:
    """Refuse now, as :func:`run_session` would, a folder ``out`` this session cannot be captured into (another
    sensor's or settings' presses, the twin's renders); nothing to check where ``out`` does not exist yet.

    Why: the emulated sensor renders its whole script before the session starts; a refusal then came after
    20 s of renders at 160x120 (minutes at full size) that were thrown away."""
    out = Path(out)
    if out.is_dir():
        rig.check()
        clean_interrupted(out)  # as run_session: a killed run's half-written folder is no press to compare
        _check_same_session(out, rig, cfg)


def captured_folders(out: str | Path, presses: int) -> list[str]:
    """The folders of the session ``out`` (its reference, then ``presses`` presses) captured whole so far, in
    capture order: what a session stopped part-way (Ctrl-C, SIGTERM) kept, and what a run again keeps. A folder
    whose files went missing counts as not captured, as :func:`run_session` captures it again."""
    names = [REFERENCE_NAME] + [press_name(k) for k in range(1, presses + 1)]
    return [name for name in names if is_press_folder(Path(out) / name) and not _damaged(Path(out) / name)]


MADE_BY = ("code", "libraries")
"""The keys of a rig's ``provenance`` naming what made its images beside the sensor: the emulated sensor's twin
code and render libraries (``sim.press.render_identity``), recorded in each press it captures; a device has none."""


def made_otherwise_line(out: str | Path, rig: Rig) -> str:
    """The warning when whole press folders in ``out`` were made by other twin code or render libraries than
    ``rig``'s (its ``provenance``'s :data:`MADE_BY`; the emulated sensor), or recorded none (emulated before
    2026-12-06); "" when they match or ``rig`` records none (a device: its images are the sensor's).

    Why: an emulated session resumed after an upgrade took today's render of a new press beside its old reference
    and presses, said nowhere (a session of before 2026-12-04 records no settings to compare), and ``nlips solve``
    pairs them. Kept, not refused, as ``nlips dataset`` keeps its renders: the user decides."""
    from ..core.press_meta import read_meta

    ours = {key: rig.provenance[key] for key in MADE_BY if key in rig.provenance}
    if not ours:
        return ""
    out, differs = Path(out), {}
    for folder in sorted((d for d in out.iterdir() if d.is_dir()), key=lambda d: (d.name != REFERENCE_NAME, d.name)):
        if is_press_folder(folder) and not _damaged(folder):
            provenance = read_meta(folder).get("provenance")
            theirs = {key: provenance.get(key) for key in MADE_BY} if isinstance(provenance, dict) else {}
            if any(theirs.get(key) != value for key, value in ours.items()):
                differs[folder.name] = theirs
    if not differs:
        return ""
    names = list(differs)
    said = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
    return (
        f"{out}: {said} {'was' if len(names) == 1 else 'were'} captured by the emulated sensor with other twin code "
        f"or render libraries ({_made_difference(differs[names[0]], ours)}); kept, so this session mixes their "
        "images with this run's: remove them to capture them again, or capture into a new --out folder"
    )


def _made_difference(was: dict, ours: dict) -> str:
    """What made a press otherwise than ``ours`` (:data:`MADE_BY` values), in words: "twin code unrecorded: ...",
    "other code of sim/ or core/", "mitsuba 3.5.0 (now 3.6.0)" (as ``nlips dataset`` says of its renders)."""
    if not was.get("code"):
        return "twin code unrecorded: an older nlipscalib captured it"
    said = ["other code of sim/ or core/"] if was.get("code") != ours.get("code") else []
    libraries = was.get("libraries") if isinstance(was.get("libraries"), dict) else {}
    now = ours.get("libraries") if isinstance(ours.get("libraries"), dict) else {}
    said += [f"{k} {libraries.get(k)} (now {v})" for k, v in now.items() if libraries.get(k) != v]
    return ", ".join(said)


@contextlib.contextmanager
def claim_session(out: str | Path) -> Iterator[None]:
    """Hold the session folder ``out`` for this capture while the block runs; a ConfigError, before anything is
    captured, while another live capture holds it.

    Why: two captures started into one folder (two terminals, the emulator and the sensor) each captured what
    the other had not published yet: the session mixed both runs' presses under one reference, and the run that
    lost a press's rename failed with "FOLDER/press_0002: already exists". The claim is ``out``'s hidden sibling
    (``.claim-NAME``, core.claims), so a capture refused or stopped before it captured leaves no folder. A killed
    capture's claim goes stale, so a run after it resumes. A folder that cannot hold a claim file (read-only
    media, disk full) is not held: nothing can be captured there either, and the write says why in its own words.
    """
    from ..core.claims import UNKNOWN_OWNER, claim, holder

    out = Path(out)
    target = out.resolve()  # "--out ." is named by the folder's own name in its parent
    with contextlib.ExitStack() as stack:
        try:
            held = stack.enter_context(claim(target))
        except OSError as exc:
            log.debug("%s: not claimed (%s)", out, exc.strerror or exc)
            held = True
        if not held:
            other = holder(target)
            raise ConfigError(
                f"{out}: another capture is writing this session ({(other or UNKNOWN_OWNER).who}); wait until it "
                "ends (then run again to resume it), or capture into another --out folder"
            )
        yield


def _damaged(folder: Path) -> str:
    """Why a captured press folder cannot be kept ("" when it is whole): files its meta.json lists are gone
    (deleted or lost since), empty or cut short (a power cut soon after it was captured), of another size than its
    checksums.json records (another image copied over one), or meta.json itself is unreadable."""
    from ..core.press_checksums import described_file_problems
    from ..core.press_folders import missing_capture_files

    try:
        missing = missing_capture_files(folder)
    except CaptureError as exc:  # meta.json cut short or emptied: "meta.json: not valid JSON", the folder said once
        return str(exc).removeprefix(f"{folder}: ").removeprefix(f"{folder}{os.sep}")
    return described_file_problems(missing)


def _check_same_session(out: Path, rig: Rig, cfg: SessionConfig) -> None:
    """Refuse to resume a session with another camera, LED count or capture settings (exposure, gain, LED
    levels, the design or emulated scene): its presses would mix two kinds of image, and a calibration would
    train on the mix. Records the session otherwise, and again while no folder is captured (a reference refused
    for its exposure is captured again at another one). A session.json from before the settings were recorded
    is checked on what it holds."""
    path = out / SESSION_FILE
    described = {"camera": rig.camera.to_dict(), "n_leds": len(rig.leds), "settings": _capture_settings(rig, cfg)}
    captured = any(is_press_folder(d) for d in out.iterdir() if d.is_dir())
    if path.exists() and captured:
        _check_session_record(path, described)
    if why := _rendered_by_the_twin(out):
        raise CaptureError(why)
    if why := _captured_by_another_sensor(out, rig):
        # session.json records no LED ring or dome, and may be absent (a folder of `nlips dataset`, or one removed
        # as an unreadable one's message says): each press's meta.json records the sensor it was captured with
        raise CaptureError(f"{why}; capture into a new --out folder")
    if not path.exists() or not captured:
        # nothing captured yet (a reference refused for its exposure, a run stopped before it): nothing to mix
        write_json(path, described | {"started": time.strftime("%Y-%m-%dT%H:%M:%S%z")})


def _check_session_record(path: Path, described: dict) -> None:
    """Refuse (CaptureError naming ``path``) a session.json of another camera, LED count or settings."""
    try:
        before = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(before, dict):
            raise ValueError(f"expected a JSON object, got {type(before).__name__}")
    except (OSError, ValueError) as exc:
        # the presses are whole (each has its own meta.json): only the session's record of its settings is lost
        raise CaptureError(
            f"{path}: unreadable session description ({exc}); to resume with the settings these presses were "
            f"captured with, remove or rename {SESSION_FILE} and run again, or capture into a new --out folder"
        ) from None
    was, now = _emulated_tone_curve(before), _emulated_tone_curve(described)
    if was != now:
        # named as the option: "settings (emulated_tone_curve: 'gamma2.2' -> None)" hid which option to give again
        raise CaptureError(
            f"{path}: this session's frames were encoded with --emulate-tone-curve {was} (this run: {now}); resume "
            f"it with {'no --emulate-tone-curve' if was == 'none' else f'--emulate-tone-curve {was}'}, or capture "
            "into a new folder"
        )
    if {k: before.get(k) for k in ("camera", "n_leds")} != {k: described[k] for k in ("camera", "n_leds")}:
        raise CaptureError(
            f"{path}: this session folder was captured with another camera or LED count "
            f"({_camera_difference(before, described)}); use a new folder"
        )
    if "settings" in before and (changes := setting_differences(*map(_lit_settings, (before, described)))):
        raise CaptureError(
            f"{path}: this session was captured with other settings ({changes[0]}); resume it with the same "
            "settings, or capture into a new folder"
        )


def _emulated_tone_curve(record: dict) -> str:
    """The tone curve a session record's emulated camera encoded its frames with (``settings.emulated_tone_curve``,
    ``nlips capture --emulate-tone-curve``), "none" for linear frames: a device's session, or one recorded before
    the emulator had tone curves (2026-12-06), whose frames were all linear."""
    settings = record.get("settings")
    curve = settings.get("emulated_tone_curve") if isinstance(settings, dict) else None
    return str(curve) if curve else "none"


def _lit_settings(record: dict) -> object:
    """A session record's ``settings`` without the emulated scene's fields that change no image
    (``core.sensor.UNRENDERED_DESIGN_KEYS``). Why: the shipped scenes declared their LEDs' emitting diameter in
    2026-12 (s29-ledsize); compared whole, every emulated session begun before then was refused on resume
    ("leds.emitter_diameter: None -> 3.6") for a field no render reads."""
    from ..core.sensor import rendered_scene

    settings = record.get("settings")
    if isinstance(settings, dict) and isinstance(settings.get("scene"), dict):
        return settings | {"scene": rendered_scene(settings["scene"])}
    return settings


def _camera_difference(before: dict, now: dict) -> str:
    """What differs between session.json's ``camera`` and ``n_leds`` and this run's ("image size 80x60, the
    session 160x120"): ``core.sensor_record.sensor_mismatch``'s words, or 'KEY: OLD -> NEW' for a record it
    cannot read."""
    from ..core.leds import tricolor_groups
    from ..core.sensor_record import sensor_mismatch

    def record(held: dict) -> dict:
        n = held.get("n_leds")
        return {"camera": held.get("camera"), "n_leds": n, "tricolor_groups": list(tricolor_groups(n))}

    try:
        why = sensor_mismatch(record(before), record(now), expected_as="the session")
    except (KeyError, TypeError, ValueError):
        why = None
    if why:
        return why
    changes = setting_differences(
        {k: before.get(k) for k in ("camera", "n_leds")}, {k: now[k] for k in ("camera", "n_leds")}
    )
    return ", ".join(changes[:2]) + (" and more" if len(changes) > 2 else "")


def _rendered_by_the_twin(out: Path) -> str | None:
    """Why ``out`` cannot hold this session, naming its first press folder rendered by the twin (meta.json
    ``provenance.source`` "sim": ``nlips render``, ``nlips dataset``), or None.

    Why: ``nlips capture --emulate nlipstac --out RENDERS`` into a folder of the twin's renders of the same sensor
    kept every render as "already captured" and wrote session.json around them, exit 0 (another sensor's renders
    were refused, as other presses); on a real sensor whose design the renders share, its reference and presses
    would have been the twin's images. A session holds only what it captured."""
    from ..core.press_meta import SOURCE_TWIN, press_source

    folders = sorted((d for d in out.iterdir() if d.is_dir()), key=lambda d: (d.name != REFERENCE_NAME, d.name))
    for folder in (d for d in folders if is_press_folder(d)):
        if press_source(folder) == SOURCE_TWIN:
            return (
                f"{folder}: a press rendered by the twin (nlips render or nlips dataset), not captured: a capture "
                "session keeps only the presses it captured; capture into a new --out folder"
            )
    return None


def _captured_by_another_sensor(out: Path, rig: Rig) -> str | None:
    """Why a whole press folder already in ``out`` is of another sensor than ``rig``'s, naming it, or None.

    Compares each folder's meta.json with the rig: camera, LED count, grouping and geometry
    (``core.sensor_record.sensor_mismatch``, the check of ``nlips solve --reference``), and the dome when both
    record one (a twin's or the emulator's scene, a device's design). Seen: ``nlips capture --emulate nlipstac``
    into a folder of fingertip presses from ``nlips dataset`` (no session.json) kept them, added nlipstac presses
    beside them and exited 0. Damaged folders are left out: they are captured again."""
    from ..core.press_meta import parse_optics, read_meta
    from ..core.sensor_record import describe_sensor, sensor_mismatch

    ours = describe_sensor(rig.camera, rig.leds)
    our_dome = _dome_of(rig.design, rig.provenance)
    folders = sorted((d for d in out.iterdir() if d.is_dir()), key=lambda d: (d.name != REFERENCE_NAME, d.name))
    for folder in (d for d in folders if is_press_folder(d) and not _damaged(d)):
        meta = read_meta(folder)
        camera, leds, _ = parse_optics(meta, folder / "meta.json")
        why = sensor_mismatch(describe_sensor(camera, leds), ours, expected_as=f"{folder.name} has")
        their_dome = _dome_of(meta.get("design"), meta.get("provenance"))
        if not why and isinstance(our_dome, dict) and isinstance(their_dome, dict):
            changes = setting_differences(their_dome, our_dome, "dome")
            why = f"{changes[0]}" if changes else None
        if why:
            return f"{folder}: captured with another sensor than the one capturing now ({why})"
    return None


def _dome_of(design: object, provenance: object) -> dict | None:
    """The dome a press or rig records: its design's (a device) or its scene's (the twin, the emulator)."""
    for holder in (design, (provenance or {}).get("scene") if isinstance(provenance, dict) else None):
        if isinstance(holder, dict) and isinstance(holder.get("dome"), dict):
            return holder["dome"]
    return None


def _capture_settings(rig: Rig, cfg: SessionConfig) -> dict:
    """What decides a session's images beside the camera: LED levels, exposure, gain, black level, and the
    design (a device) or the scene (the emulator: its render settings too). Not the port or the camera's
    device number: a board plugged into another socket takes the same images."""
    from ..core.reconstruction import jsonable

    prov = rig.provenance
    return jsonable(
        {
            "white_level": cfg.white_level,
            "tricolor_level": cfg.tricolor_level,
            "exposure_ms": rig.response.exposure_ms,
            "gain": rig.response.gain,
            "black_level": rig.response.black_level,
            "design": prov.get("design"),
            "scene": prov.get("scene"),
        }
        # a declared tone curve changes what the images mean; linear sessions keep the record they had before it
        | ({"camera_response": rig.response.camera_response} if rig.response.camera_response != "linear" else {})
        # the emulated camera's own curve changes its frames' values (recorded alike only when there is one)
        | ({"emulated_tone_curve": prov["tone_curve"]} if prov.get("tone_curve") else {})
    )
