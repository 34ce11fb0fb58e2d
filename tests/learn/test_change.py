"""The change rule (learn.change) takes a frame's per-colour gain out before it thresholds (rule 3), on the CPU and
on a torch device (learn.fullframe) alike."""

import numpy as np
import pytest

from nlipscalib.core.tolerances import FRAME_CHANNEL_DRIFT
from nlipscalib.learn.change import ChangeDetector, rule_gain

MJPG_GAIN = np.float32([0.99, 1.01, 0.99])
"""About an 8-bit MJPG stream's colour shift over the reference (s41-walkleft: 0.989-0.991)."""


def _gel(h: int = 120, w: int = 160):
    """(rows, cols, valid, reference, noise): an elliptic gel lit by three LEDs' hot spots on a dim dome (its
    brightness 0.1-0.6 of full scale, so a uniform gain changes the hot spots most), 0.2 % noise."""
    yy, xx = np.mgrid[0:h, 0:w]
    valid = ((yy - h / 2) / (h / 2)) ** 2 + ((xx - w / 2) / (w / 2)) ** 2 < 0.95
    spots = sum(
        np.exp(-((yy - h / 2 - 0.35 * h * np.sin(a)) ** 2 + (xx - w / 2 - 0.35 * w * np.cos(a)) ** 2) / (0.1 * w) ** 2)
        for a in 2 * np.pi * np.arange(3) / 3
    )
    reference = ((0.1 + 0.5 * spots)[..., None] * np.array([1.0, 0.8, 0.6])).astype(np.float32)
    noise = np.random.default_rng(0).normal(0, 0.002, reference.shape).astype(np.float32)
    return yy, xx, valid, reference, noise


def _pressed(reference, yy, xx, centre=(70, 60), radius=15):
    """(frame, dent): ``reference`` with a dent whose colours move apart (a press tilts the surface: one LED group's
    light rises, another's falls)."""
    dent = (yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 < radius**2
    frame = reference.copy()
    frame[dent] *= np.float32([1.08, 0.95, 1.03])
    return frame, dent


@pytest.mark.parametrize("gain", [MJPG_GAIN, np.float32([0.99] * 3), np.float32([1.01] * 3)])
def test_a_frame_whose_colours_are_one_percent_off_and_unpressed_changes_nowhere(gain):
    """Rule 2 took a uniform colour shift for change where the gel is brightest: this gel's three hot spots (1816-1936
    pixels); the MJPG's shift doubled its threshold on the walk's presses. The frame's own figures still see it."""
    _, _, valid, reference, noise = _gel()
    rule = ChangeDetector(reference, valid)
    assert not rule(reference + noise).any()
    assert not rule(reference * gain + noise).any()
    np.testing.assert_allclose(rule.channel_ratio, gain, atol=1e-3)  # what warns of drifted LEDs: the frame as it is
    assert rule.mismatch > 0.005


def test_a_contact_is_found_alike_with_and_without_a_one_percent_colour_gain():
    """The same press, the same noise, its colours 1 % off (an MJPG's): the same region but for the odd block at its
    edge (the threshold's noise estimate moves a little with the gain taken out). Rule 2 found 2316 pixels against
    1312 (the hot spots too), 1812 of them differing."""
    yy, xx, valid, reference, noise = _gel()
    frame, dent = _pressed(reference, yy, xx)
    rule = ChangeDetector(reference, valid)
    plain = rule(frame + noise)
    assert plain[dent].all() and plain.sum() < 2 * dent.sum()  # found whole, with the rule's rim
    shifted = rule(frame * MJPG_GAIN + noise)
    assert shifted[dent].all() and (shifted ^ plain).sum() <= 0.01 * plain.sum()


@pytest.mark.parametrize("radius", [30, 40])
def test_a_large_contact_does_not_pull_the_gain_toward_its_own_colours(radius):
    """A dent over a fifth or a third of the gel, its colours moved apart: a median over the whole gel, or over what
    the first pass (its threshold raised by the shift) left unchanged, which holds the dent's dim part, is pulled
    toward the dent's colours; the second median leaves those blocks out, so the frame's 1 % shift is what is taken
    out and the dent is found whole (with one median: 22 % of it at a third of the gel; rule 2: 11 % and 8 %)."""
    yy, xx, valid, reference, noise = _gel()
    frame, dent = _pressed(reference, yy, xx, centre=(60, 80), radius=radius)
    assert 0.15 < dent[valid].mean() < 0.4
    rule = ChangeDetector(reference, valid)
    plain = rule(frame + noise)
    shifted = frame * MJPG_GAIN + noise
    got = rule(shifted)
    whole_gel = np.median((shifted / reference)[valid], axis=0)
    assert np.abs(whole_gel - MJPG_GAIN).max() > 0.003  # what a median over the whole gel would take out
    assert np.abs(rule.channel_ratio - MJPG_GAIN).max() > 0.0015  # the first pass's median: the frame as it is
    np.testing.assert_allclose(rule.gain, MJPG_GAIN, atol=5e-4)
    assert plain[dent].all() and got[dent].all()
    assert (got ^ plain).sum() <= 0.01 * plain.sum()


def test_the_gain_taken_out_is_held_within_what_a_frame_may_drift_unwarned():
    """A larger colour change is drift (warned about; a calibration press's is taken out by learn.dataset's
    contact_pixels) or a contact over most of the gel, whose colours the rest would be shifted by."""
    n = 50
    reference, rest = np.full((n, 3), 0.4, np.float32), np.ones(n, bool)
    signed = np.tile(np.float32([-0.1, 0.004, 0.2]) * 0.4, (n, 1))  # red 0.9, green 1.004, blue 1.2 times
    held = rule_gain(signed, reference, rest)
    np.testing.assert_allclose(held, [1 - FRAME_CHANNEL_DRIFT, 1.004, 1 + FRAME_CHANNEL_DRIFT], rtol=1e-6)
    signed[:, 0] = np.nan  # nothing to go by in red
    np.testing.assert_allclose(rule_gain(signed, reference, rest), [1.0, 1.004, 1 + FRAME_CHANNEL_DRIFT], rtol=1e-6)
    assert (rule_gain(signed, reference, np.zeros(n, bool)) == 1).all()  # every block changed
    yy, xx, valid, reference, noise = _gel()
    frame, dent = _pressed(reference, yy, xx)
    rule = ChangeDetector(reference, valid)
    rule(frame * np.float32([0.9, 1, 1]) + noise)  # red 10 % down: 2.5 % of it taken out
    assert rule.channel_ratio[0] == pytest.approx(0.9, abs=2e-3) and rule.gain[0] == 1 - FRAME_CHANNEL_DRIFT


@pytest.mark.parametrize(
    "gain, pressed",
    [([1, 1, 1], False), (MJPG_GAIN, False), ([1, 1, 1], True), (MJPG_GAIN, True), ([0.9, 1.0, 1.04], True)],
)
def test_the_device_rule_is_the_cpu_rule(gain, pressed):
    """learn.fullframe's copy on torch CPU tensors: the same changed pixels, the same frame figures, and on the
    device the gain the CPU takes out (its first pass's middle block, held alike)."""
    torch = pytest.importorskip("torch")
    from nlipscalib.learn.fullframe import _ChangeRule

    yy, xx, valid, reference, noise = _gel()
    frame = _pressed(reference, yy, xx)[0] if pressed else reference
    frame = frame * np.float32(gain) + noise
    cpu = ChangeDetector(reference, valid)
    want = cpu(frame)
    device = _ChangeRule(reference, valid, torch.device("cpu"))
    with torch.no_grad():
        changed, mismatch, sampled = device(torch.from_numpy(frame))
        samples, rest = torch.from_numpy(sampled.numpy()[:, :3]), torch.from_numpy(sampled.numpy()[:, 3] == 0)
        gain_there = device._gain(samples, rest).numpy()
    np.testing.assert_array_equal(changed.numpy(), want)
    assert float(mismatch) == pytest.approx(cpu.mismatch, rel=1e-5)
    assert device.channels(sampled.numpy()) == pytest.approx(tuple(cpu.channel_ratio), abs=1e-7)
    np.testing.assert_array_equal(gain_there, rule_gain(sampled.numpy()[:, :3], device.ref_sample, rest.numpy()))
    assert want.any() == pressed
