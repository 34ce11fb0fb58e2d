"""The exposure check of a captured press: black LED frames, saturated frames, an unusable reference."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("cv2")

from nlipscalib.core import SensorResponse  # noqa: E402
from nlipscalib.core.errors import CaptureError  # noqa: E402
from nlipscalib.device.exposure import check_exposure  # noqa: E402

H, W, L = 24, 32, 6
DARK = 1000
"""The frames' dark level, their camera's black level: declared (a dark frame evenly above the declared black level
is refused at the reference, as a pedestal)."""
RESPONSE = SensorResponse(bit_depth=16, black_level=float(DARK), white_level=65535.0)


def _frames(led=20000, dark=DARK, tricolor=30000):
    """A press's frames (uint16): grey levels; ``led`` one level or one per LED, each LED's frame brighter towards
    its own side (+-10 %, as neighbouring LEDs of a ring differ; black and saturated ones uniform), so no lit LED
    frame repeats another."""
    levels = np.broadcast_to(led, (L,))

    def img(v):
        return np.full((H, W, 3), v, np.uint16)

    def lit(v, i):
        angle = 2 * np.pi * i / L
        u, w = np.meshgrid(np.linspace(-1, 1, W), np.linspace(-1, 1, H))
        side = 1 + 0.1 * (np.cos(angle) * u + np.sin(angle) * w)
        return np.clip(dark + (v - dark) * side, 0, 65535).astype(np.uint16)[..., None].repeat(3, axis=2)

    frames = {"tricolor": img(tricolor), "dark": img(dark)}
    frames |= {f"led_{i + 1:02d}": img(v) if v in (dark, 65535) else lit(v, i) for i, v in enumerate(levels)}
    return frames


def test_a_well_exposed_press_says_nothing(tmp_path):
    assert check_exposure(_frames(), RESPONSE, tmp_path / "press_0001") == []
    assert check_exposure(_frames(), RESPONSE, tmp_path / "reference", reference=True) == []


def test_black_led_frames_are_named(tmp_path):
    """LEDs off, a lens cap: the LED frames hold no light above the dark frame (noise aside)."""
    rng = np.random.default_rng(0)
    frames = _frames(led=1000)
    for name, image in frames.items():  # 1 % of full scale of noise per pixel: not light
        frames[name] = np.clip(image + rng.normal(0, 650, image.shape), 0, 65535).astype(np.uint16)
    lines = check_exposure(frames, RESPONSE, tmp_path / "press_0001")
    assert lines == [
        f"{tmp_path / 'press_0001'}: no LED frame shows light above the dark frame (led_01.png .. led_06.png against "
        "dark.png): LEDs off or not driven (the right --port?), lens cap on, or the camera not looking at the gel"
    ]
    one_dead = check_exposure(_frames(led=[20000, 20000, 1000, 20000, 20000, 1000]), RESPONSE, tmp_path / "p")
    assert one_dead == [
        f"{tmp_path / 'p'}/led_03.png, led_06.png: no light above the dark frame (dark.png): is that LED lit and wired "
        "(`nlips leds PORT test`)?"
    ]


def test_saturated_frames_are_named_with_their_share(tmp_path):
    frames = _frames()
    frames["led_03"][: int(0.53 * H)] = 65535  # 53 % of the rows clipped
    frames["tricolor"][: int(0.88 * H), :, 0] = 65535  # one channel is enough
    frames["led_05"][:2] = 65535  # 8 %
    frames["led_01"][:1] = 65535  # 4 %: under the limit
    (line,) = check_exposure(frames, RESPONSE, tmp_path / "press_0001")
    assert line == (
        f"{tmp_path / 'press_0001' / 'tricolor.png'}: 88 % of the pixels saturated (led_03.png 50 %, led_05.png 8 % "
        "also over 5 %): saturated pixels are left out of every fit; lower --exposure-ms or the LED level "
        "(--tricolor-level for tricolor.png)"
    )


def test_the_gel_is_what_counts(tmp_path):
    """Pixels off the gel (the corners of a fisheye view) neither hide nor make a saturated share."""
    frames = _frames()
    frames["led_02"][:, : W // 2] = 65535
    gel = np.zeros((H, W), bool)
    gel[:, : W // 2] = True
    (line,) = check_exposure(frames, RESPONSE, tmp_path / "p", gel)
    assert line.startswith(f"{tmp_path / 'p' / 'led_02.png'}: 100 % of the gel saturated")
    gel[:] = False
    gel[:, W // 2 :] = True
    assert check_exposure(frames, RESPONSE, tmp_path / "p", gel) == []


@pytest.mark.parametrize(
    "frames, message",
    [
        (_frames(led=1000), "the reference is black: no LED frame shows light above the dark frame"),
        (_frames(led=65535, dark=65535, tricolor=65535), "the reference is saturated: every LED frame has at least 99"),
        (_frames(led=[65535, 1000, 65535, 65535, 1000, 65535]), "the reference is saturated"),
    ],
)
def test_a_reference_with_nothing_usable_is_refused(tmp_path, frames, message):
    with pytest.raises(CaptureError) as info:
        check_exposure(frames, RESPONSE, tmp_path / "reference", reference=True)
    assert str(info.value).startswith(f"{tmp_path / 'reference'}: {message}")
    assert "so it was not written" in str(info.value)
    assert check_exposure(frames, RESPONSE, tmp_path / "press_0001")  # a press: warned about, not refused


def test_rows_dark_in_every_led_frame_are_named_with_the_fix(tmp_path):
    """Every LED frame's top 15 rows read while no LED was lit (the dark frame's level): named with the rows while
    the press can still be captured again (one LED's dark rows need the LED model: the solve's). Without a gel mask
    not looked for: a frame's rows beyond the dome's image are dark in every frame."""
    # 72 x 96: rows of 5x5 blocks wide enough to count (core.repeated_frames.MIN_LIT_ROW_BLOCKS)
    frames = {name: frame.repeat(3, axis=0).repeat(3, axis=1) for name, frame in _frames().items()}
    gel = np.ones(frames["dark"].shape[:2], bool)
    assert check_exposure(frames, RESPONSE, tmp_path / "press_0001", gel) == []
    for name in [name for name in frames if name.startswith("led_")]:
        frames[name][:15] = frames["dark"][:15]
    lines = check_exposure(frames, RESPONSE, tmp_path / "press_0001", gel)
    assert len(lines) == 1 and "press_0001: rows 0-14 (top) of every LED image are dark" in lines[0], lines
    assert "--flush" in lines[0]
    assert check_exposure(frames, RESPONSE, tmp_path / "press_0001") == []


def test_an_led_frame_that_repeats_the_one_before_is_named_with_the_fix(tmp_path):
    """A webcam whose frames lag the LED switch handed out LED 3's frame again as LED 4's: nothing said so, and
    the LED calibration fitted LED 4 at LED 3's place (s27 QA walk). The check names it while the press can still
    be captured again; the same light captured twice differs by noise only, which the blur averages away."""
    rng = np.random.default_rng(1)
    frames = _frames()
    frames["led_04"] = np.clip(frames["led_03"] + rng.normal(0, 100, (H, W, 3)), 0, 65535).astype(np.uint16)
    lines = check_exposure(frames, RESPONSE, tmp_path / "press_0001")
    assert len(lines) == 1
    assert "led_04.png repeats led_03.png" in lines[0] and "--flush" in lines[0] and "press_0001" in lines[0]


def test_a_reference_whose_dark_frame_sits_evenly_above_the_black_level_is_refused_naming_it(tmp_path):
    """A camera's own black level (pedestal) left undeclared: the session was captured whole and `nlips solve`
    refused every press after it. At the reference it is refused, naming the --black-level to declare; a dark frame
    lit unevenly (room light from one side) is not a pedestal; a press (not the reference) is not checked."""
    undeclared = SensorResponse(bit_depth=12, black_level=0.0, white_level=65520.0)
    with pytest.raises(CaptureError) as refused:
        check_exposure(_frames(), undeclared, tmp_path / "reference", reference=True)
    assert str(refused.value).startswith(
        f"{tmp_path / 'reference'}/dark.png: not a dark frame of the black level 0 (--black-level): the median of "
        "the pixels, 62.5 in the camera's 12-bit values, is 1.5 % of full scale above it and even"
    )
    assert "capture again with it declared (`--black-level 62.5`)" in str(refused.value)
    assert check_exposure(_frames(), undeclared, tmp_path / "press_0001") == []
    lamp = _frames()
    lamp["dark"] = np.linspace(0, 2 * DARK, W, dtype=np.uint16)[None, :, None] * np.ones((H, 1, 3), np.uint16)
    assert check_exposure(lamp, undeclared, tmp_path / "reference", reference=True) == []


def test_a_pedestal_reference_whose_led_frames_are_not_linear_is_refused_naming_the_tone_curve(tmp_path):
    """A gamma camera's curve lifts its small dark offset evenly above the black level: the refusal named
    `--black-level` and the solve then called the frames not linear (s37). With the tone-curve check given
    (``response_slope``, the solve's, wired by the CLI) the refusal names the curve first: undeclared, the ways to
    linear frames; declared, that the curve is another. Linear frames (slope 1) keep the black level's refusal."""
    undeclared = SensorResponse(bit_depth=12, black_level=0.0, white_level=65520.0)
    asked = []

    def slope(value):
        def response_slope(leds, dark):
            asked.append((leds.shape, dark.shape))
            return value

        return response_slope

    with pytest.raises(CaptureError) as refused:
        check_exposure(_frames(), undeclared, tmp_path / "reference", reference=True, response_slope=slope(0.48))
    message = str(refused.value)
    assert asked == [((L, H, W, 3), (H, W, 3))]
    assert message.startswith(
        f"{tmp_path / 'reference'}: the LED frames are not linear in the light: each pixel's value grows as the LED "
        "model's light to the power 0.48 (median; a linear capture: about 1), as in gamma-encoded (sRGB) frames; and "
        "dark.png sits evenly above the black level 0 (--black-level), its median of the pixels 62.5 in the camera's "
        "12-bit values (1.5 % of full scale). A tone curve is steepest at black"
    )
    assert "--camera-response srgb" in message and "`--black-level" not in message
    assert message.endswith("The reference was not written (the session's settings are fixed only once it is)")

    srgb = SensorResponse(bit_depth=12, black_level=0.0, white_level=65520.0, camera_response="srgb")
    with pytest.raises(CaptureError, match=r"declared tone curve undone \(--camera-response: srgb\).*is another"):
        # 5000 of 65520 is 0.7 % of full scale in the light (sRGB undone): a dark frame of the pedestal's kind
        check_exposure(_frames(dark=5000), srgb, tmp_path / "reference", reference=True, response_slope=slope(0.6))

    with pytest.raises(CaptureError, match=r"capture again with it declared \(`--black-level 62\.5`\)"):
        check_exposure(_frames(), undeclared, tmp_path / "reference", reference=True, response_slope=slope(1.0))
    with pytest.raises(CaptureError, match=r"`--black-level 62\.5`"):  # not told: the black level, as before
        check_exposure(_frames(), undeclared, tmp_path / "reference", reference=True, response_slope=slope(None))


def test_a_reference_whose_led_frames_are_not_linear_is_warned_about_first(tmp_path):
    """A gamma camera whose dark frame sits at the black level was captured whole without a word; each press's solve
    then warned "not linear in the light", its normals degrees off, and the session's tone curve is fixed by its
    reference (s37). The reference is warned about first, the session to be captured again; linear frames are not,
    nor a press (the check is the reference's); linear frames declared sRGB are named the other way."""
    srgb = SensorResponse(bit_depth=16, black_level=float(DARK), white_level=65535.0, camera_response="srgb")
    folder = tmp_path / "reference"
    lines = check_exposure(_frames(), RESPONSE, folder, reference=True, response_slope=lambda leds, dark: 0.5)
    assert len(lines) == 1 and lines[0].startswith(f"{folder}: the LED frames are not linear in the light: "), lines
    assert "stop (Ctrl-C) and capture it again into a new folder" in lines[0] and "--camera-response srgb" in lines[0]
    assert check_exposure(_frames(), RESPONSE, folder, reference=True, response_slope=lambda leds, dark: 1.0) == []
    assert check_exposure(_frames(), RESPONSE, folder, reference=True, response_slope=lambda leds, dark: None) == []
    assert check_exposure(_frames(), RESPONSE, tmp_path / "press_0001", response_slope=lambda leds, dark: 0.5) == []
    (line,) = check_exposure(_frames(), srgb, folder, reference=True, response_slope=lambda leds, dark: 1.6)
    assert "declares the camera's srgb tone curve" in line and "power 1.60" in line and "linear already?" in line
