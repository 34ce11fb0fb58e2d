"""The emulated camera: frames follow the latched LEDs with a camera's delay; flushing hides the delay."""

import numpy as np

from nlipscalib.emulator import EmulatedCamera
from nlipscalib.sim.scene import SceneConfig

from .fakes import FakeController


class StubRenders:
    """Per-LED images without Mitsuba: LED k lights channel-independent level (k + 1) / 100."""

    def __init__(self, scene, n_leds):
        h, w = scene.camera_model().shape
        self.scene, self.exposure = scene, 1.0
        self.stack = np.stack([np.full((h, w, 3), (k + 1) / 100, np.float32) for k in range(n_leds)])

    def images(self, surface):
        return self.stack * (2.0 if surface == "pressed" else 1.0)


def _camera(flush_frames, latency_frames=1):
    scene = SceneConfig().replace(camera={"width": 10, "height": 8}, noise={"enabled": False})
    board = FakeController(12)
    cam = EmulatedCamera(StubRenders(scene, 12), lambda: board.latched, latency_frames=latency_frames)
    cam.flush_frames = flush_frames
    return cam, board, scene.noise.response()


def _level(image, response):
    return (float(image[3, 4, 0]) - response.black_level) / (response.white_level - response.black_level)


def test_frames_lag_one_behind_the_leds_without_flushing():
    cam, board, resp = _camera(flush_frames=0)
    cam.capture()
    board.set_all(np.tile([[255, 255, 255]], (12, 1)) * (np.arange(12) == 4)[:, None])
    assert abs(_level(cam.capture(), resp)) < 1e-3  # still the dark frame: stale
    assert abs(_level(cam.capture(), resp) - 0.05) < 1e-3


def test_flushing_gives_the_current_light_and_surface():
    cam, board, resp = _camera(flush_frames=2, latency_frames=1)
    board.set_all(np.tile([[255, 0, 0]], (12, 1)) * (np.arange(12) == 9)[:, None])
    assert abs(_level(cam.capture(), resp) - 0.10) < 1e-3
    cam.show("pressed")
    assert abs(_level(cam.capture(), resp) - 0.20) < 1e-3
    cam.show(None, moves_to="pressed", after=3)
    levels = [_level(cam.read(), resp) for _ in range(6)]
    # one stale "pressed" frame, then the undeformed gel until it moves after 3 reads, delivered 1 frame late
    assert np.allclose(levels, [0.2, 0.1, 0.1, 0.1, 0.2, 0.2], atol=1e-3)


def _operator(seed):
    from nlipscalib.emulator import ScriptedOperator, default_script

    scene = SceneConfig().replace(camera={"width": 10, "height": 8}, noise={"enabled": True})
    board = FakeController(12)
    cam = EmulatedCamera(StubRenders(scene, 12), lambda: board.latched, seed=seed)
    board.set_all(np.tile([[255, 255, 255]], (12, 1)))
    return ScriptedOperator(cam, default_script(3), echo=lambda line: None), cam


def test_a_session_resumed_in_a_new_process_captures_each_press_as_an_uninterrupted_one():
    """`nlips capture --emulate` killed after press 1, then run again: the new process started the camera's noise
    stream afresh at press 2, so every press after the resume had other noise than one uninterrupted session of
    the same --seed gives (the images differed bit for bit). Each press's noise now starts from the seed and its
    number."""
    whole, cam = _operator(seed=5)
    whole.reference()
    cam.capture()
    whole.press(1, 3)
    cam.capture()
    whole.press(2, 3)
    uninterrupted = cam.capture()
    resumed, cam = _operator(seed=5)  # the new process: the reference and press 1 are kept on disk
    resumed.press(2, 3)
    assert np.array_equal(cam.capture(), uninterrupted)
    other, cam = _operator(seed=6)
    other.press(2, 3)
    assert not np.array_equal(cam.capture(), uninterrupted)  # the seed still decides the noise
