"""Frame sources for capture: a live OpenCV camera, a folder of images, an image sequence, a video file.

Every source returns frames as the capture format stores them: (H, W, 3) uint16, RGB, linear values
``DN << (16 - bit_depth)`` (docs/formats.md). Photometric stereo needs frames whose brightness depends
on the LEDs only, so a live camera is opened with auto exposure, auto gain and auto white balance off
and fixed values set; every setting is read back and those the camera refused are listed in
``refused`` (a capture with auto exposure still on would be worthless, and the user must know).

After each LED change the session calls :meth:`FrameSource.capture`, which first drops the frames that
were exposed (or buffered) before the light changed (``flush_frames``), then averages ``average``
frames. File-backed sources hold exactly one recorded frame per exposure, so they never flush.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import logging
import math
import os
import re
from collections.abc import Collection, Iterator, Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import NUMBER, PATH, CaptureError, ConfigError, check_kind, require
from ..core.imageio import opencv_path, read_image
from ..core.sensor_response import eight_bit_table, undo_tone_curve
from ..core.tolerances import (
    CAMERA_SETTING_ABS,
    CAMERA_SETTING_RTOL,
    EXPOSURE_READBACK_RANGE,
    VIDEO_FRAME_COUNT_SLACK,
    VIDEO_FRAME_COUNT_SLACK_SHARE,
)

if TYPE_CHECKING:  # OpenCV is imported where it is used (``_cv2``): named for the hints only
    import cv2

log = logging.getLogger(__name__)


class EndOfFrames(CaptureError):
    """A recorded source (folder, image sequence, video) has no frame left: its end, not a fault."""


@dataclasses.dataclass(frozen=True)
class Recording:
    """What a recorded source (folder of frames, image sequence, video file) is, as a capture resumed on it knows it
    again (``device.recording_resume``)."""

    name: str
    """The folder, image-sequence pattern or video file as given (``--camera``), for messages."""
    path: str
    """The same, absolute."""
    frames: int | None
    """Frames it holds (a video: as its container declares; None: it declares none)."""
    first_frame: str
    """Digest of its first frame's stored values (:func:`frame_digest`): another recording at the same path (the
    rest of a session recorded into the folder again) differs in it, by its noise alone."""


def frame_digest(frame: np.ndarray) -> str:
    """16 hex digits of SHA-256 over a frame's values (``frame : (H, W, 3) uint16``): 3 ms at 640x480, once per
    recording opened."""
    return hashlib.sha256(np.ascontiguousarray(frame).tobytes()).hexdigest()[:16]


IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".pgm", ".ppm", ".jpg", ".jpeg", ".bmp")
"""Files a folder source reads, in name order."""


def _cv2():
    # FFmpeg prints its own parse errors ("moov atom not found") straight to stderr at OpenCV's default level,
    # before our one line naming the file; the level is read when OpenCV first loads its FFmpeg backend
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    return require("cv2", "opencv-python-headless", "Reading a camera")


@dataclasses.dataclass(frozen=True)
class CameraSettings:
    """How a live camera is set up for photometric stereo."""

    exposure_ms: float | None = 10.0
    """Fixed exposure time, ms (auto exposure is switched off); None keeps the camera's current value."""
    gain: float | None = 0.0
    """Fixed analogue gain in the camera's units (auto gain off); None keeps the camera's."""
    white_balance_k: float | None = 5000.0
    """Fixed white balance temperature, kelvin (auto white balance off); None keeps the camera's."""
    width: int | None = None
    """Requested frame width, pixels (None: the camera's default)."""
    height: int | None = None
    """Requested frame height, pixels."""
    buffer_size: int = 1
    """Driver frame buffers: the fewer, the fewer stale frames wait after an LED change."""
    flush_frames: int = 2
    """Frames dropped after each LED change: the buffered one and the one being exposed when it changed."""
    average: int = 1
    """Frames averaged per captured image (noise drops as 1/sqrt(average))."""
    raw: bool = True
    """Ask for the camera's unconverted frames (the highest bit depth it gives, e.g. 10/12/16-bit Y16)."""
    linear_gamma: bool = True
    """Ask for gamma 1.0 (``CAP_PROP_GAMMA`` :data:`UVC_LINEAR_GAMMA`) and report a camera that refuses it; False
    leaves the camera's gamma as it is (its tone curve declared instead: ``nlips capture --camera-response srgb``, or
    a curve measured by ``nlips calibrate-camera-response``: ``--camera-response FILE``)."""

    def __post_init__(self):
        whole = (int, np.integer)
        kinds = {name: (NUMBER, type(None)) for name in ("exposure_ms", "gain", "white_balance_k")}
        kinds |= {name: (*whole, type(None)) for name in ("width", "height")}
        kinds |= {name: whole for name in ("buffer_size", "flush_frames", "average")}
        for name, kind in kinds.items():  # "'>' not supported between 'str' and 'int'" named no setting
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, kind):
                raise ConfigError(f"camera settings: {name} must be a number, got {value!r}")
        for name in ("raw", "linear_gamma"):  # "no" was taken as True
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ConfigError(f"camera settings: {name} must be True or False, got {getattr(self, name)!r}")
        if self.buffer_size < 1 or self.flush_frames < 0 or self.average < 1:
            raise ConfigError(
                f"camera settings need buffer_size >= 1, flush_frames >= 0, average >= 1; got "
                f"{self.buffer_size}, {self.flush_frames}, {self.average}"
            )
        if self.exposure_ms is not None and not self.exposure_ms > 0:  # also NaN: it went to the driver as it was
            raise ConfigError(f"camera settings need exposure_ms > 0 (or None: the camera's), got {self.exposure_ms}")


class FrameSource:
    """Base of every frame source: ``read`` one frame, ``flush`` stale ones, ``capture`` one image."""

    bit_depth: int = 8
    """Bits per sample of the frames this source delivers."""
    flush_frames: int = 0
    """Frames dropped by :meth:`flush`."""
    average: int = 1
    """Frames averaged by :meth:`capture`."""
    refused: tuple[str, ...] = ()
    """Settings the camera did not accept, one readable line each."""
    gamma: float | None = None
    """The live camera's ``CAP_PROP_GAMMA`` after the settings (:func:`reported_gamma`); None for files and for a
    camera without the control."""
    tone_curve: np.ndarray | None = None
    """(65536,) uint16 table (65536, 3: per channel) of the camera's tone curve (``tone_curve_table``) undone on every
    frame as it is converted (:func:`to_stored`): frames linear in the light; None: frames as the camera encoded them
    (a capture's, whose loader undoes its declared curve)."""
    recording: Recording | None = None
    """What a recorded source is (a folder, image sequence or video file), for a capture resumed on it; None for a
    live camera, a stream URL and the emulated camera, whose frames go on in time whatever was read before."""

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the frames."""
        raise NotImplementedError

    @property
    def frames_consumed(self) -> int:
        """A recorded source's frames read or dropped so far: the index, from 0, of the frame the next read returns."""
        raise NotImplementedError(f"{type(self).__name__} is no recording")

    def skip_to(self, index: int) -> None:
        """Make the next read return a recorded source's frame ``index`` (from 0; forward or back);
        :class:`EndOfFrames` when it holds no such frame."""
        raise NotImplementedError(f"{type(self).__name__} is no recording")

    def read(self) -> np.ndarray:
        """The next frame: (H, W, 3) uint16, RGB, stored values ``DN << (16 - bit_depth)``."""
        raise NotImplementedError

    def flush(self) -> None:
        """Drop the frames exposed before the last LED change."""
        for _ in range(self.flush_frames):
            self.read()

    def capture(self) -> np.ndarray:
        """One image for the current LED state: flush, then the mean of ``average`` frames.

        Returns
        -------
        (H, W, 3) uint16, RGB, stored values
        """
        self.flush()
        if self.average == 1:
            return self.read()
        total = np.zeros(self.shape + (3,), np.float64)
        for _ in range(self.average):
            total += self.read()
        return np.rint(total / self.average).astype(np.uint16)

    def close(self) -> None:
        """Release the device or file."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def to_stored(frame: np.ndarray, name: str = "frame", tone_curve: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """A frame as OpenCV returns it (BGR or grey, 8 or 16 bit) -> ((H, W, 3) uint16 RGB stored, bit depth).

    16-bit frames are taken as already scaled to 16 bits (OpenCV's Y16 and 16-bit PNG); 8-bit ones are
    shifted up by 8 bits. ``tone_curve``: a (65536,) or per-channel (65536, 3) uint16 table
    (``core.sensor_response.tone_curve_table``) undone on the way, the frame returned then linear in the light;
    None: nothing undone (the values as the camera encoded them). Always a new array (never ``frame`` or a view of it).

    An 8-bit frame's shift and curve are one lookup of 256 entries (``core.sensor_response.eight_bit_table``,
    ``cv2.LUT``) on its uint8 values, bit for bit the 65536-entry table on the shifted ones; 0.3 ms a 640x480 frame
    against 0.9 for the shift alone (NumPy) and 2-4 with the curve (benchmarks/RESULTS.md, s29-lut8).
    """
    check_kind(frame, np.ndarray, "frame", "an image array as OpenCV gives it ((H, W) or (H, W, 3), 8 or 16 bit)")
    if frame.dtype not in (np.uint8, np.uint16):
        raise CaptureError(f"{name}: unsupported sample type {frame.dtype} (8- or 16-bit images only)")
    channels = 1 if frame.ndim == 2 else frame.shape[2] if frame.ndim == 3 and frame.shape[2] in (3, 4) else 0
    if not channels:  # (H, W, 1) too, as before: OpenCV gives grey as (H, W)
        raise CaptureError(f"{name}: unsupported image shape {frame.shape}")
    cv2 = _cv2()
    to_rgb = {1: cv2.COLOR_GRAY2RGB, 3: cv2.COLOR_BGR2RGB, 4: cv2.COLOR_BGRA2RGB}[channels]
    rgb = cv2.cvtColor(frame, to_rgb)  # a new contiguous array in either depth
    if frame.dtype == np.uint8:
        return cv2.LUT(rgb, eight_bit_table(tone_curve)), 8
    return undo_tone_curve(rgb, tone_curve), 16


class _ImageFiles(FrameSource):
    """Recorded frames, one image file each, in order: :meth:`read` the next, or :meth:`frame_at` any one.

    16-bit PNG/TIFF keep their bit depth (OpenCV's ``imread`` with ``IMREAD_UNCHANGED``). :meth:`frame_at`
    only reads its file, so several threads may decode frames at once (:class:`~nlipscalib.device.live.ReadAhead`
    does: OpenCV releases the GIL while it decodes).
    """

    files: Sequence[Path]
    """The frames' files, in order."""
    name: str
    """What error lines call the whole (the folder, or the pattern)."""

    def __init__(self, files: Sequence[Path], name: str, average: int = 1, tone_curve: np.ndarray | None = None):
        self.files, self.name = files, name
        self.tone_curve = tone_curve
        self.average = int(average)
        self.position = 0
        first, self.bit_depth = self._load(self.files[0])
        self._shape = first.shape[:2]
        self.recording = Recording(name, str(Path(name).resolve()), len(files), frame_digest(first))

    @property
    def shape(self) -> tuple[int, int]:
        return self._shape

    def _load(self, path: Path) -> tuple[np.ndarray, int]:
        frame = read_image(path)
        if frame is None:
            raise CaptureError(f"{path}: not a readable image")
        return to_stored(frame, str(path), self.tone_curve)

    def frame_at(self, index: int) -> np.ndarray:
        """Frame ``index`` (from 0): (H, W, 3) uint16, RGB, stored values; :class:`EndOfFrames` past the last one,
        CaptureError for a file that cannot be read or has another size."""
        if index >= len(self.files):
            raise EndOfFrames(f"{self.name}: ran out of images after {len(self.files)} frames")
        frame, _ = self._load(self.files[index])
        if frame.shape[:2] != self._shape:
            (h, w), (fh, fw) = frame.shape[:2], self._shape
            raise CaptureError(
                f"{self.files[index]}: image is {w}x{h}, the stream's first frame ({self.files[0].name}) is {fw}x{fh}"
            )
        return frame

    def read(self) -> np.ndarray:
        frame = self.frame_at(self.position)
        self.position += 1
        return frame

    @property
    def frames_consumed(self) -> int:
        return self.position

    def skip_to(self, index: int) -> None:
        if not 0 <= index < len(self.files):
            raise EndOfFrames(f"{self.name}: holds {len(self.files)} frames, no frame {index + 1}")
        self.position = index


class FolderSource(_ImageFiles):
    """Images of a folder in name order, one per :meth:`read` (a recorded capture, or a test fixture)."""

    def __init__(self, folder: str | Path, average: int = 1, tone_curve: np.ndarray | None = None):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise CaptureError(f"{self.folder}: image folder does not exist")
        files = sorted(p for p in self.folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise CaptureError(f"{self.folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in the folder")
        super().__init__(files, str(self.folder), average, tone_curve)


class SequenceSource(_ImageFiles):
    """An image sequence named by a printf pattern (``frames/img_%04d.png``), read as OpenCV's image-sequence
    reader does: from index 0, or 1 when there is no 0, up to the first index whose file is missing.

    Not through ``cv2.VideoCapture``: this source can decode several frames at once (:meth:`frame_at`).
    """

    def __init__(self, pattern: str, average: int = 1, tone_curve: np.ndarray | None = None):
        self.pattern = str(pattern)
        if not is_sequence_pattern(self.pattern):
            raise CaptureError(
                f"{self.pattern}: not an image-sequence pattern (one integer field such as %04d, and %% for a "
                "literal %) nor an existing file"
            )
        start = next((i for i in (0, 1) if Path(self._name(i)).is_file()), None)
        if start is None:
            raise CaptureError(f"{self.pattern}: no image of the sequence ({self._name(0)} nor {self._name(1)} exists)")
        count = 0
        while os.path.isfile(self._name(start + count)):
            count += 1
        super().__init__(NumberedFiles(self.pattern, start, count), self.pattern, average, tone_curve)

    def _name(self, index: int) -> str:
        return self.pattern % index


class NumberedFiles(Sequence):
    """The files of an image sequence, ``pattern % (start + i)`` for i < ``count``, each made when asked for.

    Why: the sequence's list held a Path per frame, 0.66 kB each with its name: ~50 MB of a stream's memory for a
    recording of 150,000 frames (an hour and a half at 30 frames/s; benchmarks/RESULTS.md, s29-soak), for names one
    line makes.
    """

    def __init__(self, pattern: str, start: int, count: int) -> None:
        self.pattern, self.start, self.count = pattern, start, count

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, index: int | slice) -> Path | list[Path]:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(self.count))]
        if index < 0:
            index += self.count
        if not 0 <= index < self.count:
            raise IndexError(index)
        return Path(self.pattern % (self.start + index))


def is_sequence_pattern(spec: str) -> bool:
    """Whether ``spec`` names an image sequence as OpenCV's reader takes one: exactly one integer field
    (``%d``, ``%04d``), ``%%`` for a literal ``%``, and no other conversion (``%s`` would repeat names)."""
    return re.fullmatch(r"[^%]*%0?\d*d[^%]*", spec.replace("%%", "")) is not None


class OpenCVSource(FrameSource):
    """A camera (index or device path) or a video file via ``cv2.VideoCapture``.

    For a live camera, ``settings`` are applied (auto modes off) and verified by reading them back; a
    file or sequence gets no settings and no flushing (each recorded frame is one exposure).
    """

    def __init__(
        self,
        device: int | str,
        settings: CameraSettings | None = None,
        reported: Collection[str] = (),
        tone_curve: np.ndarray | None = None,
    ):
        cv2 = _cv2()
        self.device = device
        self.tone_curve = tone_curve
        self.live = isinstance(device, int) or str(device).startswith("/dev/")
        if not self.live and "%" not in str(device) and not Path(device).exists():
            raise CaptureError(f"{device}: video file does not exist")
        with _quiet_opencv(cv2):  # its own warnings ("can't open camera by index") would come before our line
            self.cap = cv2.VideoCapture(device if isinstance(device, int) else opencv_path(device))
        if not self.cap.isOpened():
            raise CaptureError(_not_opened(device, self.live))
        settings = settings or CameraSettings()
        if self.live:
            self.refused = tuple(apply_settings(self.cap, settings))
            self.gamma = reported_gamma(self.cap)
            report_refusals(device, self.refused, reported)
            self.flush_frames = settings.flush_frames
            self.exposure_ms = settings.exposure_ms
            self.gain = settings.gain
        else:
            self.exposure_ms, self.gain = None, None
        self.declared_frames = None if self.live else declared_frame_count(self.cap)
        self.frames_read = 0
        self.average = settings.average
        try:
            frame = self._grab()
        except EndOfFrames:  # opened, yet not one frame: a file OpenCV took for a video or image but cannot decode
            raise CaptureError(_not_opened(device, self.live)) from None
        self._shape = frame.shape[:2]
        self._first = frame  # the probe frame is handed out first, so files lose nothing
        if not self.live and "://" not in str(device):  # a video file (a stream URL goes on in time, as a camera)
            self.recording = Recording(
                str(device), str(Path(device).resolve()), self.declared_frames, frame_digest(frame)
            )

    @property
    def shape(self) -> tuple[int, int]:
        return self._shape

    def _grab(self) -> np.ndarray:
        ok, frame = self.cap.read()
        if not ok or frame is None:
            if self.live:  # unplugged, or stopped: a fault, not the end of a recording
                raise CaptureError(f"camera {self.device}: no frame (the camera stopped)")
            if cut_short(self.frames_read, self.declared_frames):
                raise CaptureError(
                    f"{self.device}: the video ends after {self.frames_read} of the {self.declared_frames} frames "
                    "its container declares: truncated or damaged (a copy or recording cut short?)"
                )
            raise EndOfFrames(f"camera {self.device}: no frame (end of file)")
        if frame.ndim == 2 and frame.shape[0] == 1 and self.live:
            # unconverted YUYV/MJPEG frames come as a flat byte buffer: only 16-bit grey (Y16) raw frames
            # are images, so fall back to OpenCV's 8-bit conversion
            log.info("camera %s: raw frames are compressed; using 8-bit converted frames", self.device)
            self.cap.set(_cv2().CAP_PROP_CONVERT_RGB, 1)
            self.refused = tuple(r for r in self.refused if not r.startswith("raw")) + (
                "raw frames: the camera's raw format is compressed, 8-bit frames used",
            )
            return self._grab()
        out, self.bit_depth = to_stored(frame, f"camera {self.device}", self.tone_curve)
        self.frames_read += 1
        return out

    def read(self) -> np.ndarray:
        if self._first is not None:
            frame, self._first = self._first, None
            return frame
        return self._grab()

    @property
    def frames_consumed(self) -> int:
        if self.recording is None:
            raise NotImplementedError(f"camera {self.device} is no recording")
        return self.frames_read - (self._first is not None)  # a file is never flushed: each frame grabbed is read

    def skip_to(self, index: int) -> None:
        """The video positioned at frame ``index`` by reading from its start (back: rewound to frame 0 first):
        OpenCV's frame seek (``CAP_PROP_POS_FRAMES``) lands on a key frame near it with some codecs."""
        if index < self.frames_consumed:
            self.cap.set(_cv2().CAP_PROP_POS_FRAMES, 0)
            self.frames_read, self._first = 0, None
        if self._first is not None and index > self.frames_consumed:
            self._first = None
        while self.frames_read < index:
            if not self.cap.grab():  # grab without retrieve: skipped frames are never converted
                raise EndOfFrames(f"{self.device}: holds {self.frames_read} frames, no frame {index + 1}")
            self.frames_read += 1
        if self._first is None:
            try:
                self._first = self._grab()
            except EndOfFrames:
                raise EndOfFrames(f"{self.device}: holds {self.frames_read} frames, no frame {index + 1}") from None

    def flush(self) -> None:
        # grab() without retrieve(): the stale frames are dequeued but never decoded
        for _ in range(self.flush_frames):
            if not self.cap.grab():
                raise CaptureError(f"camera {self.device}: no frame while flushing (the camera stopped)")
            self._first = None  # the probe frame is stale too

    def close(self) -> None:
        self.cap.release()


def declared_frame_count(cap: cv2.VideoCapture) -> int | None:
    """The frame count a recorded video's container declares (None: it declares none, OpenCV's 0 or -1)."""
    count = cap.get(_cv2().CAP_PROP_FRAME_COUNT)
    return int(count) if math.isfinite(count) and count > 0 else None


def cut_short(frames_read: int, declared: int | None) -> bool:
    """Whether a recording that ended after ``frames_read`` frames is truncated: further short of the ``declared``
    count than an estimated count's error (:data:`nlipscalib.core.tolerances.VIDEO_FRAME_COUNT_SLACK`)."""
    if declared is None:
        return False
    slack = max(VIDEO_FRAME_COUNT_SLACK, VIDEO_FRAME_COUNT_SLACK_SHARE * declared)
    return declared - frames_read > slack


OPENCV_SILENT = 0
"""OpenCV's ``LOG_LEVEL_SILENT`` (``cv2.utils.logging``; the same number in 4.8's ``cv2.setLogLevel``)."""


@contextlib.contextmanager
def _quiet_opencv(cv2: ModuleType) -> Iterator[None]:
    """OpenCV's own log silent for the block: a failure is then reported once, by our line. With ``-v`` (this
    module's logger at DEBUG) OpenCV's lines are left on, for a camera that will not open.

    Why silent, not errors only: OpenCV 4.8 (the lowest supported) logs a missing camera index as an error of its
    own ("[ERROR:0@0.071] global obsensor_uvc_stream_channel.cpp:156 getStreamChannelGroup Camera index out of
    range", twice), printed before ours; newer ones log only warnings there."""
    if log.isEnabledFor(logging.DEBUG):
        yield
        return
    # opencv-python-headless 4.8 has no cv2.utils.logging, only cv2.getLogLevel/setLogLevel (the same levels)
    logging_ = getattr(getattr(cv2, "utils", None), "logging", None) or cv2
    level = logging_.getLogLevel()
    logging_.setLogLevel(OPENCV_SILENT)
    try:
        yield
    finally:
        logging_.setLogLevel(level)


def unreadable_file(path: int | str) -> str:
    """The one line for a file OpenCV cannot decode (``live``, ``capture``, and ``infer``'s own video check)."""
    return f"{path}: OpenCV cannot read it as video or images (another kind of file, damaged, or a missing codec)"


def _not_opened(device: int | str, live: bool) -> str:
    """Why OpenCV could not open ``device``: a file it cannot decode, or a camera; on Linux with the cameras
    present (``/dev/video*``)."""
    if not live:
        return unreadable_file(device)
    if not Path("/dev").is_dir():  # not Linux: OpenCV numbers the cameras itself
        return f"camera {device}: OpenCV could not open it (no such camera, unplugged, busy, or no permission)"
    video = sorted(Path("/dev").glob("video*"), key=lambda p: (len(p.name), p.name))
    present = f"cameras present: {', '.join(map(str, video))}" if video else "no camera is present (no /dev/video*)"
    path = Path(f"/dev/video{device}") if isinstance(device, int) else Path(device)
    if not path.exists():
        return f"camera {device}: no such camera ({path} does not exist); {present}"
    if not path.name.startswith("video"):
        return f"camera {device}: not a camera (cameras are /dev/videoN); {present}"
    return f"camera {device}: OpenCV could not open it (busy in another program, or no permission); {present}"


def exposure_to_backend(exposure_ms: float, backend: str) -> float:
    """OpenCV's CAP_PROP_EXPOSURE value for an exposure time: V4L2 counts whole 100 us steps (its control is an
    integer: 0.707 ms is asked as 7, 0.7 ms, not left to the driver to cut), DirectShow and Media Foundation take
    whole log2(seconds), other backends are passed milliseconds."""
    if backend == "V4L2":
        return float(max(1, math.floor(exposure_ms * 10.0 + 0.5)))  # half up: 0.25 ms asks 3, not 2
    if backend in ("DSHOW", "MSMF"):
        return float(round(math.log2(exposure_ms / 1000.0)))
    return exposure_ms


def exposure_from_backend(value: float, backend: str) -> float:
    """The exposure time, ms, of a CAP_PROP_EXPOSURE value in ``backend``'s units (:func:`exposure_to_backend`'s
    inverse); NaN for a value that is no time (V4L2 and the others: not > 0)."""
    if backend in ("DSHOW", "MSMF"):
        return 1000.0 * 2.0**value if math.isfinite(value) else math.nan
    ms = value / 10.0 if backend == "V4L2" else value
    return ms if ms > 0 and math.isfinite(ms) else math.nan


def backend_exposure_ms(exposure_ms: float, backend: str) -> float:
    """The exposure time, ms, that :func:`exposure_to_backend`'s value for ``exposure_ms`` stands for: DirectShow and
    Media Foundation take whole log2(seconds) steps, so 0.5 and 0.707 ms both ask 2**-11 s (0.488 ms); V4L2 whole
    100 us steps (0.707 ms asks 0.7); other backends the time asked."""
    return exposure_from_backend(exposure_to_backend(exposure_ms, backend), backend)


def reported_exposure_ms(cap: cv2.VideoCapture, asked_ms: float) -> float:
    """The exposure time, ms, the camera reads back after ``asked_ms`` was set: ``asked_ms`` itself when it reports
    none or one more than :data:`~nlipscalib.core.tolerances.EXPOSURE_READBACK_RANGE` times off (OpenCV's 0 or -1
    where a backend reads nothing back). Why: a camera with a shutter table of its own (1/60 s for 16 ms) or a
    minimum clamps the time it is asked and, through V4L2, reads back what it took: a bracket fitted at that time is
    right where one fitted at the asked time bends the curve (benchmarks/RESULTS.md, s32-devleft)."""
    backend = cap.getBackendName() if hasattr(cap, "getBackendName") else ""
    ms = exposure_from_backend(float(cap.get(_cv2().CAP_PROP_EXPOSURE)), backend)
    if not math.isfinite(ms) or not 1 / EXPOSURE_READBACK_RANGE <= ms / asked_ms <= EXPOSURE_READBACK_RANGE:
        return asked_ms
    return ms


UVC_LINEAR_GAMMA = 100
"""``CAP_PROP_GAMMA`` asked for a linear response: the UVC gamma control counts hundredths (100 = gamma 1.0), as
V4L2 and DirectShow pass it through; its range and default are the camera's (often 100-500, default 100-300), and
a backend with other units reports a refusal, which is what a lab must see (docs/formats.md, "Cameras")."""


NO_GAMMA_CONTROL = (
    "gamma 1.0: the camera has no gamma control, so its frames are taken as linear (if it applies a tone curve, "
    "declare --camera-response srgb; the capture's linearity check warns of a curve it sees)"
)
"""The refusal line of a camera without a gamma control (OpenCV reports 0 or -1): not "asked 100, camera reports
0", which read as a value the camera chose."""


def reported_gamma(cap: cv2.VideoCapture) -> float | None:
    """The camera's ``CAP_PROP_GAMMA`` as it reports it, None when it has none (OpenCV: 0 or -1): recorded with a
    capture (meta.json ``provenance.camera_gamma``), whether or not gamma was asked for."""
    value = float(cap.get(_cv2().CAP_PROP_GAMMA))
    return value if value > 0 else None


def apply_settings(cap: cv2.VideoCapture, settings: CameraSettings) -> list[str]:
    """Set a live camera up for photometric stereo; returns one line per setting it refused.

    Each property is set, then read back: a camera that ignores a property (or clamps it) is reported,
    not silently trusted.
    """
    cv2 = _cv2()
    backend = cap.getBackendName() if hasattr(cap, "getBackendName") else ""
    wanted: list[tuple[str, int, float]] = [("buffer size", cv2.CAP_PROP_BUFFERSIZE, settings.buffer_size)]
    if settings.raw:
        wanted.append(("raw frames (no RGB conversion)", cv2.CAP_PROP_CONVERT_RGB, 0))
    if settings.width:
        wanted.append(("frame width", cv2.CAP_PROP_FRAME_WIDTH, settings.width))
    if settings.height:
        wanted.append(("frame height", cv2.CAP_PROP_FRAME_HEIGHT, settings.height))
    if settings.exposure_ms is not None:
        # V4L2 manual exposure is 1 (V4L2_EXPOSURE_MANUAL); OpenCV's older mapping used 0.25
        manual = 1 if backend == "V4L2" else 0.25
        wanted.append(("auto exposure off", cv2.CAP_PROP_AUTO_EXPOSURE, manual))
        wanted.append(("exposure", cv2.CAP_PROP_EXPOSURE, exposure_to_backend(settings.exposure_ms, backend)))
    if settings.gain is not None:
        if hasattr(cv2, "CAP_PROP_AUTO_GAIN"):  # pragma: no cover - newer OpenCV only
            wanted.append(("auto gain off", cv2.CAP_PROP_AUTO_GAIN, 0))
        wanted.append(("gain", cv2.CAP_PROP_GAIN, settings.gain))
    if settings.white_balance_k is not None:
        wanted.append(("auto white balance off", cv2.CAP_PROP_AUTO_WB, 0))
        wanted.append(("white balance", cv2.CAP_PROP_WB_TEMPERATURE, settings.white_balance_k))
    if settings.linear_gamma:
        wanted.append(("gamma 1.0 (linear; else declare --camera-response srgb)", cv2.CAP_PROP_GAMMA, UVC_LINEAR_GAMMA))
    refused = []
    for name, prop, value in wanted:
        accepted = cap.set(prop, value)
        got = cap.get(prop)
        if prop == cv2.CAP_PROP_GAMMA and not accepted and got <= 0:  # OpenCV's 0 or -1: no such control
            refused.append(NO_GAMMA_CONTROL)
        elif not accepted or not math.isclose(got, value, rel_tol=CAMERA_SETTING_RTOL, abs_tol=CAMERA_SETTING_ABS):
            refused.append(f"{name}: asked {value:g}, camera reports {got:g}")
    return refused


_REPORTED: set[tuple[str, str]] = set()
"""(camera, line) of each refusal this process has said (:func:`report_refusals`)."""


def report_refusals(device: int | str, refused: Collection[str], reported: Collection[str] = ()) -> None:
    """Warn of each setting ``device`` refused, once per camera and process, and not at all when in ``reported``
    (a resumed session's, said when it started and recorded in its captures).

    Why: a webcam without a gamma control said "camera refused: gamma 1.0 ..." at every capture of a session (twice:
    as this warning and as the capture's own line), though nothing about it could change between them."""
    for line in refused:
        key = (str(device), line)
        if line not in reported and key not in _REPORTED:
            log.warning("camera %s refused %s", device, line)
        _REPORTED.add(key)


def open_source(
    spec: str | int,
    settings: CameraSettings | None = None,
    reported: Collection[str] = (),
    tone_curve: np.ndarray | None = None,
) -> FrameSource:
    """Frame source from a command-line spec: a camera index ("0"), a device path, a folder, a video file
    or an image sequence pattern ("frames/img_%04d.png"). ``settings``: what a camera is asked for (exposure,
    gain, white balance, gamma; None: :class:`CameraSettings`' defaults), of which a folder or sequence uses
    ``average`` alone; ``reported``: refusals of a live camera not to be said
    again (:func:`report_refusals`); ``tone_curve``: undone on every frame (:attr:`FrameSource.tone_curve`)."""
    check_kind(spec, (int, *PATH), "spec", "a camera index (0), a device path, a folder of frames or a video file")
    check_kind(settings, (CameraSettings, type(None)), "settings", "a CameraSettings, or None (its defaults)")
    settings = settings or CameraSettings()
    if isinstance(spec, int) or str(spec).isdigit():
        return OpenCVSource(int(spec), settings, reported, tone_curve)
    if Path(spec).is_dir():
        return FolderSource(spec, average=settings.average, tone_curve=tone_curve)
    if "%" in str(spec) and "://" not in str(spec) and not str(spec).startswith("/dev/") and not Path(spec).exists():
        # a stream URL may hold %-escapes: OpenCV's
        return SequenceSource(spec, average=settings.average, tone_curve=tone_curve)
    return OpenCVSource(str(spec), settings, reported, tone_curve)
