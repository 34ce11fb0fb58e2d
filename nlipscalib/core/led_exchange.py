"""LED images captured in each other's place, told by where their LEDs were fitted against the sensor's design.

Two neighbouring LEDs' images exchanged (the LED wiring, the controller's LED order or the capture's image order) are
not seen by the images alone: neighbours light the dome alike (their images correlate above the 0.5 the solve's
check needs, :data:`nlipscalib.solver.led_checks.MATCH_CORRELATION`), so ``nlips calibrate-leds`` fits each LED where
its image shows it, LED 3 at LED 4's place and back, and calls the fit reliable (the twin's 160x120 undeformed dome
with led_03.png and led_04.png exchanged: both 4.68 mm from their design places, 0.19-0.28 mm from each other's;
benchmarks/RESULTS.md, s33-ledswap). The best one-to-one assignment of the fitted LEDs to the design's places
(:func:`scipy.optimize.linear_sum_assignment`, the Hungarian method SciPy keeps) names such an exchange when it is not
the identity and explains the misfit by a wide margin (:func:`exchanged_leds`). Several captures calibrated together
are first compared image by image (:func:`exchanged_images`): one holding its images in another order than the
first is told by the images alone. A solve's press, without an LED fit, is told by its images against its LED model's
light (:func:`exchanged_in_shading`), and against the undeformed capture it is solved with by :func:`exchanged_images`.
In core beside the other LED comparisons (:mod:`nlipscalib.core.led_change`); the solver's calibration and solve wire
them.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from . import tolerances

FAR_MM = 1e9
"""The distance an LED not fitted is given to every place but its own (mm): it never takes another's."""


class PlaceExchanges(NamedTuple):
    """What :func:`place_exchanges` found: the exchanges, and the distances they were told by."""

    cycles: list[list[int]]
    """Each exchange's LEDs (0-based), from its lowest, in the assignment's order (``[2, 3]``: LED 3 sits at LED 4's
    place and LED 4 at LED 3's); empty when none."""
    aligned: np.ndarray
    """(L, 3) float, mm, the design's frame: the fitted places with the LEDs' common shift, turn and scale taken out
    (:func:`aligned_places`)."""
    scatter: float
    """mm: the median distance of the LEDs assigned their own place (not held) from it, aligned: the calibration's
    own scatter about the design (inf: no such LED)."""
    margin: float
    """mm: how much nearer another place than its own an LED of an exchange had to be (:func:`exchange_margin`)."""
    doubtful: list[list[int]]
    """The cycles whose LEDs each sit :data:`~nlipscalib.core.tolerances.LED_EXCHANGE_NEARER` times nearer the place
    they are assigned than their own, but not by ``margin``: an exchange the calibration's scatter leaves in doubt
    (LEDs designed closer than ~5 times it); as ``cycles``."""


def exchanged_leds(design: ArrayLike, fitted: ArrayLike, left_out: tuple[int, ...] | list[int] = ()) -> list[list[int]]:
    """The cycles of LEDs whose fitted places are each the design place of the next (two exchanged images: a pair):
    :func:`place_exchanges`' ``cycles``.

    Parameters
    ----------
    design : (L, 3) float, mm, camera frame -- the LEDs' places as designed (the calibration's start).
    fitted : (L, 3) float, mm, camera frame -- the calibrated LEDs' places, in the same order.
    left_out : LEDs (0-based) not fitted (kept at their start): never part of an exchange.

    Returns
    -------
    list of list of int -- each exchange's LEDs (0-based), from its lowest, in the assignment's order; empty when none.
    """
    return place_exchanges(design, fitted, left_out).cycles


def place_exchanges(design: ArrayLike, fitted: ArrayLike, left_out: tuple[int, ...] | list[int] = ()) -> PlaceExchanges:
    """The cycles of LEDs whose fitted places are each the design place of the next, and the distances that tell them.

    The fitted LEDs, their common shift, turn and scale taken out (:func:`aligned_places`), are assigned one-to-one to
    the design's places at the least summed distance; each cycle of that assignment (an LED assigned to another's
    place, which is assigned on, back to the first) is an exchange when every LED of it sits
    :data:`~nlipscalib.core.tolerances.LED_EXCHANGE_NEARER` times nearer the place it is assigned than its own, and
    nearer by :func:`exchange_margin` at least: 1 mm, or less where the other LEDs scatter little about their places.

    Why the ratio: a sensor built off its design (an LED 3 mm from its place, the farthest the project's starts are
    tried from, s31-ledfar) may sit nearer a neighbour's place than its own, but not 3 times nearer on the default ring
    (neighbours 4.66 mm apart: at best 1.66 mm from it); an LED whose fit ran off onto a neighbour's place makes a
    cycle with that neighbour, which did not move (not nearer another's). Why the margin follows the scatter: a fixed
    1 mm (s33-ledswap) missed every exchange of LEDs designed closer than ~1.1 mm however exactly they were fitted
    (the twin's LEDs in pairs 0.8 mm apart: exchanged, fitted 0.02-0.08 mm from each other's places, the others
    0.03-0.05 mm from theirs; benchmarks/RESULTS.md, s35-exchange). Why the common part out: an LED's best point sits
    behind its emitting disk (0.23 mm for the twin's 3.6 mm disks), alike for every LED, which inflated each distance
    (the default ring's clean points 0.19-0.23 mm from their places, median; 0.04-0.07 mm with it out) and, added to
    an exchanged LED's distance from the place it holds, could cost it the ratio on a close design; a common offset
    alone never makes a cycle of LEDs each nearer the other's place.

    Parameters
    ----------
    design : (L, 3) float, mm, camera frame -- the LEDs' places as designed (the calibration's start).
    fitted : (L, 3) float, mm, camera frame -- the calibrated LEDs' places, in the same order.
    left_out : LEDs (0-based) not fitted (kept at their start): never part of an exchange, nor of the alignment.

    A cycle whose LEDs are each 3 times nearer, but not by the margin, is returned as ``doubtful``: on random fits and
    builds 0.05-0.5 mm off, close designs included, no such cycle came up (300 draws each; 3 of 300 at 1 mm off on
    pairs 0.8 mm apart, a build that would have put LEDs through each other), while an exchange of LEDs designed
    closer than the margin allows often is one.

    Returns
    -------
    PlaceExchanges -- the cycles (empty when none), the aligned places, the scatter, the margin and the doubtful
    cycles.
    """
    from scipy.optimize import linear_sum_assignment

    design = np.asarray(design, np.float64)
    held = sorted(int(i) for i in left_out)
    aligned = aligned_places(design, fitted, held)
    cost = np.linalg.norm(aligned[:, None, :] - design[None, :, :], axis=2)  # (fitted, design)
    cost[held, :] = FAR_MM  # a held LED keeps its own place only
    cost[held, held] = 0.0
    rows, place = linear_sum_assignment(cost)
    assigned = place[np.argsort(rows)]
    own = np.diag(cost)
    there = cost[np.arange(len(own)), assigned]
    still = assigned == np.arange(len(own))
    still[held] = False
    scatter = float(np.median(own[still])) if still.any() else float("inf")
    margin = exchange_margin(scatter)
    nearer = own >= tolerances.LED_EXCHANGE_NEARER * there
    cycles = _cycles(assigned, nearer & (own - there >= margin))
    doubtful = [cycle for cycle in _cycles(assigned, nearer) if cycle not in cycles]
    return PlaceExchanges(cycles, aligned, scatter, margin, doubtful)


def exchange_margin(scatter: float) -> float:
    """How much nearer (mm) another LED's design place than its own a fitted LED must sit to be part of an exchange:
    :data:`~nlipscalib.core.tolerances.LED_EXCHANGE_SCATTER` times ``scatter`` (mm, the other LEDs' median distance
    from their places, :func:`place_exchanges`), within [:data:`~nlipscalib.core.tolerances.LED_EXCHANGE_MIN_MM`,
    :data:`~nlipscalib.core.tolerances.LED_EXCHANGE_MM`]."""
    relative = tolerances.LED_EXCHANGE_SCATTER * scatter
    return float(min(tolerances.LED_EXCHANGE_MM, max(tolerances.LED_EXCHANGE_MIN_MM, relative)))


def aligned_places(design: ArrayLike, fitted: ArrayLike, left_out: tuple[int, ...] | list[int] = ()) -> np.ndarray:
    """The fitted places brought onto the design by the similarity (shift, turn, scale) that best maps the design's
    places onto them: what the LEDs' fit shares, taken out (an LED's best point behind its emitting disk, a ring
    built turned). The turn is :meth:`scipy.spatial.transform.Rotation.align_vectors` (Kabsch, SciPy's), the scale
    the ratio of the two sets' spreads about their centres.

    A turn above :data:`~nlipscalib.core.tolerances.LED_ALIGN_MAX_TURN_DEG` is not taken (shift and scale only): no
    fit turns a whole ring so far, while a few LEDs' mirror image is a half turn away (three LEDs on a ring with two
    exchanged are the design flipped over).

    Parameters
    ----------
    design, fitted : (L, 3) float, mm, camera frame -- the LEDs' places as designed and as fitted, in the same order.
    left_out : LEDs (0-based) not fitted: not used to find the similarity (returned moved with the others).

    Returns
    -------
    (L, 3) float, mm -- ``fitted`` in the design's frame; ``fitted`` itself when fewer than three LEDs are fitted.
    """
    from scipy.spatial.transform import Rotation

    design, fitted = np.asarray(design, np.float64), np.asarray(fitted, np.float64)
    use = np.ones(len(design), bool)
    use[list(left_out)] = False
    if use.sum() < 3:
        return fitted
    centre_d, centre_f = design[use].mean(axis=0), fitted[use].mean(axis=0)
    a, b = design[use] - centre_d, fitted[use] - centre_f
    spread = float(np.sum(a * a))
    if spread == 0.0:  # every LED designed at one place: nothing to turn or scale
        return fitted - centre_f + centre_d
    with warnings.catch_warnings():
        # LEDs designed on a line: the turn about it is any (SciPy warns on stderr); none moves them
        warnings.filterwarnings("ignore", "Optimal rotation is not uniquely", UserWarning)
        turn = Rotation.align_vectors(b, a)[0]
    if turn.magnitude() > np.radians(tolerances.LED_ALIGN_MAX_TURN_DEG):
        turn = Rotation.identity()
    scale = np.sqrt(np.sum(b * b) / spread)
    return centre_d + turn.inv().apply(fitted - centre_f) / scale


def exchanged_images(reference: np.ndarray, images: np.ndarray) -> list[list[int]]:
    """The cycles of LED images of one capture that show the light another capture's images of other LEDs show: the
    same sensor's captures in different LED orders.

    Each image of ``images`` is assigned one-to-one to an image of ``reference`` at the largest summed correlation
    (:func:`scipy.optimize.linear_sum_assignment`); a cycle of that assignment is an exchange when each of its images
    correlates at least :data:`~nlipscalib.core.tolerances.IMAGE_EXCHANGE_GAIN` better with the image it is assigned
    than with its own LED's. Why: the undeformed dome's images of one LED in two captures correlate 0.9987 or more
    (the twin's 160x120 seeds 7 and 8), two neighbours' 0.83 at most; two of them exchanged in one capture, 0.71 with
    their own and 0.999 with each other's. Calibrated together, such captures pulled both LEDs halfway (3 mm off) and
    were refused as a contact "in LED 4's image: LED 4 sits 9.9 mm from the gel" (s33-ledswap).

    Parameters
    ----------
    reference, images : (L, N) float -- two captures' LED images over the same N gel pixels (linear, e.g. the
        channels' mean), in their captured order.

    Returns
    -------
    list of list of int -- each exchange's images (0-based) in ``images``, from its lowest, in the assignment's order
    (``[2, 3]``: image 3 shows what ``reference``'s image 4 shows, and image 4 what its image 3 shows); empty when none.
    """
    count = len(reference)
    with np.errstate(invalid="ignore", divide="ignore"):  # a flat image (saturated throughout): no correlation
        corr = np.corrcoef(images, reference)[:count, count:]
    assigned, gain = _best_assignment(corr)
    return _cycles(assigned, gain >= tolerances.IMAGE_EXCHANGE_GAIN)


def exchanged_in_shading(corr: ArrayLike) -> list[list[int]]:
    """The cycles of LED images that show other LEDs' modelled light (the LED model's shading of the undeformed
    dome) better than their own's, by more than the model's own error explains: one capture's images against its
    LED model, without another capture to compare with (``nlips solve``).

    As :func:`exchanged_images`, on the correlations of each image with each LED's modelled light: a cycle of the
    assignment at the largest summed correlation is an exchange when each of its images correlates better with the
    LED it is assigned than with its own by :data:`~nlipscalib.core.tolerances.MODEL_EXCHANGE_FACTOR` times the
    median misfit of the other images to their own LEDs (one minus their correlation), and by
    :data:`~nlipscalib.core.tolerances.MODEL_EXCHANGE_MIN_GAIN` at least. Why relative to the others' misfit, not
    by a fixed gain as between two captures: an LED model off the sensor (LEDs 3 mm from their places, in random
    directions) lets two neighbours' images gain up to 0.17 over their own LEDs' light, as much as some exchanges
    gain (0.15-0.29 on the default twin, 0.04-0.28 on the capsule's denser ring), but then every image misfits its
    own LED alike: such cycles gain at most 3.8 times the others' median misfit, an exchange on a sensor its model
    describes 8 times or more (benchmarks/RESULTS.md, s34-solveswap).

    Parameters
    ----------
    corr : (L, L) float -- the correlation over the gel of each LED image (rows, the capture's order) with each
        LED's modelled light (columns, the same LEDs); NaN: no correlation (a flat image).

    Returns
    -------
    list of list of int -- each exchange's images (0-based rows of ``corr``), from its lowest, in the assignment's
    order (``[2, 3]``: image 3 shows LED 4's light and image 4 LED 3's); empty when none, or when every image is in
    one (no others to measure the model's error on).
    """
    assigned, gain = _best_assignment(corr)
    misfit = 1.0 - np.diag(np.nan_to_num(np.asarray(corr, np.float64), nan=-1.0))
    found = []
    for cycle in _cycles(assigned, gain >= tolerances.MODEL_EXCHANGE_MIN_GAIN):
        others = np.delete(misfit, cycle)
        if others.size and gain[cycle].min() >= tolerances.MODEL_EXCHANGE_FACTOR * np.median(others):
            found.append(cycle)
    return found


def _best_assignment(corr: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Each image's (row's) assigned column of ``corr`` ((L, L) correlations, NaN taken as -1) one-to-one at the
    largest summed correlation (:func:`scipy.optimize.linear_sum_assignment`), and what each gains by it over its
    own column: two (L,) arrays, int and float.

    When every row correlates best with its own column the identity is that assignment (it reaches the sum of the
    rows' maxima, which no assignment exceeds), and SciPy is not asked: importing :mod:`scipy.optimize` took ~0.5 s
    that a clean press's ``nlips solve`` never otherwise spends (:mod:`nlipscalib.solver.led_fit` says so too)."""
    corr = np.nan_to_num(np.asarray(corr, np.float64), nan=-1.0)
    own = np.arange(len(corr))
    if corr.size == 0 or np.array_equal(corr.argmax(axis=1), own):  # no images judged (a dead LED's press): none
        return own, np.zeros(len(corr))
    from scipy.optimize import linear_sum_assignment

    rows, place = linear_sum_assignment(corr, maximize=True)
    assigned = place[np.argsort(rows)]
    return assigned, corr[np.arange(len(corr)), assigned] - np.diag(corr)


def _cycles(assigned: np.ndarray, exchange: np.ndarray) -> list[list[int]]:
    """The cycles of the assignment ``assigned`` (each index to another) whose members are all ``exchange``."""
    cycles, seen = [], set()
    for start in range(len(assigned)):
        if assigned[start] == start or start in seen:
            continue
        cycle, i = [], start
        while i not in cycle:
            cycle.append(i)
            i = int(assigned[i])
        seen.update(cycle)
        if all(exchange[i] for i in cycle):
            cycles.append(cycle)
    return cycles
