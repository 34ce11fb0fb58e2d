"""Regression check: compare an experiment's accuracy figures with a stored baseline."""

from __future__ import annotations

import json
import math
from pathlib import Path

from ..core import tolerances
from ..core.errors import ConfigError
from .summary import METRICS


def headline(rows: list[dict], by: tuple[str, ...]) -> dict[str, float]:
    """Accuracy figures keyed "label=value/...: metric" from aggregated rows."""
    out = {}
    for row in rows:
        name = "/".join(f"{k}={row[k]}" for k in by)
        for m in METRICS:
            if m in row:  # tables of other figures (NLiPsNet scores) have none of the NLiPs metrics
                out[f"{name}: {m}"] = row[m]
    return out


def baseline_document(experiment: str, size: str, figures: dict[str, float]) -> dict:
    tol = {m: {"abs": tolerances.EXPERIMENT_CHECK_ABS[m], "rel": tolerances.EXPERIMENT_CHECK_REL} for m in METRICS}
    return {"experiment": experiment, "size": size, "figures": figures, "tolerances": tol}


def baseline_path(given: str | Path) -> Path:
    """The baseline file ``given`` names: a path as given, or a bare name such as ``"q1_quick"`` looked up in the
    shipped baselines (as ``nlips dataset train50`` finds a shipped spec: ``sim.scene.dataset_spec_path``).

    Raises
    ------
    ConfigError
        A bare name that is no file here nor a shipped baseline (the line lists the shipped ones).
    """
    from . import BASELINES_DIR, shipped_baselines

    path = Path(given)
    if path.is_file() or path.suffix or len(path.parts) > 1:  # a path: load_baseline says what is wrong with it
        return path
    if not (BASELINES_DIR / f"{path}.json").is_file():
        shipped = ", ".join(shipped_baselines())
        raise ConfigError(f"baseline {str(path)!r}: no such file, nor a shipped baseline ({shipped})")
    return BASELINES_DIR / f"{path}.json"


def load_baseline(path: Path, experiment: str, size: str | None = None) -> dict:
    """The baseline document at ``path``: ConfigError (naming it) unless it is one of ``experiment`` at ``size``
    (a baseline of another size holds other figures: a quick run checked against a medium one passed unsaid)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such baseline file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("figures"), dict):
        raise ConfigError(f"{path}: a baseline needs a 'figures' mapping (write one with --write-baseline)")
    if data.get("experiment") not in (None, experiment):
        raise ConfigError(f"{path}: baseline of experiment {data.get('experiment')!r}, not {experiment!r}")
    if size is not None and data.get("size") not in (None, size):
        raise ConfigError(f"{path}: baseline of size {data.get('size')!r}, this run is {size!r}")
    return data


def compare(current: dict[str, float], baseline: dict) -> list[dict]:
    """Figures worse than the baseline by more than their tolerance (missing or NaN counts as worse)."""
    tol = baseline.get("tolerances", {})
    worse = []
    for key, base in baseline["figures"].items():
        if base is None:
            continue
        metric = key.rsplit(": ", 1)[-1]
        t = tol.get(metric, {})
        allowed = max(
            t.get("abs", tolerances.EXPERIMENT_CHECK_ABS.get(metric, 0.0)),
            t.get("rel", tolerances.EXPERIMENT_CHECK_REL) * abs(base),
        )
        now = current.get(key)
        if now is None or not math.isfinite(now) or now > base + allowed:
            worse.append({"figure": key, "baseline": base, "now": now, "allowed": base + allowed})
    return worse


def format_worse(worse: list[dict]) -> str:
    lines = [f"{'figure':<50} {'baseline':>10} {'now':>10} {'allowed':>10}"]
    for w in worse:
        now = "missing" if w["now"] is None or not math.isfinite(w["now"]) else f"{w['now']:.4f}"
        lines.append(f"{w['figure']:<50} {w['baseline']:>10.4f} {now:>10} {w['allowed']:>10.4f}")
    return "\n".join(lines)
