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


def test_a_camera_turned_90_degrees_without_flushing_names_the_columns_read_before_the_switch():
    """Mounted turned 90 degrees, the rolling shutter reads the image's columns: LED 3's left (or right) columns
    show LED 2's light. Only rows were compared before (the band was not seen); the columns are named as the rows
    are, with the cause in their words, and a clean turned capture holds none."""
    camera = RollingShutterCamera(_lights(), rows_before=25, across=(2,))
    camera.flush_frames = 0
    turned = _capture_all(camera).transpose(0, 2, 1, 3)  # (4, 80, 60, 3): the first 25 columns read before
    gel = np.ones(turned.shape[1:3], bool)
    repeated, bands = frame_lags(turned, gel)
    assert repeated == [] and [(band.index, band.rows, band.where) for band in bands] == [(2, (0, 25), "left")]
    line = lagged_line("press_01", [f"led_{k + 1:02d}.png" for k in range(4)], bands)
    assert "led_03.png's columns 0-24 (left) show led_02.png's light" in line and "turned 90 degrees" in line
    mirrored = frame_lags(turned[:, :, ::-1], gel)[1]
    assert [(band.index, band.rows, band.where) for band in mirrored] == [(2, (35, 60), "right")]
    camera.flush_frames = 2
    assert frame_lags(_capture_all(camera).transpose(0, 2, 1, 3), gel) == ([], [])
