"""Solving presses as a user's command does: resumable, honest about re-runs, concurrency-safe, parallel.

The one place that turns press folders into reconstruction folders (PRESS/nlips/), shared by
``nlips solve``, ``nlips demo``, ``nlips eval`` (re-computing a damaged result), and later
``nlips calibrate`` and the experiments.

- **Honest re-runs.** Every result records what made it (report.json ``provenance``): the solver
  settings (options, ROI request, LED subset or calibrated LEDs, backend, extra solver keywords), the
  identities of its inputs (content hashes of the press and the reference capture) and the software
  version, and one ``key`` hashing them all. A result is reused only when its key equals the key of
  the new request; otherwise it is re-solved (and the log says what changed).
- **Damaged results** (truncated result.npz, an array failing its checksum, broken report.json) are
  re-computed with a warning.
- **Concurrency.** Work on PRESS/nlips is claimed (:func:`nlipscalib.core.claims.claim`): a press that
  another live process of the same settings is solving is left to it and waited for at the end, and interrupted
  writes (``.tmp-nlips-*``) are removed only by the claim's holder, i.e. when no live process can own them. A run
  holds its outputs for its settings until it ends (:func:`nlipscalib.core.claims.claim_shared`): a run of other
  settings is refused those presses, one line each, never replacing a live run's result.
- **Parallel.** ``workers > 1`` solves presses in separate processes, the usable cores shared out among them as
  the solver's threads (:func:`nlipscalib.core.cpus.threads_per_worker`; BLAS stays on one thread). A press's
  solve uses two threads well, so ``nlips solve FOLDER`` starts one process per two cores by default
  (:func:`nlipscalib.core.cpus.solve_workers_default`). Ctrl-C stops the batch in the parent: queued
  presses are not started, running ones finish; a SIGTERM'd worker removes its claim and temporary first.

Modules, one job each: ``settings`` (the arguments of a solve checked and normalised), ``provenance`` (what made
a result, and its key), ``reuse`` (an earlier result reused, its folder claimed, waited for and cleaned),
``workers`` (solver processes and their signals), ``solve`` (press folders solved and saved), ``status``.
"""

from __future__ import annotations

from .provenance import capture_identity, make_provenance
from .settings import SolveSettings, check_fits_capture, make_settings, settings_from_record
from .solve import result_dir, solve_folder, solve_one, solve_presses
from .status import BROKEN, BUSY, FAILED, NO_CONTACT, SKIPPED, SOLVED

__all__ = [
    "BROKEN",
    "BUSY",
    "FAILED",
    "NO_CONTACT",
    "SKIPPED",
    "SOLVED",
    "SolveSettings",
    "capture_identity",
    "check_fits_capture",
    "make_provenance",
    "make_settings",
    "result_dir",
    "settings_from_record",
    "solve_folder",
    "solve_one",
    "solve_presses",
]
