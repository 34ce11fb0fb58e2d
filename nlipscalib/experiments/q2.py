"""Q2, NLiPsNet: calibrated on NLiPs-solved presses of three indenters, tested on seen and unseen indenters.

The paper trained NLiPsNet on 50 presses of three indenters solved by NLiPs and tested it on the same
indenters at other places (3.33°) and on other indenters (3.11°), scored against NLiPs normals, the
only labels a real sensor has. The twin also knows the true normals: every score is given against both.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from ..learn.dataset import SamplingConfig, sampling_record
from ..learn.train import TrainConfig
from ..report import experiments as fig
from ..sim.indenters import IndenterConfig
from .common import CUBE, FULL_TWIN, MEDIUM_TWIN, QUICK_TWIN, SPHERE
from .framework import Experiment, Table, WorkFigure
from .plan import PressSet, TwinConfig, solve_dict
from .summary import aggregate

if TYPE_CHECKING:  # named in hints only
    from ..learn.dataset import CalibrationDataset
    from .tasks import Task

CYLINDER = IndenterConfig(kind="cylinder", size=4.0)
CONE = IndenterConfig(kind="cone", size=6.0)
SCREW_SIDE = IndenterConfig(kind="screw", size=4.0, length=10.0)
COIN = IndenterConfig(kind="coin", size=8.0)
SEEN = (SPHERE, CUBE, CYLINDER)
"""The paper's three calibration indenters (here: sphere, cube, cylinder)."""
UNSEEN = (CONE, SCREW_SIDE, COIN)
"""Indenters NLiPsNet never sees in training."""

PAPER = {
    "source": "NLiPsNet on the real NLiPsTac sensor, scored against NLiPs normals (paper, Q2)",
    "seen_aae_deg": 3.33,
    "unseen_aae_deg": 3.11,
    "train_presses": 50,
}
METHODS = {
    "nlipsnet": "NLiPsNet (NLiPs labels)",
    "upper": "NLiPsNet (true normals: upper bound)",
    "lut": "lookup table (Yuan 2017)",
    "none": "undeformed dome (no calibration)",
}
SCORE_COLUMNS = (
    ("presses", "presses", 0),
    ("contact_samples", "contact samples", 0),
    ("aae_vs_nlips_deg", "AAE vs NLiPs labels (°)", 2),
    ("aae_vs_true_deg", "AAE vs true normals (°)", 2),
)
STEEP_TILTS_DEG = (35.0, 45.0)
"""Tilts (deg from the undeformed normal) whose exceedance the steepness table reports: the smooth calibration
indenters stay below the first on the default twin, a coin's engraved detail goes beyond both."""
STEEPNESS_COLUMNS = (
    ("contact_samples", "contact samples", 0),
    ("tilt_p99_deg", "99th percentile tilt (°)", 1),
) + tuple((f"beyond_{t:.0f}_pct", f"% beyond {t:.0f}°", 1) for t in STEEP_TILTS_DEG)
TRAINING_COLUMNS = (
    ("epochs", "epochs", 0),
    ("best_epoch_from_1", "best epoch", 0),
    ("best_val_aae_deg", "best validation AAE (°)", 2),
    ("train_seconds", "seconds", 1),
)
"""The training columns of the Q2 and press-count tables (after each table's own ones)."""
NORMALS = WorkFigure(
    "q2_normals.png",
    "Test presses: object, ground-truth normals, NLiPsNet normals, angular error",
    "the trained NLiPsNet (work folder learned/*.pt) and the test presses' crops (views/*.npz)",
)


def training_summary(model: dict) -> dict:
    """A trained model's record (``learning.train_model``) as a training-table row.

    The record keeps the trainer's 0-based ``best_epoch`` (the model file's ``info.best_epoch``; records
    of earlier runs are reused as they are); the table numbers epochs from 1, as ``nlips train`` and the
    training-curve figure do, under its own key so results.json never holds one name with two meanings.

    Parameters
    ----------
    model : dict with ``epochs``, ``best_epoch`` (0-based; None or negative without any epoch),
        ``best_val_aae_deg`` and ``train_seconds``

    Returns
    -------
    dict: epochs, best_epoch_from_1 (None without an epoch), best_val_aae_deg, train_seconds
    """
    best = model.get("best_epoch")
    return {
        "epochs": model["epochs"],
        "best_epoch_from_1": best + 1 if best is not None and best >= 0 else None,
        "best_val_aae_deg": model["best_val_aae_deg"],
        "train_seconds": model["train_seconds"],
    }


@dataclasses.dataclass(frozen=True)
class Q2Config:
    """Q2: NLiPsNet calibrated on NLiPs labels of presses of three indenters."""

    twin: TwinConfig = TwinConfig(**FULL_TWIN)
    """The twin (default NLiPsTac sensor with noise and one interreflection bounce)."""
    train: PressSet = PressSet(indenters=SEEN, count=50, seed=0)
    """Calibration presses (the paper: 50 of three indenters)."""
    seen: PressSet = PressSet(indenters=SEEN, count=12, seed=1)
    """Test presses of the calibration indenters at other places."""
    unseen: PressSet = PressSet(indenters=UNSEEN, count=12, seed=2)
    """Test presses of other indenters."""
    leds: str = "true"
    """LEDs the NLiPs labels are solved with: true (the capture's) or calibrated (self-calibrated)."""
    roi: str = "auto"
    """Region NLiPs solves: auto (its contact detector, as ``nlips calibrate``), truth or full."""
    interreflection: str = "dent"
    """Interreflection correction of the label solves: off, reference or dent."""
    normals: str = "depth"
    """Normals of the label solves (``SolverOptions.normals``): depth (the solved depth's gradient, as the paper)
    or refined (each pixel's refitted to its images where they reject the depth's: steep relief)."""
    sampling: SamplingConfig = SamplingConfig()
    """Which pixels of a solved press become samples (as ``nlips calibrate``)."""
    net: TrainConfig = TrainConfig()
    """NLiPsNet and its training (the paper's 256-256-128; seeded; split by press; its colour inputs over the
    undeformed reference's, ``TrainConfig.colour_input``'s default since the thirty-seventh session: ``colour_input =
    "linear"`` gives the paper's; the reference with its own 3 px Gaussian since the thirty-eighth,
    ``TrainConfig.reference_smoothing_px``: 0 gives the earlier nets)."""
    upper_bound: bool = True
    """Also train on the twin's true normals (what perfect labels would give)."""
    figure_presses: int = 3
    """Test presses per split in the normals figure."""


QUICK_NET = TrainConfig(hidden=(64, 64, 64), dropout=0.0, max_epochs=30, patience=8, batch_size=256)
"""CI: a small net, few epochs (the numbers test the plumbing), of the default colour ratios; without dropout, which
a 64-64-64 net underfits with (`nlips train --help`), the ratio most: on the CI test's two 96x72 calibration presses
(tests/experiments/test_q2.py, TINY) the seen press scored 6.61 / 4.89 deg vs its labels at seeds 0 / 1 with
dropout 0.2 (linear colours 3.71 / 3.08; no calibration 6.96 vs truth, the test's bound 0.8x that: 5.57), 5.03 /
4.18 / 3.88 at seeds 0 / 1 / 2 without (linear 3.62 at seed 0); 60 epochs, a cosine schedule or no weight decay
gained nothing (docs/experiments/RESULTS.md, s37-ratiodef). At the thirty-eighth session's defaults (weight decay 0.5,
the reference's 3 px Gaussian) 4.38 / 4.16 / 4.06 / 4.54 / 4.57 at seeds 0-4 (0 px: 5.07 / 4.09 / 3.98 / 4.56 / 4.48):
the test's margin 1.19 deg at its seed 0, 1.01 at the worst seed, the spread over seeds 0.51 (s39-q2bits)."""
QUICK = Q2Config(
    twin=TwinConfig(**QUICK_TWIN),
    train=PressSet(indenters=SEEN, count=8, seed=0),
    seen=PressSet(indenters=SEEN, count=3, seed=1),
    unseen=PressSet(indenters=UNSEEN[:2], count=2, seed=2),
    net=QUICK_NET,
    figure_presses=2,
)
MEDIUM = Q2Config(
    twin=TwinConfig(**MEDIUM_TWIN),
    train=PressSet(indenters=SEEN, count=20, seed=0),
    seen=PressSet(indenters=SEEN, count=6, seed=1),
    unseen=PressSet(indenters=UNSEEN, count=6, seed=2),
    net=TrainConfig(max_epochs=80, patience=10),
)


class Q2(Experiment):
    name = "q2"
    title = "Q2: NLiPsNet on seen and unseen indenters"
    description = (
        "Presses of three indenters on the default NLiPsTac twin are solved by NLiPs (as `nlips calibrate`: the "
        "capture's LEDs, auto contact region, undeformed reference), paired into (u, v, r, g, b) -> normal samples "
        "and used to train NLiPsNet (seeded; training and validation split by press). It is tested on the same "
        "indenters pressed at other places (seen) and on other indenters (unseen), on the contact samples, against "
        "the NLiPs normals (all the paper could measure: 3.33° seen, 3.11° unseen) and against the twin's true "
        "normals; next to the GelSight-style lookup table fitted on the same samples, NLiPsNet trained on the "
        "true normals (upper bound), the undeformed dome's normals (no calibration) and NLiPs itself. Contact "
        "samples are the pixels whose tri-colour value changed (learn.change). The first table is NLiPs (the "
        "labels) against the truth per press, over the true contact."
    )
    config_cls = Q2Config
    sizes = {"quick": QUICK, "medium": MEDIUM, "full": Q2Config()}
    paper = PAPER
    check_table = "nlips"
    work_figures = (NORMALS,)

    # ------------------------------------------------------------------ tasks
    def roles(self, cfg: Q2Config) -> dict[str, list[dict]]:
        """Press mappings per role: train, seen (test), unseen (test)."""
        return {"train": cfg.train.presses(), "seen": cfg.seen.presses(), "unseen": cfg.unseen.presses()}

    def evaluations(self, cfg: Q2Config) -> list[tuple[dict, dict, dict, dict]]:
        scene = cfg.twin.scene_dict()
        # the default adds no option, so the tasks (and their kept results) of earlier runs keep their names
        options = {} if cfg.normals == "depth" else {"normals": cfg.normals}
        solve = solve_dict(leds=cfg.leds, interreflection=cfg.interreflection, roi=cfg.roi, options=options)
        return [
            (scene, press, {"role": role, "indenter": press["indenter"]["kind"]}, solve)
            for role, presses in self.roles(cfg).items()
            for press in presses
        ]

    def samples(self, cfg: Q2Config) -> dict:
        return sampling_record(cfg.sampling)

    # ------------------------------------------------------------------ learning
    def learn(self, cfg: Q2Config, tasks: list[Task], out: Path, progress: bool = True) -> dict:
        from ..learn.lut import fit_lookup_table
        from . import learning

        data, stamps = learning.assemble_dataset(out, tasks, self.samples(cfg))
        names = self.names_by_role(tasks, stamps)
        if len(names["train"]) < 2:  # e.g. most label solves failed: report it, do not stop the report
            return {"error": f"NLiPsNet not trained: {len(names['train'])} calibration press(es) with samples, need 2"}
        tests = {"seen": names["seen"], "unseen": names["unseen"]}
        models = {"nlipsnet": learning.train_model(data, names["train"], stamps, cfg.net, out, progress)}
        if cfg.upper_bound:
            upper = dataclasses.replace(cfg.net, labels="true")
            models["upper"] = learning.train_model(data, names["train"], stamps, upper, out, progress)
        predictors = {METHODS[k]: learning.net_predictor(out, m, cfg.net.threads) for k, m in models.items()}
        lut = fit_lookup_table(data, names["train"])  # `nlips lut`'s fit (NLiPs labels, default size)
        predictors[METHODS["lut"]] = lut.predict
        predictors[METHODS["none"]] = learning.undeformed_predictor(data)
        by_indenter = _by_indenter(data, tests)
        per_indenter = learning.score(data, predictors, by_indenter)
        for r in per_indenter:
            r["split"], r["indenter"] = r["split"].split("/", 1)
        return {
            "presses": {k: len(v) for k, v in names.items()},
            "names": names,
            "scores": learning.score(data, predictors, tests),
            "per_indenter": per_indenter,
            "steepness": learning.steepness(
                data, _by_indenter(data, {"train": names["train"]}) | by_indenter, STEEP_TILTS_DEG
            ),
            "models": {k: {key: v for key, v in m.items() if key != "history"} for k, m in models.items()},
            "histories": {k: m["history"] for k, m in models.items()},
        }

    @staticmethod
    def names_by_role(tasks: list[Task], stamps: dict) -> dict[str, list[str]]:
        """Press task ids that have samples, per role (train, seen, unseen), in task order."""
        out = {"train": [], "seen": [], "unseen": []}
        for t in tasks:
            if t.kind == "press" and t.id in stamps:
                out[t.evaluations[0]["labels"]["role"]].append(t.id)
        return out

    # ------------------------------------------------------------------ report
    def tables(self, cfg: Q2Config, rows: list[dict], learned: dict | None = None) -> list[Table]:
        nlips = aggregate(rows, ("role", "indenter"))
        tables = [Table("nlips", "NLiPs (the training labels) against the true normals", ("role", "indenter"), nlips)]
        if not learned or "error" in learned:
            return tables
        scores = learned["scores"]
        for r in scores:
            if r["method"] == METHODS["nlipsnet"]:
                r["paper_aae_deg"] = PAPER[f"{r['split']}_aae_deg"]
        tables.append(
            Table(
                "nlipsnet",
                f"NLiPsNet on {learned['presses']['train']} calibration presses, tested on seen indenters at "
                "unseen places and on unseen indenters (contact samples)",
                ("split", "method"),
                scores,
                {"paper_aae_deg": "paper (°, vs NLiPs, real sensor)"},
                SCORE_COLUMNS,
            )
        )
        if learned.get("per_indenter"):  # what each test indenter costs (reports made before it lack it)
            tables.append(
                Table(
                    "per_indenter",
                    "The same scores per test indenter",
                    ("split", "indenter", "method"),
                    learned["per_indenter"],
                    columns=SCORE_COLUMNS,
                )
            )
        if learned.get("steepness"):  # why an unseen indenter costs more (reports made before it lack it)
            tables.append(
                Table(
                    "steepness",
                    "How steep the contact is: true normals' tilt from the undeformed surface (the net extrapolates "
                    "beyond what its calibration presses reach)",
                    ("split", "indenter"),
                    learned["steepness"],
                    columns=STEEPNESS_COLUMNS,
                )
            )
        training = [
            {"model": METHODS[k]}
            | {"train": len(m["train_presses"]), "val": len(m["val_presses"])}
            | training_summary(m)
            for k, m in learned["models"].items()
        ]
        tables.append(
            Table(
                "training",
                f"Training (hidden layers {'-'.join(map(str, cfg.net.hidden))}, seed {cfg.net.seed})",
                ("model",),
                training,
                columns=(("train", "training presses", 0), ("val", "validation presses", 0)) + TRAINING_COLUMNS,
            )
        )
        return tables

    def figures(
        self, cfg: Q2Config, rows: list[dict], tables: list[Table], folder: Path, learned: dict | None = None
    ) -> list[tuple[str, str]]:
        if not learned or "error" in learned:
            return []
        from ..report.learn import training_curve

        figs = []
        scores = learned["scores"]
        splits = list(dict.fromkeys(r["split"] for r in scores))
        methods = list(dict.fromkeys(r["method"] for r in scores))
        lines = {"paper seen (vs NLiPs)": PAPER["seen_aae_deg"], "paper unseen (vs NLiPs)": PAPER["unseen_aae_deg"]}
        for key, label, name in (
            ("aae_vs_nlips_deg", "vs NLiPs labels", "q2_vs_nlips.png"),
            ("aae_vs_true_deg", "vs true normals", "q2_vs_true.png"),
        ):
            series = {}
            for m in methods:
                found = {r["split"]: r[key] for r in scores if r["method"] == m}
                series[m] = ([_nan(found.get(s)) for s in splits], [0.0] * len(splits))
            caption = f"AAE on the test presses' contact samples {label}"
            fig.grouped_bars(splits, series, f"AAE {label} (°)", folder / name, lines, title=caption)
            figs.append((caption, name))
        validation = learned["models"]["nlipsnet"]["val_presses"]
        training_curve(learned["histories"]["nlipsnet"], folder / "q2_training.png", METHODS["nlipsnet"], validation)
        figs.append(("Training curve of NLiPsNet (validation presses)", "q2_training.png"))
        return figs

    def draw_work_figures(
        self, cfg: Q2Config, rows: list[dict], out: Path, folder: Path, learned: dict | None = None
    ) -> list[WorkFigure]:
        if not learned or "error" in learned:
            return []
        from ..learn.dataset import CalibrationDataset
        from . import learning

        predict = learning.net_predictor(out, learned["models"]["nlipsnet"], cfg.net.threads)
        titles = {
            n: f"{role}: {n.split('-p')[0]}"
            for role in ("seen", "unseen")
            for n in learned["names"][role][: cfg.figure_presses]
        }
        views = learning.predicted_views(out, predict, list(titles))
        if not views:
            return []
        # each press's contact AAE as the tables score a split (learn() wrote the dataset in this run)
        data = CalibrationDataset(Path(out) / learning.DATASET_DIR)
        scores = learning.press_scores(data, predict, [n for n, _ in views])
        fig.nlipsnet_maps(
            [(titles[n], v) for n, v in views], folder / NORMALS.file, title=NORMALS.caption, scores=scores
        )
        return [NORMALS]


def _by_indenter(data: CalibrationDataset, splits: dict[str, list[str]]) -> dict[str, list[str]]:
    """ "split/indenter" -> the split's press names of that indenter kind, kinds in order of appearance."""
    return {
        f"{split}/{kind}": [n for n in names if data.entry(n)["press"]["indenter"] == kind]
        for split, names in splits.items()
        for kind in dict.fromkeys(data.entry(n)["press"]["indenter"] for n in names)
    }


def _nan(value: float | None) -> float:
    return float("nan") if value is None else float(value)
