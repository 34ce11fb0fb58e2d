"""A task's numbers are made on one BLAS thread in every library, also where a library is first loaded inside the
task: the first task of a fresh worker process (the local pool's replacement of a killed worker runs its task again
as its first)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

# a fresh interpreter, as a worker process: SciPy's BLAS is first loaded inside the task, as the solver loads it
_TASK_IN_A_FRESH_PROCESS = """
import json, sys
from nlipscalib.experiments import tasks
from nlipscalib.experiments.tasks import Task

assert "scipy.linalg" not in sys.modules, "SciPy's BLAS is loaded before the task: the check would be vacuous"


def reference(task, out, threads, keep):
    import scipy.linalg  # noqa: F401  (loads SciPy's own OpenBLAS, as the solver's first use does)
    from threadpoolctl import threadpool_info

    from nlipscalib.core.blas import blas_threads

    with blas_threads(1):  # a solver's block, as on the pool's threads: it must not restore the cores' count after
        pass

    return {"blas": {info["filepath"]: info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"}}


tasks._run_reference = reference
print(tasks.execute(Task(kind="reference", id="ref-0", scene={}), sys.argv[1]))
"""


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: every library runs on one thread anyway")
def test_a_fresh_processs_first_task_runs_every_blas_library_on_one_thread(tmp_path):
    # no thread settings in the environment, as a local pool's worker process (Dask's nanny sets them)
    env = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[2]), env.get("PYTHONPATH", "")])
    done = subprocess.run(
        [sys.executable, "-c", _TASK_IN_A_FRESH_PROCESS, str(tmp_path)], env=env, capture_output=True, text=True
    )
    assert done.returncode == 0 and done.stdout.strip() == "done", done.stderr[-2000:]
    blas = json.loads((tmp_path / "tasks" / "ref-0.json").read_text(encoding="utf-8"))["blas"]
    assert len(blas) >= 2, blas  # NumPy's and SciPy's own OpenBLAS
    assert set(blas.values()) == {1}, blas
