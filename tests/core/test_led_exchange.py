"""LED images captured in each other's place, told by the fitted LEDs' places against the design
(core.led_exchange, `nlips calibrate-leds`), and by a press's images against its LED model's light (`nlips solve`)."""

from __future__ import annotations

import functools
import math

import numpy as np

from nlipscalib.core.blas import blas_threads
from nlipscalib.core.led_exchange import exchanged_in_shading, exchanged_leds, place_exchanges
from nlipscalib.core.leds import Led, led_arrays, led_shading
from tests.solver import synth


def _ring(count: int, radius: float = 9.0) -> np.ndarray:
    """(count, 3) LED places on a ring in the base plane, mm."""
    a = 2 * np.pi * np.arange(count) / count
    return np.stack([radius * np.cos(a), radius * np.sin(a), np.full(count, 3.0)], axis=1)


def _scattered(places: np.ndarray, mm: float, rng: np.random.Generator) -> np.ndarray:
    """``places`` each moved ``mm`` in a random direction."""
    offset = rng.normal(size=places.shape)
    return places + mm * offset / np.linalg.norm(offset, axis=1, keepdims=True)


def test_two_neighbours_fitted_at_each_others_places_are_one_exchange_and_a_clean_fit_none():
    """The twin's led_03.png and led_04.png exchanged calibrated LED 3 at LED 4's place and back (4.68 mm off their
    own, 0.19-0.28 mm from each other's) and was called reliable; a clean fit lies 0.19-0.51 mm off."""
    design = led_arrays(synth.ring_leds())[0]
    rng = np.random.default_rng(0)
    clean = _scattered(design, 0.5, rng)
    assert exchanged_leds(design, clean) == []
    swapped = clean.copy()
    swapped[[2, 3]] = clean[[3, 2]]
    assert exchanged_leds(design, swapped) == [[2, 3]]
    cycle = clean.copy()
    cycle[[4, 5, 6]] = clean[[5, 6, 4]]  # LED 5 at LED 6's place, 6 at 7's, 7 at 5's
    assert exchanged_leds(design, cycle) == [[4, 5, 6]]
    assert exchanged_leds(design, swapped, left_out=[3]) == []  # an LED not fitted sits at its start


def test_leds_built_far_from_their_design_or_one_fit_run_off_are_no_exchange():
    """LEDs 3 mm from their design places (the farthest s31-ledfar starts from), 500 draws: an LED may sit nearer a
    neighbour's place than its own (at best 1.66 mm from it), which an assignment alone calls a swap; never 3 times
    nearer. One LED whose fit ran off onto its neighbour's place (the neighbour where designed): no exchange."""
    design = led_arrays(synth.ring_leds())[0]
    rng = np.random.default_rng(1)
    named = sum(bool(exchanged_leds(design, _scattered(design, 3.0, rng))) for _ in range(500))
    assert named == 0
    ran_off = design.copy()
    ran_off[2] = design[3] + 0.2
    assert exchanged_leds(design, ran_off) == []


def test_a_design_with_close_neighbours_raises_no_false_alarm_and_still_names_an_exchange():
    """36 LEDs 1.57 mm apart, each fitted 0.5 mm off (a clean fit's worst, in any direction), 500 draws: nothing
    named; two of them exchanged with 0.2 mm of fit error: named."""
    design = _ring(36)
    assert math.isclose(np.linalg.norm(design[1] - design[0]), 1.57, abs_tol=0.01)
    rng = np.random.default_rng(2)
    named = sum(bool(exchanged_leds(design, _scattered(design, 0.5, rng))) for _ in range(500))
    assert named == 0
    swapped = _scattered(design, 0.2, rng)
    swapped[[10, 11]] = swapped[[11, 10]]
    assert exchanged_leds(design, swapped) == [[10, 11]]


def _pairs(gap: float, groups: int = 6, per: int = 2, radius: float = 9.0) -> np.ndarray:
    """(groups * per, 3) LED places: ``groups`` clusters around a ring, each of ``per`` LEDs ``gap`` mm apart along it
    (s35-exchange's scene copies: six pairs, four triples)."""
    angles = [2 * np.pi * g / groups + (k - (per - 1) / 2) * gap / radius for g in range(groups) for k in range(per)]
    return np.array([[radius * np.cos(a), radius * np.sin(a), 3.0] for a in angles])


def _common(places: np.ndarray, rng: np.random.Generator, shift: float = 0.3, turn_deg: float = 1.0) -> np.ndarray:
    """``places`` moved alike: turned ``turn_deg`` about a random axis through their centre, scaled 1 % at random and
    shifted ``shift`` mm (a ring built turned; an LED's best point behind its disk, the same for every LED)."""
    from scipy.spatial.transform import Rotation

    centre = places.mean(axis=0)
    axis = rng.normal(size=3)
    turn = Rotation.from_rotvec(np.radians(turn_deg) * axis / np.linalg.norm(axis))
    return centre + turn.apply(places - centre) * (1 + 0.01 * rng.normal()) + shift * rng.normal(size=3) / np.sqrt(3)


def test_neighbours_designed_under_a_millimetre_apart_exchanged_are_named_where_the_fit_places_leds_closely():
    """LEDs in pairs 0.8 mm apart (the twin's scene copy: exchanged, each fitted 0.01-0.09 mm from the other's place,
    the others 0.03-0.05 mm from theirs once their common offset is out): a fixed 1 mm margin never named them. Now
    the margin is 5 times the others' scatter: named, with a common shift, turn and scale on top; clean: none."""
    design = _pairs(0.8)
    rng = np.random.default_rng(5)
    named = clean_named = 0
    for _ in range(200):
        fitted = _common(_scattered(design, 0.04, rng), rng)
        clean_named += bool(exchanged_leds(design, fitted))
        fitted[[2, 3]] = fitted[[3, 2]]
        named += exchanged_leds(design, fitted) == [[2, 3]]
    assert clean_named == 0 and named == 200
    found = place_exchanges(design, _common(_scattered(design, 0.04, rng), rng)[[1, 0, *range(2, 12)]])
    assert found.cycles == [[0, 1]] and 0.02 < found.scatter < 0.06 and found.margin < 0.3


def test_a_close_design_built_or_fitted_loosely_is_no_exchange_and_an_exchange_there_is_only_in_doubt():
    """Pairs and triples 0.5-1.2 mm apart, every LED 0.05-1 mm off its place at random (a loose build or fit) with a
    common shift, turn and scale, 300 draws each: none named (an exchange needs each LED 3 times nearer the other's
    place, by 5 times the others' scatter), none in doubt up to 0.5 mm. The others 0.3 mm off make the margin the
    fixed 1 mm: two LEDs 0.8 mm apart exchanged exactly are then in doubt, not named."""
    rng = np.random.default_rng(6)
    for design in (_pairs(0.5), _pairs(0.8), _pairs(1.2), _pairs(0.8, groups=4, per=3)):
        for mm in (0.05, 0.1, 0.2, 0.5, 1.0):
            found = [place_exchanges(design, _common(_scattered(design, mm, rng), rng)) for _ in range(300)]
            assert not any(f.cycles for f in found), (len(design), mm)
            assert mm > 0.5 or not any(f.doubtful for f in found), (len(design), mm)
    design = _pairs(0.8)
    loose = _scattered(design, 0.3, rng)
    loose[[0, 1]] = design[[1, 0]]
    found = place_exchanges(design, loose)
    assert found.margin == 1.0 and found.cycles == [] and found.doubtful == [[0, 1]]


def test_leds_designed_on_a_line_are_aligned_without_a_warning_and_their_exchange_named():
    """Six LEDs on a line (a bar beside a flat gel): the turn about the line is not defined, and SciPy's
    align_vectors warned of it on stderr in the middle of the command's output. Now no warning; the exchange named."""
    import warnings

    design = np.stack([np.linspace(-5.0, 5.0, 6), np.zeros(6), np.full(6, 3.0)], axis=1)
    fitted = _scattered(design, 0.02, np.random.default_rng(7))
    fitted[[1, 2]] = fitted[[2, 1]]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert exchanged_leds(design, fitted) == [[1, 2]]


def test_three_leds_with_two_exchanged_are_not_turned_back_onto_their_design():
    """Three LEDs on a ring with two exchanged are the design turned half round (flipped over): the alignment that
    takes out the LEDs' common turn must not take that, or the exchange would vanish."""
    design = _ring(3)
    fitted = design[[1, 0, 2]] + 0.05
    assert exchanged_leds(design, fitted) == [[0, 1]]


@functools.cache
def _gel() -> tuple[np.ndarray, np.ndarray]:
    """The undeformed synthetic dome's points and normals, (N, 3) each, at every 4th gel pixel."""
    _, pts, normals, valid = synth.surface(synth.camera(), "none")
    return pts[valid][::4], normals[valid][::4]


def _gel_light(leds) -> np.ndarray:
    """(L, N) the undeformed synthetic dome's light of ``leds`` (channels' sum) at :func:`_gel`'s pixels."""
    return led_shading(*_gel(), list(leds)).sum(-1)


def _correlation(images: np.ndarray, model: np.ndarray) -> np.ndarray:
    """(L, L) each image's correlation with each LED's light; on one BLAS thread, as the solve's checks run (two
    threads on a busy 2-core machine took ~0.5 s for each of these small products)."""
    count = len(images)
    with blas_threads(1):
        return np.corrcoef(images, model)[:count, count:]


def _moved(leds, mm: float, rng: np.random.Generator):
    """``leds`` each moved ``mm`` in a random direction (an LED model off the sensor)."""
    places = _scattered(np.array([led.position for led in leds]), mm, rng)
    return [Led(tuple(p), led.direction, led.mu, led.intensity) for p, led in zip(places, leds, strict=True)]


def test_neighbours_images_exchanged_are_named_against_the_led_model_and_a_clean_press_is_not():
    """A press's led_03.png and led_04.png exchanged was solved without a word: neighbours' light correlates above
    the 0.5 of the misplaced images' check. Against their LEDs' modelled light each shows the other's better than
    its own, by far more than the other images misfit theirs; a cycle of three alike."""
    leds = synth.ring_leds()
    model = _gel_light(leds)
    images = model * np.random.default_rng(3).uniform(0.95, 1.05, model.shape[1])  # an albedo, per pixel
    assert exchanged_in_shading(_correlation(images, model)) == []
    assert exchanged_in_shading(_correlation(images[[0, 1, 3, 2, *range(4, 12)]], model)) == [[2, 3]]
    cycle = images[[0, 1, 2, 3, 5, 6, 4, *range(7, 12)]]  # image 5 shows LED 6's light, 6 LED 7's, 7 LED 5's
    assert exchanged_in_shading(_correlation(cycle, model)) == [[4, 5, 6]]


def test_an_led_model_off_the_sensor_is_no_exchange_where_the_gain_alone_would_name_one():
    """LEDs 3 mm from the model's places in random directions (the farthest s31-ledfar starts from), 100 draws: a
    neighbour's modelled light may fit an image better than its own LED's (a cycle of the best assignment, gaining
    up to 0.17 on the twin, as much as some exchanges), but every image then misfits its own LED alike: none named.
    The same LEDs with two images exchanged on a model that fits: named."""
    leds = synth.ring_leds()
    rng = np.random.default_rng(4)
    images = _gel_light(leds)
    cycles = named = 0
    for _ in range(100):
        corr = _correlation(images, _gel_light(_moved(leds, 3.0, rng)))
        best = corr.argmax(axis=1)
        cycles += bool(np.any(best != np.arange(12)))
        named += bool(exchanged_in_shading(corr))
    assert cycles > 0  # the assignment alone would swap some
    assert named == 0
    fitting = _gel_light(_moved(leds, 0.3, rng))  # a model as near as a calibration's
    assert exchanged_in_shading(_correlation(images[[1, 0, *range(2, 12)]], fitting)) == [[0, 1]]


def test_a_flat_image_or_every_image_in_one_exchange_names_nothing_it_cannot_measure():
    """A saturated image's correlation is NaN (no verdict, no crash); two LEDs alone exchanged leave no other image
    to measure the model's error on: nothing named."""
    model = _gel_light(synth.ring_leds())
    images = model.copy()
    images[5] = 1.0
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = _correlation(images, model)
    assert exchanged_in_shading(corr) == []
    two = _correlation(model[[1, 0]], model[:2])
    assert exchanged_in_shading(two) == []


def test_no_image_judged_names_nothing():
    """A press whose LEDs all went unjudged (a dead LED and a lit dark frame: `calibrate-leds` refusing them) gave
    exchanged_in_shading an empty (0, 0) correlation: NumPy's "argmax of an empty sequence" instead of the refusal."""
    assert exchanged_in_shading(np.zeros((0, 0))) == []
