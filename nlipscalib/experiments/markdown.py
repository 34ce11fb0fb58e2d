"""The Markdown page of an experiment report (text only; figures come from nlipscalib.report)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # named in hints only: the framework imports this module
    from .framework import Experiment, Table


def fmt(value: object, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


METRIC_HEADERS = (("aae_deg", "AAE (°)", 2), ("mabse", "MabsE", 4), ("depth_rmse_mm", "depth RMSE (mm)", 3))


def table(t: Table) -> str:
    if t.columns:
        return _plain_table(t)
    heads = _by_heads(t) + ["n"] + [h for _, h, _ in METRIC_HEADERS] + ["AAE ROI (°)"] + list(t.paper.values())
    lines = [f"**{t.caption}**", "", "| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    for r in t.rows:
        cells = [fmt(r.get(k)) for k in t.by] + [f"{r['n']}" + (f" ({r['failed']} failed)" if r["failed"] else "")]
        cells += [fmt(r[m], d) + (f" ± {fmt(r[m + '_std'], d)}" if r["n"] > 1 else "") for m, _, d in METRIC_HEADERS]
        cells += [fmt(r.get("roi_aae_deg"), 2)] + [fmt(r.get(k), 4 if "mabse" in k else 2) for k in t.paper]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _by_heads(t: Table) -> list[str]:
    """Headers of the group columns: their row keys in words ("calibration_presses" -> "calibration presses")."""
    return [k.replace("_", " ") for k in t.by]


def _plain_table(t: Table) -> str:
    """A table of named columns (``Table.columns``) and the paper's columns."""
    heads = _by_heads(t) + [h for _, h, _ in t.columns] + list(t.paper.values())
    lines = [f"**{t.caption}**", "", "| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    for r in t.rows:
        cells = [fmt(r.get(k)) for k in t.by] + [fmt(r.get(k), d) for k, _, d in t.columns]
        cells += [fmt(r.get(k), 2) for k in t.paper]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def report(exp: Experiment, doc: dict, tables: list[Table], figures: list[tuple[str, str]], note: str = "") -> str:
    """The report page; ``note``: a paragraph after the introduction (what redrew the figures)."""
    cfg, mach, sw = doc["config"], doc["machine"], doc["software"]
    twin = cfg.get("twin", {})
    tasks = doc["tasks"]
    parts = [
        f"# {exp.title}",
        "",
        exp.description,
        "",
        f"Size **{doc['size']}**; twin: scene `{twin.get('scene')}` at {twin.get('width')}x{twin.get('height')} px, "
        f"{twin.get('spp')} spp{_reference_spp(twin)}, {twin.get('bounces')} interreflection bounce(s), noise "
        f"{'on' if twin.get('noise') else 'off'}. AAE, MabsE and depth RMSE are over the true contact region "
        "(mean ± standard deviation over presses); AAE ROI is over the whole solved region. "
        f"{tasks['total']} tasks ({tasks['run_now']} run now, {tasks['already_done']} reused), "
        f"{len(tasks['failed'])} failed; {doc['wall_seconds']} s wall for this run, "
        f"{doc['task_seconds']['all']} s of task time in all, on {mach['cores']} cores "
        f"({mach['cpu']}, load {mach['load_average']}); nlipscalib {sw['nlipscalib']} at `{sw['git_commit']}`. "
        "Every number, the exact configuration and the machine are in `results.json`.",
        "",
    ]
    parts += [note, ""] if note else []
    parts += _other_software_lines(tasks.get("made_by_other_software", {}))
    parts += _calibration_lines(doc.get("calibrations", []))
    if doc["solver_option_overrides"]:
        parts += [f"Solver option overrides: `{doc['solver_option_overrides']}`.", ""]
    for t in tables:
        parts += [table(t), ""]
    for caption, path in figures:
        parts += [f"![{caption}]({path})", "", f"*{caption}*", ""]
    if doc.get("learned", {}).get("error"):
        parts += ["## Not computed", "", doc["learned"]["error"], ""]
    if doc["not_done"]:
        parts += ["## Not done", ""] + [f"- {line}" for line in doc["not_done"]] + [""]
    if tasks["failed"]:
        parts += ["## Failed tasks", ""] + [f"- `{k}`: {v}" for k, v in tasks["failed"].items()] + [""]
    return "\n".join(parts)


def _reference_spp(twin: dict) -> str:
    spp = twin.get("reference_spp") or 0
    return f" (the undeformed reference at {spp} spp)" if spp > (twin.get("spp") or 0) else ""


def _calibration_lines(calibrations: list[dict]) -> list[str]:
    """One line on the LED self-calibrations' fit quality (the calibrated LEDs' trust), or none."""
    rated = [c for c in calibrations if c.get("quality")]
    if not rated:
        return []
    ratios = ", ".join(f"{c['quality']['median_ratio']:.2f}" for c in rated)
    bad = [c["id"] for c in rated if not c["quality"]["reliable"]]
    verdict = f"UNRELIABLE: {', '.join(bad)}" if bad else "reliable"
    return [
        f"LED self-calibration: residual {ratios}x the images' noise (reliable up to "
        f"{rated[0]['quality']['threshold']}): {verdict}.",
        "",
    ]


def _other_software_lines(other: dict[str, str]) -> list[str]:
    """The report's note on tasks kept by ``--keep-old`` that other code or libraries made
    (framework._made_by_other_software)."""
    if not other:
        return []
    makers = "; ".join(sorted(set(other.values())))
    return [
        f"**{len(other)} reused task(s) were made by other code or libraries** (kept by `--keep-old`; {makers}): "
        f"their numbers are that code's, not this commit's ({', '.join(sorted(other))}).",
        "",
    ]
