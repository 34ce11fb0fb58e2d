"""A rolling-shutter camera whose readout an LED switch falls into: the first frame after the switch holds the
previous light above a row and the new light below it. `nlips capture` drops it by default (``--flush`` 2); with
no frame dropped the capture's check names the rows (s28-rolling)."""

import argparse

import numpy as np

from nlipscalib.cli import capture as capture_cli
from nlipscalib.core.repeated_frames import frame_lags, lagged_line
from nlipscalib.device.camera import CameraSettings, FrameSource


class RollingShutterCamera(FrameSource):
    """Frames of a gel lit by ``light[state]``; the first frame read after :meth:`switch` to a state in
    ``across`` was read out across the switch: its top ``rows_before`` rows show the previous state's light."""

    def __init__(self, light, rows_before, across, shape=(60, 80)):
        self.light, self.rows_before, self.across, self._shape = light, rows_before, across, shape
        self.state, self.previous, self.fresh = 0, 0, False

    @property
    def shape(self):
        return self._shape

    def switch(self, state):
        self.previous, self.state, self.fresh = self.state, state, state in self.across

    def read(self):
        frame = np.broadcast_to(self.light[self.state], self._shape + (3,)).astype(np.float32).copy()
        if self.fresh:  # the frame being read out when the LEDs switched
            frame[: self.rows_before] = self.light[self.previous][: self.rows_before]
            self.fresh = False
        return frame


def _lights():
    """(4, 60, 1, 1) light of four LEDs: each a different ramp down the rows (neighbours differ by ~10-40 %)."""
    rows = np.linspace(0.0, 1.0, 60)[:, None, None]
    return np.stack([0.3 + 0.1 * k + 0.2 * (rows if k % 2 else 1 - rows) for k in range(4)])


def _capture_all(camera):
    images = []
    for state in range(4):
        camera.switch(state)
        images.append(camera.capture())
    return np.stack(images)


def test_the_default_flush_drops_the_frame_read_across_the_led_switch():
    parser = argparse.ArgumentParser()
    capture_cli.register(parser.add_subparsers())
    flush = parser.parse_args(["capture", "--out", "unused"]).flush
    assert flush >= 1 and CameraSettings().flush_frames >= 1
    camera = RollingShutterCamera(_lights(), rows_before=25, across=(1, 2, 3))
    camera.flush_frames = flush
    images = _capture_all(camera)
    assert np.allclose(images[2], _lights()[2])  # LED 3's own light in every row
    assert frame_lags(images, np.ones((60, 80), bool)) == ([], [])


def test_without_flushing_the_capture_check_names_the_rows_read_before_the_switch():
    camera = RollingShutterCamera(_lights(), rows_before=25, across=(2,))
    camera.flush_frames = 0
    images = _capture_all(camera)
    repeated, bands = frame_lags(images, np.ones((60, 80), bool))
    assert repeated == [] and [(band.index, band.top) for band in bands] == [(2, True)]
    assert bands[0].rows == (0, 25)
    line = lagged_line("press_01", [f"led_{k + 1:02d}.png" for k in range(4)], bands)
    assert "led_03.png's rows 0-24 (top) show led_02.png's light" in line and "--flush 1 or more" in line
