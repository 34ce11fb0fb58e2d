"""The paper's experiments and the studies only a twin can run, as commands with reports (``nlips experiment``).

Each experiment expands into per-press tasks (render, solve every variant, score) that write their
results atomically into a shared folder; they run in this process, in local worker processes or on a
Dask cluster with identical numbers, and an interrupted run resumes. See docs/experiments/README.md.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.errors import ConfigError

if TYPE_CHECKING:  # named in hints only: the experiment modules load when one is asked for
    from .framework import Experiment

EXPERIMENTS = {
    "q1": "q1:Q1",
    "q2": "q2:Q2",
    "ablation": "ablation:Ablation",
    "q3": "q3:Q3",
    "studies": "studies:Studies",
    "presses": "presses:PressCount",
}
"""Runnable experiments: name -> module:class."""
GUIDE = {
    "q1": (
        "Q1 table: NLiPs normal and depth error (AAE, MabsE, depth RMSE) of sphere and cube presses against the "
        "true normals, with the true and with self-calibrated LEDs",
        {"quick": "~10 s", "medium": "~6 min", "full": "~40 min"},
    ),
    "q2": (
        "Q2 table: NLiPsNet trained on NLiPs-solved presses of three indenters, AAE on seen and unseen indenters "
        "vs the NLiPs labels and the true normals, next to a lookup table and the undeformed dome",
        {"quick": "~40 s", "medium": "~8 min", "full": "~25-40 min"},
    ),
    "ablation": (
        "LED ablation table: AAE and MabsE with 3 to 24 LEDs in the ring",
        {"quick": "~35 s", "medium": "~17 min", "full": "~95 min"},
    ),
    "q3": (
        "Q3 table: AAE on every shipped dome shape (hemisphere, fingertip, oblate, capsule, flat pad)",
        {"quick": "~1 min", "medium": "~9 min", "full": "~70 min"},
    ),
    "studies": (
        "twin-only studies: noise, interreflection, LED position/axis error, press depth, coating albedo",
        {"quick": "~45 s", "medium": "~6 min", "full": "~30 min"},
    ),
    "presses": (
        "how many calibration presses are enough: NLiPsNet and the lookup table trained on k of Q2's presses",
        {"quick": "~10 s after q2", "medium": "~3 min after q2", "full": "~30 min with Q2's presses"},
    ),
}
"""Per experiment, for ``nlips experiment --help``: what its tables measure, and its wall time per size with
``--workers 2`` on a shared 2-core machine (docs/experiments/RESULTS.md; a GPU or more cores take less)."""
UNAVAILABLE: dict[str, str] = {}
"""Experiments of the issue that cannot run yet, with the reason."""
BASELINES_DIR = Path(__file__).resolve().parent / "baselines"
"""Baselines shipped in the package (``--check NAME``): an installed wheel has no checkout to name them by path."""


def shipped_baselines() -> list[str]:
    """Names of the shipped baselines (``q1_quick``), for ``nlips experiment --check NAME``."""
    return sorted(p.stem for p in BASELINES_DIR.glob("*.json"))


def get(name: str) -> Experiment:
    """The experiment object of that name (ConfigError naming the known ones otherwise)."""
    if name in UNAVAILABLE:
        raise ConfigError(f"experiment {name}: not available: {UNAVAILABLE[name]}")
    if name not in EXPERIMENTS:
        from ..core.config import did_you_mean

        hint = did_you_mean(name, [*EXPERIMENTS, "all"])
        raise ConfigError(f"unknown experiment {name!r}{hint} (known: {', '.join(EXPERIMENTS)}, all)")
    module, cls = EXPERIMENTS[name].split(":")
    return getattr(importlib.import_module(f".{module}", __name__), cls)()
