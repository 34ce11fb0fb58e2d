"""core.main_guard: a script's call that starts worker processes outside its `if __name__ == "__main__":` guard."""

import subprocess
import sys

import pytest

CALL = 'from nlipscalib.core.main_guard import check_main_guarded\ncheck_main_guarded("starting workers")\n'


def _run_script(tmp_path, text: str) -> subprocess.CompletedProcess:
    script = tmp_path / "script.py"
    script.write_text(text, encoding="utf-8")
    return subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize(
    "text",
    [
        'import sys\nif __name__ == "__main__":\n    ' + CALL.replace("\n", "\n    "),
        "def main():\n    " + CALL.replace("\n", "\n    ") + '\n\nif "__main__" == __name__:\n    main()\n',
        'try:\n    if __name__ == "__main__":\n        ' + CALL.replace("\n", "\n        ") + "\nfinally:\n    pass\n",
    ],
    ids=["guarded", "a function called under the guard", "a guard inside a top-level block"],
)
def test_a_call_under_the_main_guard_passes(tmp_path, text):
    done = _run_script(tmp_path, text)
    assert done.returncode == 0, done.stderr


def test_a_call_at_the_scripts_top_level_names_the_script_and_line(tmp_path):
    """The workers import the script again and ran the call again, each failing with multiprocessing's bootstrapping
    traceback; the call returned every press as 'a solver process was killed'."""
    done = _run_script(tmp_path, "import os\n" + CALL)
    assert done.returncode == 1
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith("nlipscalib.core.errors.ConfigError: ")
    assert f"{tmp_path / 'script.py'}, line 3: starting workers at the script's top level" in last
    assert 'call it under `if __name__ == "__main__":`' in last


def test_nothing_is_checked_without_a_script(tmp_path):
    """`python -c`, a notebook (no __main__ file): their workers import no script of the caller's."""
    done = subprocess.run([sys.executable, "-c", CALL], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def test_solve_presses_in_processes_from_an_unguarded_script_is_refused_before_any_worker(tmp_path):
    from tests.solver import synth

    for name, kind in (("reference", "none"), ("press_a", "sphere"), ("press_b", "cube")):
        synth.make_press(tmp_path / name, kind, size=(64, 48))
    script = (
        "from pathlib import Path\nfrom nlipscalib.pipeline import solve_presses\n"
        f"root = Path({str(tmp_path)!r})\n"
        'solve_presses([root / "press_a", root / "press_b"], reference=root / "reference", workers=2)\n'
    )
    done = _run_script(tmp_path, script)
    assert done.returncode == 1
    assert "line 4: solving presses in 2 processes (workers=2) at the script's top level" in done.stderr
    assert "bootstrapping phase" not in done.stderr and "killed" not in done.stderr
    assert not (tmp_path / "press_a" / "nlips").exists()


def test_run_experiment_in_processes_from_an_unguarded_script_is_refused_before_any_work(tmp_path):
    """run_experiment's own worker pool (spawned: each worker imports the script again) had no check."""
    script = (
        "from pathlib import Path\nfrom nlipscalib.experiments.framework import run_experiment\n"
        f"root = Path({str(tmp_path)!r})\n"
        'run_experiment(None, None, root / "work", root / "report", size="quick", workers=2)\n'
    )
    done = _run_script(tmp_path, script)
    assert done.returncode == 1
    last = done.stderr.strip().splitlines()[-1]
    assert "line 4: running the experiment's tasks in 2 processes (workers=2) at the script's top level" in last
    assert not (tmp_path / "work").exists() and not (tmp_path / "report").exists()


def test_run_experiment_on_a_local_cluster_from_an_unguarded_script_names_the_in_process_way_out(tmp_path):
    """Its refusal ended "(or with workers=1)", the hint of a worker pool: a local Dask cluster runs its workers
    whatever ``workers`` is; ``scheduler=None`` (and workers=1) runs the tasks in the script's process."""
    script = (
        "from pathlib import Path\nfrom nlipscalib.experiments.framework import run_experiment\n"
        f"root = Path({str(tmp_path)!r})\n"
        'run_experiment(None, None, root / "work", root / "report", size="quick", scheduler="local:2")\n'
    )
    done = _run_script(tmp_path, script)
    assert done.returncode == 1
    last = done.stderr.strip().splitlines()[-1]
    assert "line 4: running the experiment's tasks on a local cluster of 2 processes (local:2)" in last
    assert last.endswith('call it under `if __name__ == "__main__":` (or with scheduler=None and workers=1)')
    assert not (tmp_path / "work").exists() and not (tmp_path / "report").exists()
