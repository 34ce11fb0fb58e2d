"""The warning for a contact too small, in pixels, for the steepness of its normals (solver.resolution)."""

import numpy as np
import pytest

from nlipscalib.core import load_press, tolerances
from nlipscalib.solver import solve_press
from nlipscalib.solver.contact import ContactMap
from nlipscalib.solver.resolution import contact_steepness, resolution_note

SHAPE = (120, 160)


def _dent(radius: float, tilt_deg: float):
    """A ContactMap hit on a disk of ``radius`` px, flat undeformed normals, and normals tilted by ``tilt_deg``
    on the disk."""
    rows, cols = np.indices(SHAPE)
    disk = (rows - 60) ** 2 + (cols - 80) ** 2 <= radius**2
    misfit = np.where(disk, 20.0, 1.0)
    contact = ContactMap(misfit, np.ones(SHAPE), (0, 1, 2), (), 0.01, np.ones(SHAPE))
    reference = np.zeros(SHAPE + (3,), np.float32)
    reference[..., 2] = -1.0
    tilt = np.radians(tilt_deg)
    normals = reference.copy()
    normals[disk] = (np.sin(tilt), 0.0, -np.cos(tilt))
    return contact, normals, reference


@pytest.mark.parametrize(
    ("radius", "tilt_deg", "warned"),
    [
        (5, 30.0, True),  # a 1 mm sphere at 320x240: ~10 px across, steep
        (30, 30.0, False),  # the same slopes over 60 px: resolved
        (5, 4.0, False),  # as small but shallow: little to smooth away
    ],
)
def test_a_contact_is_warned_about_only_when_small_for_its_slopes(radius, tilt_deg, warned):
    contact, normals, reference = _dent(radius, tilt_deg)
    diameter, tilt = contact_steepness(contact, normals, reference, np.ones(SHAPE, bool))
    assert diameter == pytest.approx(2 * radius, rel=0.1)
    assert tilt == pytest.approx(tilt_deg, abs=0.01)
    note = resolution_note("press7", diameter, tilt)
    assert (note is not None) == warned
    if warned:
        assert note.startswith("press7: contact about 10 px across") and "higher resolution" in note


def test_no_contact_among_the_solved_pixels_is_not_judged():
    contact, normals, reference = _dent(5, 30.0)
    assert contact_steepness(contact, normals, reference, np.zeros(SHAPE, bool)) is None


def test_the_solve_records_the_warning_in_its_report(presses, monkeypatch, caplog):
    press = load_press(presses["sphere"])
    # the exact 96x72 sphere dent is resolved (0.1 deg contact AAE): no warning at the measured threshold
    assert not any("px the solver resolves" in w for w in solve_press(press).report.get("warnings", []))
    monkeypatch.setattr(tolerances, "RESOLVED_TILT_PER_PX", 0.05)  # as if its slopes were far steeper
    warnings = solve_press(press).report.get("warnings", [])
    assert [w for w in warnings if "px the solver resolves" in w and w.startswith(str(press.folder))]
    assert "px the solver resolves" in caplog.text
