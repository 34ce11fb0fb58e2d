"""The calibration dataset's sorting of presses by their tri-colour verdict (learn.dataset_tricolor): which are left
out, kept, and when a whole session disagreeing alike is one refusal (known answers on verdict records)."""

import logging
from pathlib import Path

import pytest

from nlipscalib.core.errors import ConfigError
from nlipscalib.learn.dataset_tricolor import (
    KEEP_OPTION,
    disagrees,
    judged_before_solve,
    left_out_line,
    reordered,
    session_line,
    sort_presses,
)

FITS = {"verdict": "fits", "misfit": [0.015, 0.015, 0.015], "sources": [0, 1, 2], "exchanged": None}
BGR = {"verdict": "colours", "misfit": [0.01] * 3, "sources": [2, 1, 0], "exchanged": None, "line": "P: BGR"}
SWAP45 = {"verdict": "exchanged", "misfit": [0.04, 0.04, 0.01], "sources": [0, 1, 2], "exchanged": [3, 4]}
SWAP45 |= {"line": "P: led_04.png / led_05.png"}
UNJUDGED = {"verdict": "not judged", "misfit": None, "sources": None, "exchanged": None}


def _entries(*records):
    return [{"name": f"press_{i:04d}", "folder": f"/p/press_{i:04d}", "tricolor": r} for i, r in enumerate(records, 1)]


def test_a_press_that_disagrees_is_left_out_and_one_that_fits_or_is_unjudged_or_older_is_kept(caplog):
    entries = _entries(FITS, BGR, UNJUDGED, FITS)
    entries.append({"name": "press_0005", "folder": "/p/press_0005"})  # an older build's entry: no verdict
    kept, left = sort_presses(entries, FITS, Path("/p/reference"), Path("/p"), keep=False)
    assert [e["name"] for e in kept] == ["press_0001", "press_0003", "press_0004", "press_0005"]
    assert left == [{"name": "press_0002", "folder": "/p/press_0002", "tricolor": BGR}]
    (record,) = [r for r in caplog.records if r.levelno == logging.ERROR]
    assert record.getMessage().startswith("P: BGR; left out of the dataset") and KEEP_OPTION in record.getMessage()
    kept, left = sort_presses(entries, FITS, Path("/p/reference"), Path("/p"), keep=True)
    assert len(kept) == 5 and left == []


def test_every_capture_disagreeing_alike_is_one_refusal_and_unlike_ways_are_not():
    with pytest.raises(ConfigError, match=r"^/p: every capture's tri-colour frame \(4, the undeformed one's among"):
        sort_presses(_entries(BGR, BGR, BGR), BGR, Path("/p/reference"), Path("/p"), keep=False)
    # unjudged captures do not stop it; two ways of disagreeing are each press's own
    with pytest.raises(ConfigError, match="each fits with led_04.png and led_05.png exchanged"):
        sort_presses(_entries(SWAP45, UNJUDGED, SWAP45), SWAP45, Path("/p/reference"), Path("/p"), keep=False)
    kept, left = sort_presses(_entries(BGR, SWAP45, FITS), FITS, Path("/p/reference"), Path("/p"), keep=False)
    assert [e["name"] for e in kept] == ["press_0003"] and len(left) == 2
    # one press and an undeformed capture that fits: that press's own line, not the session's
    kept, left = sort_presses(_entries(BGR), FITS, Path("/p/reference"), Path("/p"), keep=False)
    assert kept == [] and [g["name"] for g in left] == ["press_0001"]


def test_an_undeformed_capture_that_disagrees_alone_is_refused_unless_kept(caplog):
    with pytest.raises(ConfigError, match="^P: BGR; it is the dataset's undeformed reference frame"):
        sort_presses(_entries(FITS, FITS), BGR, Path("/p/reference"), Path("/p"), keep=False)
    kept, left = sort_presses(_entries(FITS, FITS), BGR, Path("/p/reference"), Path("/p"), keep=True)
    assert len(kept) == 2 and left == [] and "kept (--keep-tricolor-mismatch)" in caplog.text


def test_the_session_line_names_what_each_way_of_disagreeing_holds():
    assert "its red channel the blue group's, its blue channel the red group's" in session_line(Path("/p"), BGR, 3)
    assert "BGR for RGB" in session_line(Path("/p"), BGR, 3)
    assert "(LEDs 4 and 5)" in session_line(Path("/p"), SWAP45, 3)
    assert KEEP_OPTION in session_line(Path("/p"), BGR, 3, keep=True) and "fix it" not in session_line(
        Path("/p"), BGR, 3, keep=True
    )
    assert disagrees(BGR) and disagrees(SWAP45) and not disagrees(FITS) and not disagrees(UNJUDGED)
    assert not disagrees(None)


def test_the_leds_a_solve_used_in_another_place_are_those_its_report_moved():
    """A solve that found two LED images out of order used them in the order they show (report.json led_order): the
    tri-colour frame's exchange of those two is the one it mended (core.tricolor_check's ``said``), not a reason to
    leave the press out; a "said" verdict counts as judged and agreeing."""
    assert reordered({"led_order": [8, 1, 2, 3, 4, 5, 6, 7, 0, 9, 10, 11]}) == {0, 8}
    assert reordered({"led_order": list(range(12))}) == set() and reordered({}) == set()
    said = FITS | {"verdict": "said", "exchanged": [0, 8]}
    assert not disagrees(said)
    with pytest.raises(ConfigError, match="undeformed reference frame"):  # judged: not a session of one way
        sort_presses(_entries(said, said), BGR, Path("/p/reference"), Path("/p"), keep=False)


def test_only_an_exchange_waits_for_the_solve_and_a_press_said_before_it_is_not_said_again(caplog):
    """`nlips calibrate` leaves a press out before its solve when its verdict stands whatever the solve finds (other
    colours, no exchange that mends it); an exchanged pair may be mended by the solve (its LED checks solve the two
    images in the order they show: "said"), so it is solved and judged after. The build then leaves the press
    judged before out without its line a second time."""
    misfit = {"verdict": "misfit", "misfit": [0.05] * 3, "sources": [0, 1, 2], "exchanged": None, "line": "P: other"}
    assert judged_before_solve(BGR) and judged_before_solve(misfit)
    assert not judged_before_solve(SWAP45) and not judged_before_solve(FITS) and not judged_before_solve(UNJUDGED)
    assert not judged_before_solve(FITS | {"verdict": "said", "exchanged": [3, 4]}) and not judged_before_solve(None)
    assert left_out_line(BGR, solved=False).startswith("P: BGR; not solved, and left out of the dataset")
    assert left_out_line(BGR).startswith("P: BGR; left out of the dataset") and KEEP_OPTION in left_out_line(BGR)
    entries = _entries(BGR, FITS, misfit)
    kept, left = sort_presses(entries, FITS, Path("/p/reference"), Path("/p"), keep=False, said={"press_0001"})
    assert [e["name"] for e in kept] == ["press_0002"] and [g["name"] for g in left] == ["press_0001", "press_0003"]
    (record,) = [r for r in caplog.records if r.levelno == logging.ERROR]
    assert record.getMessage().startswith("P: other; left out of the dataset")
