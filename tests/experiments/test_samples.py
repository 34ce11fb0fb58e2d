"""The NLiPsNet samples a press task writes: each file carries the identity of the task that wrote it, and a run
uses only its own task's samples, whole (no render: the task's result and samples are written here)."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from nlipscalib.core.atomic import tmp_prefix, write_json
from nlipscalib.core.errors import CaptureError, ConfigError
from nlipscalib.experiments import framework, learning, tasks
from nlipscalib.experiments.framework import Experiment
from nlipscalib.experiments.runner import RunStatus, run_tasks
from nlipscalib.experiments.tasks import Task, dataset_entry, load_result, result_path, samples_path
from nlipscalib.learn.dataset import SamplingConfig, write_shard

PRESS = {"indenter": {"kind": "sphere", "size": 6.0}, "polar_deg": 10.0, "azimuth_deg": 30.0, "depth": 1.0}
SAMPLING = dataclasses.asdict(SamplingConfig())


def _task(**sampling) -> Task:
    return Task(kind="press", id="sphere-p10", scene={}, press=PRESS, samples=SAMPLING | sampling)


def _arrays(n: int = 5) -> dict:
    normal = np.tile(np.array([0, 0, -1], np.float32), (n, 1))
    return {
        "pixel": np.zeros((n, 2), np.int16),
        "rgb": np.full((n, 3), 0.5, np.float32),
        "normal": normal,
        "true_normal": normal,
        "contact": np.ones(n, bool),
        "source": np.zeros(n, np.uint8),
    }


def _info(n: int = 5) -> dict:
    return {"file": "calibration/samples/sphere-p10.npz", "count": n, "contact": n, "has_truth": True}


def _finish(out, task: Task, written_by: Task | None = None, entry: bool = True) -> None:
    """Store ``task`` as done, with samples written by ``written_by`` (default: itself; entry=False: a file of
    before samples carried their entry)."""
    writer = written_by or task
    write_shard(samples_path(out, task.id), _arrays(), dataset_entry(out, writer, _info()) if entry else None)
    body = {"id": task.id, "kind": "press", "task_hash": task.hash, "status": "done", "samples": _info()}
    body["made_with"] = tasks.made_with(task.kind, samples=True)  # made by this code: only the samples decide
    write_json(result_path(out, task.id), body)


def test_samples_rewritten_by_a_run_of_other_settings_are_not_taken_as_this_tasks(tmp_path, monkeypatch, caplog):
    """q2 run with smoothing_px = 2, then again with 1 and killed between writing a press's samples and its
    result: a third run with 2 found its own result beside the other run's samples (same sample count) and
    trained and scored on them without a word. Now the task is run again, with one line naming the file."""
    mine, other = _task(smoothing_px=2.0), _task(smoothing_px=1.0)
    _finish(tmp_path, mine, written_by=other)
    assert load_result(tmp_path, mine) is None
    ran = []

    def run_press(task, out, threads, keep):
        ran.append(task.id)
        write_shard(samples_path(out, task.id), _arrays(), dataset_entry(out, task, _info()))
        return {"samples": _info()}

    monkeypatch.setattr(tasks, "_run_press", run_press)
    with caplog.at_level("WARNING", logger="nlipscalib.experiments"):
        status = run_tasks([mine], tmp_path, progress=False)
    assert ran == status.done == [mine.id]
    lines = [r.getMessage() for r in caplog.records if "other settings" in r.getMessage()]
    assert len(lines) == 1 and str(samples_path(tmp_path, mine.id)) in lines[0], lines
    assert load_result(tmp_path, mine) is not None
    assert run_tasks([mine], tmp_path, progress=False).skipped == [mine.id]


@pytest.mark.parametrize("damage", ["truncated", "flipped"])
def test_damaged_samples_make_their_task_run_again(tmp_path, damage, monkeypatch, caplog):
    """A truncated samples file stopped the report with an error that said nothing of what to do, every run."""
    task = _task()
    _finish(tmp_path, task)
    path = samples_path(tmp_path, task.id)
    data = bytearray(path.read_bytes())
    if damage == "truncated":
        data = data[: len(data) // 2]
    else:  # a byte of a stored array
        data[len(data) // 3] ^= 0xFF
    path.write_bytes(bytes(data))
    assert load_result(tmp_path, task) is None
    monkeypatch.setattr(tasks, "_run_press", lambda *a: {"samples": None})  # the label solve failed, say
    with caplog.at_level("WARNING", logger="nlipscalib.experiments"):
        assert run_tasks([task], tmp_path, progress=False).done == [task.id]
    # a damaged array is named by the reader, which inflates the format's own arrays only (s26-untrusted)
    said = f"{path}: damaged or truncated" if damage == "truncated" else f"{path}: array '"
    assert said in caplog.text and f"running {task.id} again" in caplog.text


def test_samples_written_before_files_carried_their_task_are_kept_when_the_counts_agree(tmp_path):
    """A work folder of an earlier version is not made again for want of the stamp (as ``nlips calibrate`` keeps
    its older shards); one whose count is not its result's is."""
    task = _task()
    _finish(tmp_path, task, entry=False)
    assert load_result(tmp_path, task) is not None
    write_shard(samples_path(tmp_path, task.id), _arrays(7))
    assert load_result(tmp_path, task) is None


def test_the_dataset_refuses_samples_rewritten_after_the_tasks_ran(tmp_path):
    """Another run of other settings rewriting a press's samples between this run's tasks and its training:
    one line naming the file, never those samples under this run's stamp."""
    mine, other = _task(smoothing_px=2.0), _task(smoothing_px=1.0)
    _finish(tmp_path, mine, written_by=other)
    with pytest.raises(CaptureError, match=rf"{samples_path(tmp_path, mine.id)}: samples of this press written by"):
        learning.assemble_dataset(tmp_path, [mine], mine.samples)


def test_a_press_task_writes_samples_carrying_its_entry_and_stamp(tmp_path):
    """What the dataset checks a shard by (learn.dataset: the stamp it carries against index.json's) is there for
    the experiment's shards too: the task's entry, stamped with its hash."""
    from nlipscalib.experiments import adapters

    task = _task()
    fake = SimpleNamespace(
        calibration_samples=lambda *a: _arrays(),
        write_samples=adapters.write_samples,
        figure_view=lambda *a: {},
    )
    press = SimpleNamespace(ground_truth=None, folder=tmp_path / "gone")  # no images: no press_identity
    info = tasks._write_samples(fake, tmp_path, task, press, tmp_path, rec=object())
    entry, count = adapters.samples_entry(samples_path(tmp_path, task.id))
    assert entry == dataset_entry(tmp_path, task, info) and entry["stamp"] == task.hash and count == 5


def test_a_killed_runs_temporary_samples_are_removed_by_the_next_run(tmp_path):
    """A run killed while writing a press's samples (or its figure crop, its error map) left its temporary file
    there for good: only the tasks' folder was cleaned."""
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    left = []
    for path in (samples_path(tmp_path, "p"), tasks.view_path(tmp_path, "p"), tmp_path / "maps" / "p-key.npz"):
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.parent / (tmp_prefix(path.name).replace(f"~{os.getpid()}~", f"~{pid}~") + "x")
        tmp.write_bytes(b"half")
        left.append(tmp)
    tasks.clean_leftovers(tmp_path)
    assert not [p for p in left if p.exists()]


@dataclasses.dataclass(frozen=True)
class _Config:
    seed: int = 0
    """Decides the tasks (a twin's seed, say)."""
    hidden: int = 16
    """Decides only what is trained and reported from the tasks (a net's layers, say)."""


class _Study(Experiment):
    """An experiment of one reference task per seed, whose learn phase starts another run into the same folders."""

    name, title, description, config_cls = "study", "Study", "", _Config

    def __init__(self, inner: _Config | None = None):
        self.inner, self.outcome = inner, None

    def tasks(self, cfg: _Config, solver_options: dict | None = None) -> list[Task]:
        return [Task(kind="reference", id=f"ref-{cfg.seed}", scene={"seed": cfg.seed})]

    def learn(self, cfg: _Config, tasks: list[Task], out, progress: bool = True) -> dict:
        if self.inner is not None:  # while this run trains: another run of ``inner`` into the same folders
            try:
                framework.run_experiment(_Study(), self.inner, out, out / "report", size="custom", progress=False)
                self.outcome = "ran"
            except ConfigError as exc:
                self.outcome = str(exc)
        return {}

    def tables(self, cfg: _Config, rows: list[dict], learned: dict) -> list:
        return []


@pytest.mark.parametrize(
    ("inner", "refused"),
    [(_Config(seed=1), ("--out", "config.seed 0 (this run: 1)")), (_Config(hidden=32), ("--report", "hidden 16"))],
)
def test_a_run_of_other_settings_is_refused_while_another_holds_the_folder(tmp_path, monkeypatch, inner, refused):
    """``nlips experiment q2 --config X`` and ``--config Y`` at once on one --out: both exited 0 with one report (the
    last one's) in q2-custom/report, and with other twins one run's calibration/sensor.npz could replace the
    other's while it trained. Now the second is refused in one line naming the folder, what differs and what to do:
    other tasks by the work folder (--out), the same tasks but other settings (the net) by the report (--report)."""
    monkeypatch.setattr(framework, "run_tasks", lambda tasks, out, **kw: RunStatus())  # no render: tasks "done"
    first = _Study(inner)
    framework.run_experiment(first, _Config(), tmp_path, tmp_path / "report", size="custom", progress=False)
    folder, option = (tmp_path, "--out") if refused[0] == "--out" else (tmp_path / "report", "--report")
    assert first.outcome is not None and "\n" not in first.outcome, first.outcome
    assert first.outcome.startswith(f"{folder}: process {os.getpid()} on ") and "other settings" in first.outcome
    assert refused[1] in first.outcome and f"give another {option}" in first.outcome, first.outcome
    assert not list(tmp_path.glob(".claim-*")) and not list(tmp_path.glob("report/.claim-*"))  # released at the end


def test_runs_of_the_same_settings_share_the_folders(tmp_path, monkeypatch):
    """A second terminal running the same config (or ``presses`` beside ``q2``, whose tasks it reuses) goes on as
    before: the tasks' claims split the work."""
    monkeypatch.setattr(framework, "run_tasks", lambda tasks, out, **kw: RunStatus())
    first = _Study(_Config())
    framework.run_experiment(first, _Config(), tmp_path, tmp_path / "report", size="custom", progress=False)
    assert first.outcome == "ran"


def test_an_experiments_dataset_tells_to_run_the_experiment_again(tmp_path, monkeypatch):
    """A shard of an experiment's dataset rewritten after its index.json: ``CalibrationDataset.load`` (training,
    scoring, ``nlips train``) said "run `nlips calibrate` on its presses again", which knows nothing of the
    experiment's tasks and made a dataset elsewhere. Now one line naming the file says to run the experiment."""
    from nlipscalib.core import capture, sensor_record
    from nlipscalib.learn import dataset

    sensor = _sensor()
    cam = sensor["camera"]
    monkeypatch.setattr(capture, "load_press", lambda folder: SimpleNamespace(folder=folder))
    monkeypatch.setattr(sensor_record, "sensor_of", lambda press: sensor)
    plane = np.zeros((cam["height"], cam["width"]), np.float32)
    colour = np.zeros(plane.shape + (3,), np.float32)
    arrays = {"tricolor": colour, "dark": colour, "depth": plane, "normals": colour, "valid": plane > 0}
    monkeypatch.setattr(dataset, "reference_arrays", lambda press: arrays)
    mine, other = _task(smoothing_px=2.0), _task(smoothing_px=1.0)
    _finish(tmp_path, mine)
    data, _ = learning.assemble_dataset(tmp_path, [mine], mine.samples)
    assert data.load(mine.id)["rgb"].shape == (5, 3)
    write_shard(samples_path(tmp_path, mine.id), _arrays(), dataset_entry(tmp_path, other, _info()))
    with pytest.raises(CaptureError) as caught:
        data.load(mine.id)
    said = str(caught.value)
    assert said.startswith(f"{samples_path(tmp_path, mine.id)}: made from other") and "\n" not in said, said
    assert "nlips calibrate" not in said and f"run the experiment again on its work folder {tmp_path}" in said, said


def _sensor() -> dict:
    """The default design's sensor description (what index.json records)."""
    from nlipscalib.core.capture import SensorResponse
    from nlipscalib.core.sensor import SensorDesign
    from nlipscalib.core.sensor_record import describe_sensor

    design = SensorDesign()
    return describe_sensor(design.camera_model(), design.led_models(), SensorResponse())


def test_a_bumped_sampling_rule_makes_the_press_tasks_samples_anew(tmp_path, monkeypatch):
    """``nlips calibrate``'s shard stamp holds the change-detection rule's version, so a changed rule re-samples its
    presses; an experiment's press task hash did not, and its samples stayed the old rule's for good. Both now take
    the one list (learn.dataset.SAMPLE_RULES); the versions of 2026-12-05 (tasks.RULES_HASHED_SILENTLY) leave the
    hash as it was then (work folders of that day keep their tasks), and tasks without samples are untouched."""
    from nlipscalib.learn import dataset

    task, plain = _task(), Task(kind="reference", id="ref-x", scene={})
    fields = {k: v for k, v in dataclasses.asdict(task).items() if k != "keep_old"}  # which result, not what
    today = task.hash
    with monkeypatch.context() as then:
        then.setattr(dataset, "SAMPLE_RULES", dict(tasks.RULES_HASHED_SILENTLY))
        assert task.hash == tasks.digest(fields)
    assert today == tasks.digest(fields | {"sample_rules": dataset.SAMPLE_RULES})  # the dimmed-press rule since
    _finish(tmp_path, task)
    assert load_result(tmp_path, task) is not None
    run = dataset.dataset_run([], tmp_path, SamplingConfig())
    was = {"task": task.hash, "plain": plain.hash, "run": run["key"]}
    monkeypatch.setattr(dataset, "SAMPLE_RULES", dataset.SAMPLE_RULES | {"rule": dataset.RULE_VERSION + 1})
    assert task.hash != was["task"] and plain.hash == was["plain"]
    assert dataset.dataset_run([], tmp_path, SamplingConfig())["key"] != was["run"]
    assert load_result(tmp_path, task) is None  # the run makes it again


def test_an_experiments_dataset_records_the_capture_each_press_tasks_labels_were_solved_from(tmp_path, monkeypatch):
    """A press task's samples record the identity of the capture its label solve read (``provenance.inputs.press``,
    as `nlips calibrate`'s do), and the experiment's index.json carries it: a model trained or a table fitted there
    then tells its presses from the others (report.json `trained_on`). The press here is solved by the experiments'
    own solving path (``adapters.solve``: the pipeline), on an exact-data 64x48 press; a task result of before,
    without it, gives an entry without it."""
    from nlipscalib.core import capture, sensor_record
    from nlipscalib.core.press_identity import press_identity
    from nlipscalib.experiments import adapters
    from nlipscalib.learn import dataset
    from nlipscalib.pipeline import capture_identity
    from nlipscalib.solver import SolverOptions
    from tests.solver import synth

    folder = tmp_path / "presses" / "sphere-p10"
    synth.make_press(folder, "sphere", size=(64, 48))
    press = adapters.load(folder)
    rec = adapters.solve(
        press, out=folder / "solves" / "x", interreflection="off", roi="full", options=SolverOptions(max_iters=4)
    )
    task = _task()
    fake = SimpleNamespace(
        calibration_samples=lambda *a: _arrays(),
        write_samples=adapters.write_samples,
        figure_view=lambda *a: {},
    )
    info = tasks._write_samples(fake, tmp_path, task, press, tmp_path, rec=rec)
    identity = capture_identity(folder)
    assert info["capture_identity"] == identity
    entry, _ = adapters.samples_entry(samples_path(tmp_path, task.id))
    assert entry["capture_identity"] == identity and entry == dataset_entry(tmp_path, task, info)
    assert entry["press_identity"] == press_identity(folder) == info["press_identity"]  # by content (s43-pressid)

    sensor = _sensor()
    cam = sensor["camera"]
    monkeypatch.setattr(capture, "load_press", lambda where: SimpleNamespace(folder=where))
    monkeypatch.setattr(sensor_record, "sensor_of", lambda where: sensor)
    plane = np.zeros((cam["height"], cam["width"]), np.float32)
    colour = np.zeros(plane.shape + (3,), np.float32)
    arrays = {"tricolor": colour, "dark": colour, "depth": plane, "normals": colour, "valid": plane > 0}
    monkeypatch.setattr(dataset, "reference_arrays", lambda where: arrays)
    body = {"id": task.id, "kind": "press", "task_hash": task.hash, "status": "done", "samples": info}
    write_json(result_path(tmp_path, task.id), body | {"made_with": tasks.made_with(task.kind, samples=True)})
    data, _ = learning.assemble_dataset(tmp_path, [task], task.samples)
    assert data.entry(task.id)["capture_identity"] == identity and data.load(task.id)["rgb"].shape == (5, 3)
    index = json.loads((data.folder / "index.json").read_text(encoding="utf-8"))
    assert index["presses"][0]["capture_identity"] == identity

    del info["capture_identity"]  # a task run before its samples recorded the capture
    assert "capture_identity" not in dataset_entry(tmp_path, task, info)
