"""Images of two LEDs designed 0.8 mm apart, exchanged (solver.led_checks._close_pair_exchanges): their modelled
lights correlate 0.99, so each image fits its own LED as well as the other's and the press was solved without a word
(the twin's pairs08 sphere, --reference --roi auto: 0.66 -> 0.83 deg on the contact, a false "the camera moved?";
benchmarks/RESULTS.md, s37-swapcheck). How the two images differ tells them."""

import shutil

import pytest

pytest.importorskip("mitsuba")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.sim.press import render_press  # noqa: E402
from nlipscalib.solver.led_checks import led_check_measured  # noqa: E402
from tests.cli.test_calibrate_leds import _close_pairs_scene  # noqa: E402
from tests.solver.twin_helpers import recorded_anew  # noqa: E402


@pytest.fixture(scope="module")
def pressed(tmp_path_factory):
    """A press of LEDs in six pairs 0.8 mm apart (160x120, one bounce, 16 spp; the default sphere)."""
    from nlipscalib.sim.indent import PressConfig
    from nlipscalib.sim.indenters import IndenterConfig

    sphere = PressConfig(IndenterConfig("sphere", 6.0), polar_deg=20, azimuth_deg=0, depth=1.0)
    return render_press(_close_pairs_scene(), sphere, tmp_path_factory.mktemp("pairs") / "clean", seed=11)


def _exchanged_copy(clean, folder, first, second):
    shutil.copytree(clean, folder)
    (folder / first).rename(folder / "x.png")
    (folder / second).rename(folder / first)
    (folder / "x.png").rename(folder / second)
    recorded_anew(folder)
    return folder


def test_images_of_leds_designed_0_8_mm_apart_exchanged_are_named_and_refused_and_clean_ones_are_not(
    pressed, tmp_path, capsys
):
    clean = load_press(pressed)
    assert led_check_measured(clean, clean.leds, range(12)).exchanged == []
    for first, second, leds in (("led_01.png", "led_02.png", (0, 1)), ("led_05.png", "led_06.png", (4, 5))):
        folder = _exchanged_copy(pressed, tmp_path / first, first, second)
        press = load_press(folder)
        (found,) = led_check_measured(press, press.leds, range(12)).exchanged
        assert found.leds == leds and found.against == "model"
        assert found.line.startswith(f"{folder}: {first} and {second} look exchanged (LEDs {leds[0] + 1} and ")
    capsys.readouterr()
    assert main(["--no-progress", "solve", str(tmp_path / "led_01.png"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "led_01.png and led_02.png look exchanged" in err and "--keep-led-order" in err, err
