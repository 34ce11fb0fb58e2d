"""Consecutive LEDs whose frames the lag-band check cannot tell apart over much of the gel: said once, not silently.

Why: the lag-band check (:func:`nlipscalib.core.repeated_frames.lagged_bands`) counts a line of blocks only where
the LED model lights the gel differently (by :data:`~nlipscalib.core.tolerances.LAGGED_BAND_CONTRAST`) from the
frame's LED and the previous one: LEDs designed in close pairs light the gel far from the pair alike, and the images
alone called those lines the previous LED's light (s35-pairband). There a frame read out across the switch between
the two LEDs of a pair cannot be seen, and a user was told nothing (a lag of 3/8 of the frame between LEDs 0.5 mm
apart was found on 4 of 16 injections). Each such pair is now named once per command where the check runs
(``nlips solve``, ``nlips calibrate-leds``, ``nlips capture``) and in the solve's report.json (s36-lagcost).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from . import said_once
from .repeated_frames import MIN_LIT_ROW_BLOCKS, Lines, ModelLight, gel_blocks, median_at_least, model_blocks
from .tolerances import LAG_BLIND_SHARE, LAGGED_BAND_CONTRAST, LAGGED_BAND_ROWS

log = logging.getLogger(__name__)


class BlindPair(NamedTuple):
    """Two consecutive LEDs (capture order) a lag between which the lag-band check cannot see over much of the gel."""

    leds: tuple[int, int]
    """The previous LED and the LED (0-based, capture order): the second's frame holding the first's light."""
    unseen: float
    """The largest share of the gel's rows (or columns) that such a band, read from the frame's edge, can cover and
    not be found, beyond the :data:`~nlipscalib.core.tolerances.LAGGED_BAND_ROWS` lines any band needs."""
    apart: float
    """The two LEDs' distance, mm (their design's, or the solve's LEDs)."""

    def to_dict(self) -> dict:
        """The report.json entry: ``{"leds": [previous, led], "unseen": share, "apart_mm": mm}``."""
        return {"leds": list(self.leds), "unseen": round(self.unseen, 3), "apart_mm": round(self.apart, 3)}


def lag_blind_pairs(expected: object, gel: np.ndarray) -> list[BlindPair]:
    """The consecutive LEDs (capture order) whose modelled light on the gel is too alike for the lag-band check to
    see a lag between them over :data:`~nlipscalib.core.tolerances.LAG_BLIND_SHARE` or more of the gel's rows or
    columns from an edge (:class:`BlindPair`); none without the LED model (``expected`` not a ModelLight).

    The lines are the check's (:func:`nlipscalib.core.repeated_frames.lagged_bands`: 5x5 blocks wholly on the gel,
    :data:`~nlipscalib.core.repeated_frames.MIN_LIT_ROW_BLOCKS` or more a line), each LED's light the check's own
    (:func:`nlipscalib.core.repeated_frames.model_blocks`, kept per design in this process: ~0.1 ms when the check
    ran). A line counts as the check counts it with the model: the two LEDs' light differs there by
    :data:`~nlipscalib.core.tolerances.LAGGED_BAND_CONTRAST` or more in median over its blocks (all of them: which
    blocks the images light is the capture's).

    Parameters
    ----------
    expected : ModelLight -- the capture's LED model (:func:`nlipscalib.core.repeated_frames.model_light`).
    gel : (H, W) bool -- the pixels that see the gel.

    Returns
    -------
    list of BlindPair, in capture order; empty when none is blind (every shipped design).
    """
    if not isinstance(expected, ModelLight) or len(expected.leds) < 2:
        return []
    inside = gel_blocks(gel)
    model = model_blocks(expected, inside)
    if model.blind is None:
        positions = np.array([led.position for led in expected.leds], float)
        found = []
        for led in range(1, len(expected.leds)):
            unseen = max(
                _unseen(turn(model.contrast(led, led - 1)), turn(inside)) for turn in (np.asarray, np.transpose)
            )
            if unseen >= LAG_BLIND_SHARE:
                found.append(
                    BlindPair((led - 1, led), unseen, float(np.linalg.norm(positions[led] - positions[led - 1])))
                )
        model.blind = found
    return list(model.blind)


def _unseen(contrast: np.ndarray, inside: np.ndarray) -> float:
    """The largest share of the counted lines (rows of ``inside``, (h, w) bool, with enough blocks) that a band from
    either end can cover, beyond :data:`~nlipscalib.core.tolerances.LAGGED_BAND_ROWS`, before it holds that many
    lines whose ``contrast`` (h, w) tells the two LEDs apart (the band the check finds needs them); 0 where every
    line tells, 1 where fewer than that many do."""
    lines = Lines(inside, np.count_nonzero(inside, axis=1))
    counted = lines.count >= MIN_LIT_ROW_BLOCKS
    total = int(counted.sum())
    if total <= LAGGED_BAND_ROWS:
        return 0.0
    tells = median_at_least(contrast, lines, counted, LAGGED_BAND_CONTRAST)
    reach = 0
    for order in (tells, tells[::-1]):
        at = np.flatnonzero(order)
        reach = max(reach, int(at[LAGGED_BAND_ROWS - 1]) + 1 if len(at) >= LAGGED_BAND_ROWS else total)
    return (reach - LAGGED_BAND_ROWS) / (total - LAGGED_BAND_ROWS)


def lag_blind_line(folder: object, pairs: Sequence[BlindPair]) -> str:
    """One line naming the LED pairs the lag-band check is blind to (1-based, as the solve's LED lines), how much,
    why and what keeps such a lag from happening."""
    said = ", ".join(
        f"{pair.leds[0] + 1} to {pair.leds[1] + 1} ("
        + (
            f"{pair.apart:.1f} mm apart: a band over up to {100 * pair.unseen:.0f} % of the rows or columns from an "
            "edge)"
            if k == 0
            else f"{pair.apart:.1f} mm, {100 * pair.unseen:.0f} %)"
        )
        for k, pair in enumerate(pairs)
    )
    return (
        f"{folder}: the lag-band check cannot see a frame read out across the switch of LEDs {said}: the LED model "
        f"lights the gel within {100 * LAGGED_BAND_CONTRAST:.0f} % alike from the two LEDs of each over those lines, "
        "where the second's frame holding the first's light looks like its own; capture with --flush 1 or more "
        "(frames dropped after each LED change, default 2) so that no frame is read across a switch"
    )


def say_lag_blind(folder: object, expected: object, gel: np.ndarray | None) -> list[BlindPair]:
    """:func:`lag_blind_pairs`, said in one INFO line (:func:`lag_blind_line`) the first time this command meets the
    design (its LEDs and camera: a session's presses, a calibration's captures, said once: core.said_once)."""
    if gel is None or not isinstance(expected, ModelLight):
        return []
    pairs = lag_blind_pairs(expected, gel)
    key = f"lag blind\0{expected.camera!r}\0{tuple(expected.leds)!r}\0{gel.shape}"
    if pairs and said_once.first_time(key):
        log.info("%s", lag_blind_line(folder, pairs))
    return pairs
