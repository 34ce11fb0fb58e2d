"""From per-task JSON to tables: one row per evaluation, then means over presses per group."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from .plan import press_name
from .tasks import Task, stored_result

METRICS = ("aae_deg", "mabse", "depth_rmse_mm")
"""Accuracy figures of the true contact region (the paper's numbers are over the contact)."""


def evaluation_rows(tasks: list[Task], out: Path) -> list[dict]:
    """Every evaluation of every finished press task, flattened, in task order.

    Returns
    -------
    list of dict: the evaluation's labels, ``press`` (name), ``aae_deg``, ``mabse``, ``depth_rmse_mm``
    and ``pixels`` of the true contact, ``roi_aae_deg``/``roi_mabse`` over the whole solved region,
    ``map`` (error-map file or None), ``error`` (None or why the solve failed).
    """
    rows = []
    for task in tasks:
        if task.kind != "press":
            continue
        # the result alone: its samples were checked as the run ran its tasks (runner.run_tasks), and its
        # evaluations do not depend on them; reading every press's shard again cost a full read per report
        result = stored_result(out, task)
        if result is None:
            continue
        for ev in result["evaluations"]:
            row = dict(ev["labels"]) | {"press": press_name(result["press"]), "task": task.id}
            if "error" in ev:
                rows.append(row | dict.fromkeys(METRICS, math.nan) | {"error": ev["error"], "map": None})
                continue
            c, a = ev["metrics"]["contact"], ev["metrics"]["all"]
            row |= {m: c[m] for m in METRICS} | {"pixels": c["pixels"], "roi_aae_deg": a["aae_deg"]}
            rows.append(row | {"roi_mabse": a["mabse"], "map": ev.get("map"), "error": None})
    return rows


def rows_from_json(rows: list[dict]) -> list[dict]:
    """Evaluation rows read back from a results.json: the NaN of a failed solve, which JSON stores as null
    (:func:`clean`), is NaN again, as :func:`aggregate` and the figures expect."""
    return [r | {k: math.nan for k in METRICS + ("roi_aae_deg", "roi_mabse") if k in r and r[k] is None} for r in rows]


def aggregate(rows: list[dict], by: tuple[str, ...]) -> list[dict]:
    """Mean, standard deviation and count of the contact metrics per group, groups in first-seen order.

    Solves that failed or saw no contact pixel are counted in ``failed`` and left out of the means.
    """
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r.get(k) for k in by), []).append(r)
    out = []
    for key, members in groups.items():
        ok = [r for r in members if r["error"] is None and np.isfinite(r["aae_deg"])]
        row = dict(zip(by, key)) | {"n": len(ok), "failed": len(members) - len(ok)}
        for m in METRICS + ("roi_aae_deg",):
            vals = np.array([r[m] for r in ok if np.isfinite(r.get(m, np.nan))], float)
            row[m] = float(vals.mean()) if len(vals) else math.nan
            row[m + "_std"] = float(vals.std()) if len(vals) > 1 else 0.0 if len(vals) else math.nan
        out.append(row)
    return out


def clean(obj: Any) -> Any:
    """JSON-safe copy: NaN and infinities become None (JSON has no NaN), numpy scalars become floats."""
    if isinstance(obj, dict):
        return {str(k): clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def dumps(obj: Any) -> str:
    return json.dumps(clean(obj), indent=2) + "\n"
