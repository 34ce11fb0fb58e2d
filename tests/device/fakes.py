"""Small stand-ins for the LED controller and a camera, to test session logic without hardware."""

import numpy as np

from nlipscalib.device.camera import FrameSource

OPERATOR_LINES = ("Do not touch the sensor", "Press ", "Reference: ")
"""How the instructions to the person at the sensor (device.session.Operator) begin: `nlips capture` says them on
stderr (stdout holds the session's folder alone), among the errors a test reads there."""


def errors_only(err: str) -> list[str]:
    """The lines of ``err`` that are neither log lines nor the operator's instructions."""
    return [line for line in err.splitlines() if not line.startswith(("INFO ", "WARNING ", *OPERATOR_LINES))]


class FakeController:
    """Latches every command at once, like a board that acknowledges after latching."""

    def __init__(self, n_leds: int):
        self.n_leds = n_leds
        self.latched = np.zeros((n_leds, 3), np.uint8)
        self.commands = []

    def set_all(self, colors):
        colors = np.asarray(colors, np.uint8)
        assert colors.shape == (self.n_leds, 3)
        self.latched = colors.copy()
        self.commands.append("set_all")

    def show(self):
        self.commands.append("show")

    def off(self):
        self.latched[:] = 0
        self.commands.append("off")

    def state(self):
        return self.latched.copy()

    def close(self):
        self.commands.append("close")


class LitSource(FrameSource):
    """Frames = a fixed per-LED image stack weighted by the controller's latched colours; optional change later."""

    bit_depth = 16

    def __init__(self, controller, images, noise=0.0, seed=0):
        self.controller = controller
        self.images = np.asarray(images, np.float32)  # (L, H, W, 3), fraction of full scale
        self.noise = noise
        self.rng = np.random.default_rng(seed)
        self.reads = 0
        self.change_at = None  # (read count, new images)

    @property
    def shape(self):
        return self.images.shape[1:3]

    def read(self):
        if self.change_at is not None and self.reads >= self.change_at[0]:
            self.images, self.change_at = self.change_at[1], None
        self.reads += 1
        w = self.controller.latched.astype(np.float32) / 255
        x = np.einsum("lhwc,lc->hwc", self.images, w)
        x = x + self.noise * self.rng.standard_normal(x.shape)
        return np.clip(np.rint(x * 65000 + 256), 0, 65535).astype(np.uint16)


def flat_predictor(shape):
    """A pluggable `nlips live` predictor: facing-the-camera normals, depth = the frame's mean green value."""
    from nlipscalib.device.live import LiveResult

    def predict(frame):
        normals = np.zeros(tuple(shape) + (3,), np.float32)
        normals[..., 2] = -1.0
        depth = np.full(tuple(shape), frame[..., 1].mean() / 1000.0, np.float32)
        return LiveResult(normals, depth)

    return predict


def srgb_predictor(shape):
    """:func:`flat_predictor`, made for a camera's sRGB frames: it says so (``camera_response``), as a model file
    records its calibration's camera response."""
    return flat_predictor(shape)


srgb_predictor.camera_response = "srgb"


def gamma_predictor(shape):
    """:func:`flat_predictor` declaring a camera response the workbench does not know."""
    return flat_predictor(shape)


gamma_predictor.camera_response = "gamma 2.2"


def tuple_predictor(shape):
    """A broken `nlips live` predictor: its callable returns a tuple, not a LiveResult."""
    return lambda frame: (frame, frame)


def two_argument_predictor(shape):
    """A broken `nlips live` predictor: its callable wants two arguments, so the first frame's call fails."""
    return lambda frame, extra: None


def green_predictor(shape):
    """A pluggable `nlips live` predictor that shows its input: depth = the frame's green channel / 1000 per pixel
    (tests compare the saved depth maps to see what the camera saw)."""
    from nlipscalib.device.live import LiveResult

    def predict(frame):
        normals = np.zeros(tuple(shape) + (3,), np.float32)
        normals[..., 2] = -1.0
        return LiveResult(normals, frame[..., 1].astype(np.float32) / 1000.0)

    return predict


class PtyBoard:
    """A board on a pseudo-terminal that answers each host line with ``respond(seq, command)``'s bytes.

    For boards the virtual board cannot be: one whose replies fail their checksum, one that describes itself
    with bad fields, one that prints another firmware's text. ``url`` is the port to open; use as a context
    manager (the reader thread stops and the pty closes at its end).
    """

    def __init__(self, respond):
        import os
        import threading
        import tty

        self.respond = respond
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        self.url = os.ttyname(self.slave)
        self.lines = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self):
        import os
        import select

        buf = b""
        while not self._stop.is_set():
            ready, _, _ = select.select([self.master], [], [], 0.02)
            if not ready:
                continue
            try:
                buf += os.read(self.master, 4096)
            except OSError:
                return
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                if b">" not in line:
                    continue
                body = line[line.rindex(b">") + 1 :].split(b"*")[0].decode("ascii", "replace")
                seq, _, rest = body.partition(" ")
                self.lines.append(body)
                answer = self.respond(seq, rest.split(" ")[0])
                if answer:
                    os.write(self.master, answer)

    def close(self):
        import os

        self._stop.set()
        self._thread.join()
        os.close(self.master)
        os.close(self.slave)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def protocol_line(body: str, start: str = "<", crc: str | None = None) -> bytes:
    """One protocol line with ``body`` (its CRC unless ``crc`` gives four other hex digits)."""
    from nlipscalib.device import protocol as p

    return f"{start}{body}*{crc if crc is not None else format(p.crc16(body.encode()), '04x')}\n".encode()


def hello_then(other, payload: str = "fw=1.0.0 proto=1 leds=12 sid=0001"):
    """A ``respond`` for PtyBoard: HELLO answered with ``payload``, every other command with ``other(seq)``."""

    def respond(seq, command):
        if command == "HELLO":
            return protocol_line(f"{seq} OK {payload}")
        return other(seq)

    return respond


def skewed_emulated_camera(power: float = 1.0, droop: float = 1.0):
    """The emulator's camera class made to take ``0.5 (t / 0.5) ** power`` ms when asked ``t`` (a shutter table of
    another log base), and to see LEDs lit together at ``droop`` times their drive (a shared supply that sags): what
    the camera-response checks must catch (tests/device/test_response_fit.py, benchmarks/bench_response_gap.py)."""
    from nlipscalib import emulator

    class Camera(emulator.EmulatedCamera):
        def __init__(self, renders, latched, *args, **kwargs):
            def sagging():
                colours = np.asarray(latched(), dtype=np.float32)
                return colours * np.float32(droop) if colours.any(axis=1).sum() > 1 else colours

            super().__init__(renders, sagging, *args, **kwargs)

        @property
        def exposure_scale(self) -> float:
            return self._scale

        @exposure_scale.setter
        def exposure_scale(self, value: float) -> None:
            self._scale = 0.05 * (value / 0.05) ** power  # 10 ms is scale 1: 0.5 ms, 0.05, is where the two agree

    return Camera


SECOND_STREAM: dict = {}
""":func:`predictor_running_a_second_stream`'s command (``argv``, set by the test) and what it gave (``code``,
``err``)."""


def predictor_running_a_second_stream(shape):
    """:func:`flat_predictor` which, at its first frame, runs ``nlips SECOND_STREAM["argv"]...`` as a process of its
    own and waits for it: a second stream started while this one streams and saves."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    flat = flat_predictor(shape)

    def predict(frame):
        if "code" not in SECOND_STREAM:
            root = str(Path(__file__).resolve().parents[2])
            env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (root, os.environ.get("PYTHONPATH"))))}
            argv = [sys.executable, "-m", "nlipscalib", *SECOND_STREAM["argv"]]
            done = subprocess.run(argv, capture_output=True, text=True, env=env)
            SECOND_STREAM.update(code=done.returncode, err=done.stderr)
        return flat(frame)

    return predict
