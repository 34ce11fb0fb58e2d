"""Local worker processes and a 2-worker Dask LocalCluster give identical numbers, even when a worker is
killed in the middle of the sweep (its press is re-run elsewhere, nothing else is lost)."""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
from pathlib import Path

import pytest

from nlipscalib import progress
from nlipscalib.experiments import get
from nlipscalib.experiments.framework import run_experiment
from tests.processes import wait_until

psutil = pytest.importorskip("psutil")
distributed = pytest.importorskip("distributed")


def _in_thread(fn) -> tuple[threading.Thread, dict]:
    box: dict = {}

    def target():
        try:
            box["doc"] = fn()
        except BaseException as exc:  # surfaced by the test
            box["error"] = exc

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    return thread, box


def _wait(predicate):
    """``predicate()``'s first true value (600 s at most)."""
    value = wait_until(predicate, 600.0)
    assert value, "the sweep did not get there in time"
    return value


def _worker_processes() -> list:
    """This process's local experiment workers (spawned children; not multiprocessing's resource tracker)."""
    found = []
    for child in psutil.Process().children(recursive=True):
        try:
            if "spawn_main" in " ".join(child.cmdline()):
                found.append(child)
        except psutil.Error:  # exited meanwhile
            pass
    return found


def _pid_in_a_press(out: Path, pids) -> int | None:
    """A process of ``pids`` that holds a press task's claim now, i.e. is in the middle of that press (killing
    one after a fixed delay could hit a worker between tasks, or find the sweep already over on a fast machine)."""
    for path in (out / "tasks").glob(".claim-*"):
        if path.name.startswith(".claim-cal-"):
            continue
        try:
            pid = json.loads(path.read_text(encoding="utf-8"))["pid"]
        except (OSError, ValueError, KeyError):  # released or being written meanwhile
            continue
        if pid in pids:
            return pid
    return None


def _sweep(out: Path, **kw) -> dict:
    exp = get("q1")
    return run_experiment(exp, exp.config("quick"), out, out / "report", size="quick", progress=False, **kw)


def _numbers(doc: dict) -> list[dict]:
    return [{k: v for k, v in e.items() if k != "map"} for e in doc["evaluations"]]


@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    """Two local worker processes; one is killed while the presses are being rendered/solved."""
    out = tmp_path_factory.mktemp("local")
    deaths: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: deaths.append(record.getMessage()) if "died" in record.getMessage() else None
    logging.getLogger("nlipscalib.experiments.runner").addHandler(handler)
    progress.configure(progress=False, log_file=out / "log.txt")  # --log-file: the workers append to it too
    thread, box = _in_thread(lambda: _sweep(out, workers=2))  # noqa: B023
    os.kill(_wait(lambda: _pid_in_a_press(out, {w.pid for w in _worker_processes()})), signal.SIGKILL)
    thread.join(timeout=900)
    progress.configure(progress=False, log_file=None)
    logging.getLogger("nlipscalib.experiments.runner").removeHandler(handler)
    logged = (out / "log.txt").read_text(encoding="utf-8")
    assert "nlipscalib.solver" in logged, logged[-2000:]  # solves run in the worker processes only
    assert "error" not in box, box.get("error")
    assert deaths, "the killed worker was not noticed"
    return box["doc"]


def test_local_sweep_survives_a_killed_worker(local_run):
    assert local_run["tasks"]["failed"] == {}
    assert len(local_run["evaluations"]) == 4
    assert all(e["error"] is None for e in local_run["evaluations"])


def test_dask_cluster_gives_identical_numbers_despite_a_killed_worker(local_run, tmp_path, caplog):
    from distributed import Client, LocalCluster

    caplog.set_level(logging.WARNING)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        with Client(cluster) as client:
            thread, box = _in_thread(lambda: _sweep(tmp_path, scheduler=cluster.scheduler_address))
            pids = set(client.run(os.getpid).values())
            # the nanny restarts it; its task runs again
            os.kill(_wait(lambda: _pid_in_a_press(tmp_path, pids)), signal.SIGKILL)
            thread.join(timeout=900)
    assert "error" not in box, box.get("error")
    doc = box["doc"]
    assert doc["tasks"]["failed"] == {}
    assert _numbers(doc) == _numbers(local_run)  # bit-identical accuracy numbers
    assert doc["tables"] == local_run["tables"]


def test_nlipsnet_samples_and_scores_are_identical_on_a_dask_cluster(tmp_path):
    """Q2's press tasks write the same calibration samples on Dask workers as in this process, so the trained
    NLiPsNet and its scores are the same too (a tiny Q2: 2 calibration presses, one test press of each kind)."""
    import dataclasses
    import json

    import numpy as np

    from nlipscalib.experiments.plan import PressSet
    from nlipscalib.experiments.summary import clean
    from nlipscalib.learn.dataset import ENTRY_KEY
    from nlipscalib.pipeline import capture_identity

    exp = get("q2")
    quick = exp.config("quick")
    cfg = dataclasses.replace(
        quick,
        train=dataclasses.replace(quick.train, count=2),
        seen=dataclasses.replace(quick.seen, count=1),
        unseen=PressSet(indenters=quick.unseen.indenters[:1], count=1, seed=2),
        net=dataclasses.replace(quick.net, max_epochs=3),
        upper_bound=False,
        figure_presses=1,
    )
    docs = {}
    for where, kw in (("here", {}), ("dask", {"scheduler": "local:2"})):
        out = tmp_path / where
        docs[where] = run_experiment(exp, cfg, out, out / "report", size="custom", progress=False, **kw)
    assert docs["here"]["tasks"]["failed"] == {} == docs["dask"]["tasks"]["failed"]
    for shard in sorted((tmp_path / "here" / "calibration" / "samples").glob("*.npz")):
        with np.load(shard) as a, np.load(tmp_path / "dask" / "calibration" / "samples" / shard.name) as b:
            assert set(a.files) == set(b.files)
            for key in set(a.files) - {ENTRY_KEY}:
                np.testing.assert_array_equal(a[key], b[key])
            here, dask = (json.loads(bytes(f[ENTRY_KEY])) for f in (a, b))
            # the same task (stamp) wrote both; their press folders differ by the run's output folder only, and their
            # captures by the render each run made (meta.json records its render_seconds): each names its own
            for entry in (here, dask):
                assert entry.pop("capture_identity") == capture_identity(entry["folder"])
            assert Path(here.pop("folder")).name == Path(dask.pop("folder")).name and here == dask
    assert clean(docs["dask"]["learned"]["scores"]) == clean(docs["here"]["learned"]["scores"])  # NaN-safe
    assert clean(_numbers(docs["dask"])) == clean(_numbers(docs["here"]))


def test_dask_workers_that_indented_a_gel_exit_cleanly():
    """A Dask worker runs tasks in a thread: pymeshlab (the indentation's mesh subdivision) first imported there
    corrupted the heap, and every worker that had rendered a press aborted when the cluster closed ("malloc_
    consolidate(): unaligned fastbin chunk detected", "Worker process N was killed by signal 6")."""
    import numpy as np
    import trimesh

    from nlipscalib.experiments.runner import _backend
    from nlipscalib.sim.indent import _subdivide

    said: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: said.append(record.getMessage())
    nanny = logging.getLogger("distributed.nanny")
    nanny.addHandler(handler)
    sphere = trimesh.creation.icosphere(subdivisions=3)
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    try:
        backend = _backend("local:1", 1)
        with backend:
            v, f = backend.client.submit(_subdivide, vertices, faces, np.ones(len(faces), bool)).result()
    finally:
        nanny.removeHandler(handler)
    assert len(f) == 4 * len(faces)  # each face split in four
    assert not [m for m in said if "killed by signal" in m], said


def test_a_dask_sweep_starts_no_task_after_one_failed_on_a_full_disk(tmp_path, monkeypatch):
    """As the local runner: once a task fails for lack of space, the tasks not started are cancelled (one Dask
    worker thread in this process, so the tasks see this test's stand-ins)."""
    import errno
    import time

    from nlipscalib.experiments import runner
    from nlipscalib.experiments import tasks as tasks_mod
    from nlipscalib.experiments.tasks import Task

    started = []

    def reference(task, out, threads, keep):
        started.append(task.id)
        time.sleep(0.5)  # long enough that the cancel comes while later tasks wait, even under load
        if task.id == "ref-0":
            raise OSError(errno.ENOSPC, "No space left on device", str(out / "refs" / task.id / "dark.png"))
        return {"folder": "refs/x"}

    monkeypatch.setattr(tasks_mod, "_run_reference", reference)
    tasks = [Task(kind="reference", id=f"ref-{i}", scene={"i": i}) for i in range(12)]
    backend = runner._backend(None, 1)
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None)
    backend.client, backend.cluster_workers = distributed.Client(cluster), 1
    status = runner.RunStatus()
    try:
        backend._dask(tasks, tmp_path, False, status, runner._bar(len(tasks), 0, False, "tasks"))
    finally:
        backend.client.close()
        cluster.close()
    assert status.no_space and list(status.failed) == ["ref-0"]
    assert len(started) < len(tasks), started  # those not started were cancelled
    assert set(status.done) == set(started[1:]), (started, status)  # one under way finished and was recorded
