"""The paper's experiments and the studies only a twin can run, as commands with reports (``nlips experiment``).

Each experiment expands into per-press tasks (render, solve every variant, score) that write their
results atomically into a shared folder; they run in this process, in local worker processes or on a
Dask cluster with identical numbers, and an interrupted run resumes. See docs/experiments/README.md.
"""

from __future__ import annotations

import importlib

from ..errors import ConfigError

EXPERIMENTS = {
    "q1": "q1:Q1",
    "q2": "q2:Q2",
    "ablation": "ablation:Ablation",
    "q3": "q3:Q3",
    "studies": "studies:Studies",
    "presses": "presses:PressCount",
}
"""Runnable experiments: name -> module:class."""
UNAVAILABLE: dict[str, str] = {}
"""Experiments of the issue that cannot run yet, with the reason."""


def get(name: str):
    """The experiment object of that name (ConfigError naming the known ones otherwise)."""
    if name in UNAVAILABLE:
        raise ConfigError(f"experiment {name}: not available: {UNAVAILABLE[name]}")
    if name not in EXPERIMENTS:
        raise ConfigError(f"unknown experiment {name!r} (known: {', '.join(EXPERIMENTS)}, all)")
    module, cls = EXPERIMENTS[name].split(":")
    return getattr(importlib.import_module(f".{module}", __name__), cls)()
