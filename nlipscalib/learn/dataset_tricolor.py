"""A calibration dataset's presses whose tri-colour frame does not hold their LED images' light: left out, or kept
on request, and a whole session that disagrees the same way refused in one line.

Why: the dataset pairs each press's tri-colour pixels with normals solved from its LED images, and the tri-colour
frame is NLiPsNet's only input. A press whose frame disagrees with its LED images (two images of different colour
groups captured in each other's place, its channels in another order, a frame of another press) teaches the network
colours its labels do not have, silently: ``nlips calibrate`` neither refused nor warned of it (s37-swapcheck's
"not done"). The check is :mod:`nlipscalib.core.tricolor_check`'s, the one the solve, ``nlips capture`` and ``nlips
calibrate-leds`` run; its verdict is recorded in each press's index entry (``tricolor``), so a resumed build keeps
it with the shard, and the presses left out in index.json's ``tricolor`` (docs/formats.md, "Calibration dataset").
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Sequence
from pathlib import Path

from ..core.errors import ConfigError
from ..core.press_meta import led_image_name

KEEP_OPTION = "--keep-tricolor-mismatch"
"""The ``nlips calibrate`` option that keeps such presses (``build_dataset(keep_tricolor=True)``)."""
RECORD_KEY = "tricolor"
"""The key of the verdict in each press's index entry, and of the build's record in index.json."""

log = logging.getLogger(__name__)


def disagrees(record: object) -> bool:
    """Whether an index entry's ``tricolor`` record says its frame does not hold its LED images' light (an entry of
    an older build, or of an experiment, has none: not known to)."""
    from ..core.tricolor_check import DISAGREE  # where read: reading a dataset needs no capture modules

    return isinstance(record, dict) and record.get("verdict") in DISAGREE


def reordered(report: dict) -> set[int]:
    """The LEDs (0-based) whose images the press's solve used in another place than captured (report.json
    ``led_order``: the LED images out of order, solved in the order they show; ``solver.led_checks``): an exchange of
    theirs the tri-colour frame shows is the one the solve mended, its labels made from the images in their LEDs'
    order, which the frame fits (``core.tricolor_check``'s ``said``)."""
    order = report.get("led_order")
    if not isinstance(order, list):
        return set()
    return {k for k, led in enumerate(order) if led != k}


MENDABLE = ("exchanged",)
"""The verdicts a press's solve may mend: two LED images of different groups in each other's place, which the
solve's LED checks may find and solve in the order they show (report.json ``led_order``); the frame then fits
(``said``). Every other disagreement stands whatever the solve finds (:func:`judged_before_solve`)."""


def judged_before_solve(record: object) -> bool:
    """Whether a press's ``tricolor`` record, judged from its capture alone, leaves it out of the dataset whatever
    its solve finds (a verdict that disagrees and is not :data:`MENDABLE`): ``nlips calibrate`` then says so and
    leaves it unsolved."""
    return disagrees(record) and record.get("verdict") not in MENDABLE


def left_out_line(record: dict, solved: bool = True) -> str:
    """The line for a press left out for its tri-colour frame (``record``: its verdict, with its ``line``);
    ``solved``: False where it is left out before its solve."""
    done = "" if solved else " not solved, and"
    return (
        f"{record['line']};{done} left out of the dataset, whose network it would teach colours its normals do not "
        f"have: capture it again, or keep it with {KEEP_OPTION}"
    )


def sort_presses(
    entries: list[dict],
    reference: dict,
    reference_folder: Path,
    where: Path,
    keep: bool,
    said: Collection[str] = (),
) -> tuple[list[dict], list[dict]]:
    """The entries the dataset indexes and the presses it leaves out for their tri-colour frame.

    Parameters
    ----------
    entries : the presses' index entries, each with its ``tricolor`` record (``TricolorVerdict.record``)
    reference : the undeformed capture's record, ``reference_folder`` its folder
    where : what the line about a whole session names (the presses' folder)
    keep : keep the presses that disagree (``--keep-tricolor-mismatch``), each warned of
    said : the names of presses whose line was said before their solve (:func:`judged_before_solve`): left out
        without saying it again

    Returns
    -------
    kept : the entries indexed, in their order
    left_out : ``{"name", "folder", "tricolor"}`` of each press left out, in their order (each said in one line)

    Raises ConfigError (without ``keep``): every capture judged (two or more, the undeformed one among them)
    disagrees the same way (:func:`session_line`: a camera's colour order, the controller's pattern or LED order);
    or the undeformed capture's frame disagrees (the dataset's reference frame, against which every press's
    contact is told).
    """
    judged = [r for r in (reference, *(e.get(RECORD_KEY) for e in entries)) if _judged(r)]
    if len(judged) >= 2 and all(disagrees(r) for r in judged) and len({_signature(r) for r in judged}) == 1:
        line = session_line(where, judged[0], len(judged), keep)
        if not keep:
            raise ConfigError(line)
        log.warning("%s", line)
        return entries, []
    if disagrees(reference):
        line = f"{reference['line']}; it is the dataset's undeformed reference frame, against which every press's "
        if not keep:
            raise ConfigError(f"{line}contact is told: capture it again, or pass {KEEP_OPTION} to use it as captured")
        log.warning("%scontact is told; kept (%s)", line, KEEP_OPTION)
    kept, left_out = [], []
    for entry in entries:
        record = entry.get(RECORD_KEY)
        if not disagrees(record):
            kept.append(entry)
        elif keep:
            log.warning("%s; kept in the dataset (%s)", record["line"], KEEP_OPTION)
            kept.append(entry)
        else:
            if entry["name"] not in said:
                log.error("%s", left_out_line(record))
            left_out.append({"name": entry["name"], "folder": entry["folder"], RECORD_KEY: record})
    return kept, left_out


def session_line(where: Path, record: dict, count: int, keep: bool = False) -> str:
    """The one line for ``count`` captures (the undeformed one among them) whose tri-colour frames all disagree
    with their LED images as ``record`` says: what they hold, the likely cause, and what to do (``keep``: that they
    were kept, on request)."""
    verdict = record["verdict"]
    if verdict == "colours":
        from ..core.tricolor_check import sources_said

        how = f"each holds the LED groups' light in other colours ({sources_said(record['sources'])})"
        cause = (
            "the camera's colour order (a camera or reader that gives BGR for RGB) or the LED controller's "
            "tri-colour pattern"
        )
    elif verdict == "exchanged":
        i, j = record["exchanged"]
        how = f"each fits with {led_image_name(i)} and {led_image_name(j)} exchanged (LEDs {i + 1} and {j + 1})"
        cause = "the LED controller's LED order, or the order the images were written in"
    else:
        how = "no exchange of two LED images mends them"
        cause = "the LED controller's tri-colour pattern, or frames written under each other's names"
    head = (
        f"{where}: every capture's tri-colour frame ({count}, the undeformed one's among them) disagrees with its LED "
        f"images the same way: {how}: {cause}, for the whole session"
    )
    if keep:
        return (
            f"{head}; the dataset is built from the frames as captured ({KEEP_OPTION}): every frame `nlips infer` is "
            "given must be captured alike"
        )
    return (
        f"{head}. A dataset of them would teach NLiPsNet colours its LED images' normals do not have: fix it and "
        f"capture again, or pass {KEEP_OPTION} to build it from the frames as captured (then every frame `nlips "
        "infer` is given must be captured alike)"
    )


def _judged(record: object) -> bool:
    return isinstance(record, dict) and (record.get("verdict") in ("fits", "said") or disagrees(record))


def _signature(record: dict) -> tuple:
    """What two disagreeing captures share when they disagree the same way: the verdict, the channels' groups and
    the exchanged pair."""
    return record["verdict"], _tuple(record.get("sources")), _tuple(record.get("exchanged"))


def _tuple(value: Sequence[int] | None) -> tuple | None:
    return None if value is None else tuple(value)


def index_record(reference: dict, left_out: list[dict], keep: bool) -> dict:
    """index.json's ``tricolor``: the undeformed capture's verdict, whether presses that disagree were kept
    (``keep``), and those left out."""
    return {"reference": reference, "kept_disagreeing": keep, "left_out": left_out}
