"""The emulated camera: frames follow the latched LEDs with a camera's delay; flushing hides the delay."""

import numpy as np
import pytest

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


class SurfaceRenders(StubRenders):
    """As StubRenders, but the undeformed gel dim (below the noise model's Poisson threshold) and a press bright:
    what a frame shows then decides how many draws its noise takes, as with real renders."""

    def images(self, surface):
        return self.stack * (0.05 if surface is None else 1.0)


def test_the_first_press_after_a_resume_is_captured_as_in_an_uninterrupted_session():
    """`nlips capture --emulate` stopped by Ctrl-C after press 2 and run again: press 3 came out with other noise
    than in one uninterrupted run (press 6 the same): the new process's camera delivered press 3 itself in the
    frames flushed after the prompt, the old one the frame before, and the noise stream's Poisson draws hang on
    what a frame shows. Each frame's noise now comes from the seed, the press and the frame's place in it."""
    from nlipscalib.emulator import ScriptedOperator, default_script

    def operator():
        scene = SceneConfig().replace(camera={"width": 10, "height": 8}, noise={"enabled": True})
        board = FakeController(12)
        cam = EmulatedCamera(SurfaceRenders(scene, 12), lambda: board.latched, seed=5)
        board.set_all(np.tile([[255, 255, 255]], (12, 1)))
        return ScriptedOperator(cam, default_script(3), echo=lambda line: None), cam

    whole, cam = operator()
    whole.reference()
    cam.capture()
    whole.press(1, 3)
    uninterrupted = [cam.capture(), cam.capture()]
    resumed, cam = operator()  # the new process: the reference is kept on disk
    resumed.press(1, 3)
    assert np.array_equal(cam.capture(), uninterrupted[0])
    assert np.array_equal(cam.capture(), uninterrupted[1])


def test_emulated_frames_pass_through_the_scenes_lens_and_camera_effects_as_the_twins_captures(monkeypatch):
    """The emulated camera left out the scene's camera effects: its frames had no defocus, vignetting or response
    curve where the twin's (`nlips render` of the same press) have them. With noise off, an emulated frame is now
    the twin's capture, bit for bit, but at the stated black level (the scene's black-level error left out: under a
    tone curve it made `nlips calibrate-camera-response --emulate` refuse the camera as one adding a black level)."""
    import nlipscalib.emulator as emulator
    import nlipscalib.sim.press as press
    import nlipscalib.sim.render.surface as surface
    from nlipscalib.emulator import TwinRenders
    from nlipscalib.sim.press import camera_capture

    scene = SceneConfig().replace(
        camera={"width": 16, "height": 12},
        noise={"enabled": False},
        camera_effects={
            "defocus_px": 1.5,
            "vignetting": "polynomial",
            "black_level_error": 3.0,
            "response_gamma": 1.03,
        },
    )
    h, w = scene.camera_model().shape
    rng = np.random.default_rng(0)
    per_led = rng.uniform(0.0, 0.01, (12, h, w, 3)).astype(np.float32)

    class Rendered:
        images = per_led

    monkeypatch.setattr(surface, "render_surface", lambda *args, **kwargs: Rendered)
    for module in (emulator, press):  # the exposure the twin picks on its own render of the dome, fixed here
        monkeypatch.setattr(module, "scene_exposure", lambda scene, tricolor=False: 40.0)
    board = FakeController(12)
    cam = EmulatedCamera(TwinRenders(scene), lambda: board.latched)
    stated = scene.replace(camera_effects={"black_level_error": 0.0})
    dark, leds, _, _, _ = camera_capture(stated, per_led, seed=0)
    assert not np.array_equal(camera_capture(scene, per_led, seed=0)[0], dark)  # the error shows in a dark frame
    assert np.array_equal(cam.capture(), dark)
    board.set_all(np.tile([[255, 255, 255]], (12, 1)) * (np.arange(12) == 4)[:, None])
    assert np.array_equal(cam.capture(), leds[4])


class ScriptRenders(StubRenders):
    """As StubRenders, each scripted surface (a number) scaling the light by its own factor: a frame tells which
    surface it shows."""

    def images(self, surface):
        return self.stack * (1.0 if surface is None else 1.0 + surface)


@pytest.mark.parametrize("latency", [1, 2])
@pytest.mark.parametrize("per_press", [1, 3])
def test_the_emulated_stream_shows_each_press_in_its_own_frames_the_last_one_included(latency, per_press):
    """`nlips live/infer --emulate`: the stream changed the gel right before each read while the camera delivers a
    frame one read late, so each press's first frame showed the press before and, with --frames-per-press 1, the
    last press was never shown. Frame i now shows surface i // per_press, whatever the camera's latency, and the
    script once is all the stream gives."""
    from nlipscalib.device.live import StopLive
    from nlipscalib.emulator import ScriptedStream

    scene = SceneConfig().replace(camera={"width": 10, "height": 8}, noise={"enabled": False})
    board = FakeController(12)
    board.set_all(np.tile([[255, 255, 255]], (12, 1)) * (np.arange(12) == 4)[:, None])  # LED 5: level 0.05
    cam = EmulatedCamera(ScriptRenders(scene, 12), lambda: board.latched, latency_frames=latency)
    surfaces = [None, 1, 2, 3]
    before_frame = ScriptedStream(cam, surfaces, per_press, loop=False)
    response = scene.noise.response()
    shown = []
    for frame in range(len(surfaces) * per_press):
        before_frame(frame)
        shown.append(round(_level(cam.read(), response) / 0.05 - 1.0, 2))
    assert shown == [float(s or 0) for s in surfaces for _ in range(per_press)]
    with pytest.raises(StopLive):
        before_frame(len(surfaces) * per_press)
