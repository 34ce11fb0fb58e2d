"""``python -m nlipscalib`` and ``python -m nlipscalib.cli`` run the ``nlips`` command (a Python whose venv
scripts are not on PATH, e.g. a notebook's or a scheduler's)."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("module", ["nlipscalib", "nlipscalib.cli"])
def test_python_dash_m_runs_the_nlips_command(module, tmp_path):
    ok = subprocess.run([sys.executable, "-m", module, "solve", "--help"], capture_output=True, text=True, cwd=ROOT)
    assert ok.returncode == 0 and ok.stdout.startswith("usage: nlips solve"), ok.stderr
    bad = subprocess.run(
        [sys.executable, "-m", module, "solve", str(tmp_path / "missing")], capture_output=True, text=True, cwd=ROOT
    )
    assert bad.returncode != 0 and "Traceback" not in bad.stderr
    assert "missing" in bad.stderr


def test_the_command_ends_once_its_work_is_done_with_the_solvers_thread_pool_idle(tmp_path):
    """The solver's threads are a concurrent.futures pool kept for the process: ``command()`` ends the process
    itself (cli._exit), and joining those idle threads without telling them to end waited forever."""
    from tests.solver import synth

    press = synth.make_press(tmp_path / "p", "sphere", size=(48, 36))
    run = subprocess.run(
        [sys.executable, "-m", "nlipscalib", "--no-progress", "solve", str(press), "--no-figures"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    assert (press / "nlips" / "result.npz").exists()


FREEZE_COUNT_AT_EXIT = (
    "import atexit, gc, sys\n"
    "atexit.register(lambda: print('enabled', gc.isenabled(), 'frozen', gc.get_freeze_count()))\n"
    "sys.argv = ['nlips', '--no-progress', 'solve', sys.argv[1], '--no-figures', '--overwrite']\n"
    "from nlipscalib.cli import command\n"
    "command()\n"
)


def test_nlips_solve_leaves_its_imported_modules_out_of_the_garbage_collectors_walks_in_its_own_process_only(
    tmp_path,
):
    """``nlips solve`` collects no garbage while it imports the solver and then freezes the objects of the modules
    it imported (gc.freeze: a full collection no longer walks them) in the command's own process; ``cli.main``
    called from Python (a test session, a notebook) freezes nothing, as its objects would never be collected."""
    import gc

    from nlipscalib.cli import main
    from tests.solver import synth

    press = synth.make_press(tmp_path / "p", "sphere", size=(48, 36))
    run = subprocess.run(
        [sys.executable, "-c", FREEZE_COUNT_AT_EXIT, str(press)], capture_output=True, text=True, cwd=ROOT, timeout=300
    )
    assert run.returncode == 0, run.stderr
    assert int(run.stdout.split("frozen")[-1]) > 10_000  # NumPy's, SciPy's and the solver's modules
    assert "enabled True" in run.stdout  # collecting again after the imports
    before = gc.get_freeze_count()
    assert main(["--no-progress", "solve", str(press), "--no-figures", "--overwrite"]) == 0
    assert gc.get_freeze_count() == before and gc.isenabled()


HEAP_AHEAD_AT_EXIT = (
    "import atexit, sys\n"
    "from nlipscalib.core import pages\n"
    "calls = []\n"
    "populate = pages.populate_heap_ahead\n"
    "def spy(nbytes):\n"
    "    thread = populate(nbytes)\n"
    "    calls.append((nbytes, thread is not None))\n"
    "    return thread\n"
    "pages.populate_heap_ahead = spy\n"
    "atexit.register(lambda: print('calls', calls))\n"
    "sys.argv = ['nlips', '--no-progress', 'solve', sys.argv[1], '--no-figures', '--overwrite']\n"
    "from nlipscalib.cli import command\n"
    "command()\n"
)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator settings")
def test_nlips_solve_maps_its_memory_ahead_in_its_own_process_only(tmp_path, monkeypatch):
    """``nlips solve PRESS`` grows the heap by its share of an auto-ROI solve's modelled arrays and starts the thread
    that maps it (core.pages.populate_heap_ahead); ``cli.main`` from Python, whose allocator keeps its settings, maps
    nothing ahead."""
    from nlipscalib.cli import main
    from nlipscalib.cli.solve import HEAP_AHEAD_SHARE
    from nlipscalib.core import pages
    from nlipscalib.core.cpus import SOLVE_ROI_MEMORY
    from tests.solver import synth

    monkeypatch.delenv("GLIBC_TUNABLES", raising=False)
    press = synth.make_press(tmp_path / "p", "sphere", size=(48, 36))
    run = subprocess.run(
        [sys.executable, "-c", HEAP_AHEAD_AT_EXIT, str(press)], capture_output=True, text=True, cwd=ROOT, timeout=300
    )
    assert run.returncode == 0, run.stderr
    expected = int(HEAP_AHEAD_SHARE * (SOLVE_ROI_MEMORY.estimate(48, 36) - SOLVE_ROI_MEMORY.base_bytes))
    assert f"calls [({expected}, True)]" in run.stdout
    started, populate = [], pages.populate_heap_ahead
    monkeypatch.setattr(pages, "populate_heap_ahead", lambda nbytes: started.append(populate(nbytes) is not None))
    assert main(["--no-progress", "solve", str(press), "--no-figures", "--overwrite"]) == 0
    assert started == [False]  # asked, and nothing mapped: the allocator's settings are the command's alone


NUMPY_IMPORT_SEES = (
    "import os, sys\n"
    "class Spy:\n"
    "    def find_spec(self, name, path=None, target=None):\n"
    "        if name == 'numpy':\n"
    "            print('at numpy import:', os.environ.get('OPENBLAS_THREAD_TIMEOUT'), flush=True)\n"
    "            sys.meta_path.remove(self)\n"
    "sys.meta_path.insert(0, Spy())\n"
    "sys.argv = ['nlips', 'solve', '--help']\n"
    "from nlipscalib.__main__ import command\n"
    "command()\n"
)


@pytest.mark.parametrize(("users", "loaded_with"), [(None, "4"), ("20", "20")])
def test_the_command_loads_openblas_with_idle_threads_that_sleep_at_once_unless_the_user_set_it(users, loaded_with):
    """OpenBLAS reads ``OPENBLAS_THREAD_TIMEOUT`` once, when NumPy loads it: the command sets it before that import
    (its idle helper threads spun 0.03-0.04 s of CPU each per process, s32-threads), and keeps a user's own value."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_THREAD_TIMEOUT"}
    if users is not None:
        env["OPENBLAS_THREAD_TIMEOUT"] = users
    run = subprocess.run(
        [sys.executable, "-c", NUMPY_IMPORT_SEES], capture_output=True, text=True, cwd=ROOT, env=env, timeout=120
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines()[0] == f"at numpy import: {loaded_with}"
