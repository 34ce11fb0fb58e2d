"""Statuses of one press in a batch (what :func:`nlipscalib.pipeline.solve_presses` returns per press)."""

from __future__ import annotations

SOLVED, SKIPPED, FAILED = "solved", "skipped", "failed"
"""Statuses of one press (a failure reads "failed: reason")."""

NO_CONTACT = "no contact"
"""Status of a press ``--roi auto`` found no contact in ("no contact: reason"): nothing solved, not a failure."""

BUSY = "busy"
"""Internal status: another live process holds the press's claim (left to it, then waited for)."""

BROKEN = f"{FAILED}: not solved, a solver process was killed (by a signal or for lack of memory); run again"
"""Status of the presses a parallel batch could not finish because one of its processes died."""
