"""The emulated sensor end to end: a capture session through the LED host driver, the virtual board and the
virtual camera on the twin; its captures solve like direct renders of the same presses."""

import pytest

pytest.importorskip("mitsuba")

from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.core.metrics import evaluate  # noqa: E402
from nlipscalib.device.session import SessionConfig, run_session  # noqa: E402
from nlipscalib.emulator import default_script, open_emulated_sensor  # noqa: E402
from nlipscalib.sim.press import render_press  # noqa: E402
from nlipscalib.sim.scene import load_scene  # noqa: E402
from nlipscalib.solver import solve_press  # noqa: E402


@pytest.fixture(scope="module")
def scene():
    return load_scene().replace(camera={"width": 160, "height": 120}, render={"spp": 4, "threads": 2})


@pytest.fixture(scope="module")
def session(scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("emulated")
    script = default_script(3, move_press=3)
    lines = []
    with open_emulated_sensor(scene, script, seed=7, echo=lines.append) as sensor:
        cfg = SessionConfig(presses=3, tricolor_level=sensor.tricolor_level)
        status = run_session(sensor.rig, out / "session", cfg, sensor.operator)
    return out, script, status, lines


def test_moved_press_is_detected_and_retaken(session):
    _, _, status, lines = session
    assert [status[f"press_000{k}"]["attempts"] for k in (1, 2, 3)] == [1, 1, 2]
    assert status["press_0003"]["moved"][0] > 0.001 >= status["press_0003"]["moved"][1]
    assert any("moved" in line and "retaking" in line for line in lines)


def test_emulated_capture_solves_like_direct_render(session, scene):
    out, script, status, _ = session
    for k, step in enumerate(script, 1):
        truth = step.moved or step.press  # the retaken press holds the moved pose
        direct = load_press(render_press(scene, truth, out / f"direct_{k}"))
        emulated = load_press(out / "session" / f"press_000{k}")
        assert emulated.meta["provenance"]["source"] == "device"
        assert emulated.led_images.shape == direct.led_images.shape
        gt = direct.ground_truth
        aae = [evaluate(solve_press(p, roi="auto"), gt)["contact"]["aae_deg"] for p in (direct, emulated)]
        assert abs(aae[0] - aae[1]) <= 0.2, aae
