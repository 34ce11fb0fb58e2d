"""Study: how many calibration presses are enough? NLiPsNet accuracy against the number of training presses.

NLiPsNet is trained on the first k calibration presses of Q2 (balanced over its three indenters) for
every k of ``counts`` and scored on one fixed held-out set: Q2's seen-indenter and unseen-indenter
test presses, against the NLiPs labels and the true normals, next to the lookup table fitted on the
same k presses. The presses are Q2's: this study shares Q2's work folder (OUT/q2-SIZE), so after
``nlips experiment q2`` it only trains.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.errors import ConfigError
from ..report import experiments as fig
from .framework import Table
from .q2 import MEDIUM, PAPER, Q2, QUICK, TRAINING_COLUMNS, Q2Config, training_summary

if TYPE_CHECKING:  # named in hints only
    from .framework import WorkFigure
    from .tasks import Task

METHODS = ("NLiPsNet", "lookup table")


@dataclasses.dataclass(frozen=True)
class PressCountConfig(Q2Config):
    """Q2's presses and training, plus the numbers of calibration presses to train on."""

    counts: tuple[int, ...] = (5, 10, 20, 35, 50)
    """Numbers of calibration presses (the first k of ``train``; at least 2: one is held for validation)."""

    def __post_init__(self):
        if not self.counts or any(int(k) < 2 for k in self.counts):
            raise ConfigError(f"counts must list numbers of presses >= 2 (one validates), got {list(self.counts)}")


def _with_counts(base: Q2Config, counts: tuple[int, ...]) -> PressCountConfig:
    fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(Q2Config)}
    return PressCountConfig(**fields, counts=counts)


class PressCount(Q2):
    name = "presses"
    title = "Study: how many calibration presses are enough? (NLiPsNet vs number of training presses)"
    description = __doc__.split("\n\n", 1)[1].strip()
    config_cls = PressCountConfig
    sizes = {
        "quick": _with_counts(QUICK, (2, 4, 8)),
        "medium": _with_counts(MEDIUM, (3, 6, 12, 20)),
        "full": PressCountConfig(),
    }
    paper = {"note": "the paper used 50 presses and did not vary their number"} | PAPER
    check_table = "counts"
    work_name = "q2"
    work_figures = ()  # Q2's normals figure is Q2's

    def draw_work_figures(
        self, cfg: PressCountConfig, rows: list[dict], out: Path, folder: Path, learned: dict | None = None
    ) -> list[WorkFigure]:
        return []

    def learn(self, cfg: PressCountConfig, tasks: list[Task], out: Path, progress: bool = True) -> dict:
        from ..learn.lut import fit_lookup_table
        from . import learning

        data, stamps = learning.assemble_dataset(out, tasks, self.samples(cfg))
        names = self.names_by_role(tasks, stamps)
        if len(names["train"]) < 2:
            return {"error": f"NLiPsNet not trained: {len(names['train'])} calibration press(es) with samples, need 2"}
        tests = {"seen": names["seen"], "unseen": names["unseen"]}
        counts = sorted({min(int(k), len(names["train"])) for k in cfg.counts})
        rows, models = [], {}
        for k in counts:
            subset = names["train"][:k]
            model = learning.train_model(data, subset, stamps, cfg.net, out, progress)
            lut = fit_lookup_table(data, subset)  # `nlips lut`'s fit
            predictors = {METHODS[0]: learning.net_predictor(out, model, cfg.net.threads), METHODS[1]: lut.predict}
            for r in learning.score(data, predictors, tests):
                if r["method"] in METHODS:
                    rows.append({"calibration_presses": k} | r)
                elif k == counts[0]:  # NLiPs itself does not depend on k: once
                    rows.append({"calibration_presses": None} | r)
            models[k] = {key: v for key, v in model.items() if key != "history"}
        return {"presses": {r: len(v) for r, v in names.items()}, "counts": counts, "scores": rows, "models": models}

    def tables(self, cfg: PressCountConfig, rows: list[dict], learned: dict | None = None) -> list[Table]:
        if not learned or "error" in learned:
            return []
        scores = sorted(
            learned["scores"],
            key=lambda r: (r["calibration_presses"] is None, r["calibration_presses"] or 0, r["split"], r["method"]),
        )
        counts = Table(
            "counts",
            f"NLiPsNet and the lookup table trained on k of {learned['presses']['train']} calibration presses, "
            f"scored on the same {learned['presses']['seen']} seen-indenter and {learned['presses']['unseen']} "
            "unseen-indenter test presses (contact samples)",
            ("calibration_presses", "split", "method"),
            scores,
            columns=(
                ("contact_samples", "contact samples", 0),
                ("aae_vs_nlips_deg", "AAE vs NLiPs labels (°)", 2),
                ("aae_vs_true_deg", "AAE vs true normals (°)", 2),
            ),
        )
        training = Table(
            "training",
            f"NLiPsNet training per number of presses (hidden layers {'-'.join(map(str, cfg.net.hidden))})",
            ("calibration_presses",),
            [
                {"calibration_presses": int(k), "val": len(m["val_presses"])} | training_summary(m)
                for k, m in learned["models"].items()
            ],
            columns=(("val", "of them validation", 0),) + TRAINING_COLUMNS,
        )
        return [counts, training]

    def figures(
        self, cfg: PressCountConfig, rows: list[dict], tables: list[Table], folder: Path, learned: dict | None = None
    ) -> list[tuple[str, str]]:
        if not learned or "error" in learned:
            return []
        series = {}
        for method in METHODS:
            for split in ("seen", "unseen"):
                for key, label in (("aae_vs_nlips_deg", "vs NLiPs"), ("aae_vs_true_deg", "vs true")):
                    if method != METHODS[0] and key == "aae_vs_nlips_deg":
                        continue  # the lookup table vs its labels adds little to the picture
                    mine = [r for r in learned["scores"] if r["method"] == method and r["split"] == split]
                    if mine:
                        xs = [r["calibration_presses"] for r in mine]
                        ys = [float("nan") if r[key] is None else r[key] for r in mine]
                        series[f"{method}, {split}, {label}"] = (xs, ys, [0.0] * len(xs))
        paper = {"paper (50 presses, vs NLiPs)": ([50, 50], [PAPER["seen_aae_deg"], PAPER["unseen_aae_deg"]])}
        if max(learned["counts"]) < 25:  # a sweep far from the paper's 50 presses: the marker would squash it
            paper = {}
        caption, name = "Test AAE against the number of calibration presses", "presses_aae.png"
        fig.sweep(series, "calibration presses", "AAE on the test contact (°)", folder / name, paper, title=caption)
        return [(caption, name)]
