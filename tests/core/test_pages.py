"""The ``nlips`` command's NumPy arrays on ordinary pages, for its process and the processes it starts, unless the
user chose NumPy's huge-page advice themselves."""

import os
import subprocess
import sys

import pytest

from nlipscalib.core import pages

pytestmark = pytest.mark.skipif(pages._setter() is None, reason="this NumPy has no huge-page switch")

CHILD_ADVICE = "from nlipscalib.core import pages; print(pages._setter()(True))"


@pytest.fixture
def advice():
    """NumPy's advice as it was, restored after the test (the switch is process-wide)."""
    setter = pages._setter()
    original = setter(True)
    setter(original)
    yield setter
    setter(original)


def test_the_command_turns_the_advice_off_here_and_in_the_processes_it_starts(advice, monkeypatch):
    monkeypatch.delenv(pages.ADVICE_VARIABLE, raising=False)
    monkeypatch.setattr(pages, "_reuse_freed_memory", lambda: None)  # this test process's allocator left alone
    advice(True)
    pages.ordinary_pages_for_command()
    assert advice(False) is False  # off in this process
    child = subprocess.run([sys.executable, "-c", CHILD_ADVICE], capture_output=True, text=True, check=True)
    assert child.stdout.strip() == "False"  # and in a worker started from it
    assert os.environ[pages.ADVICE_VARIABLE] == "0"


def test_a_users_own_choice_of_the_advice_is_kept(advice, monkeypatch):
    monkeypatch.setenv(pages.ADVICE_VARIABLE, "1")
    monkeypatch.setattr(pages, "_reuse_freed_memory", lambda: None)
    advice(True)
    pages.ordinary_pages_for_command()
    with pages.ordinary_pages():  # the solver's block respects it too
        assert advice(True) is True
    assert os.environ[pages.ADVICE_VARIABLE] == "1"


def test_python_dash_m_runs_the_command_entry(tmp_path):
    """``python -m nlipscalib`` goes through the console script's entry (the process-wide settings included)."""
    code = (
        "import runpy, sys; from nlipscalib.core import pages; sys.argv = ['nlips', '--version'];\n"
        "try:\n    runpy.run_module('nlipscalib', run_name='__main__')\n"
        "except SystemExit:\n    pass\n"
        "print('advice', pages._setter()(True))"
    )
    env = {k: v for k, v in os.environ.items() if k != pages.ADVICE_VARIABLE}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert "advice False" in out.stdout, out.stderr


FAULTS_OF_REPEATED_ARRAYS = """
import resource, numpy as np
a = np.ones(8 << 20); del a  # 64 MB: above glibc's largest default mmap threshold (32 MB)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(6):
    a = np.ones(8 << 20); del a
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""
IN_A_COMMAND = (
    "import subprocess, sys; from nlipscalib.core import pages; pages.ordinary_pages_for_command(); "
    "exec(sys.argv[1]); sys.stdout.flush(); subprocess.run([sys.executable, '-c', sys.argv[1]], check=True)"
)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator settings")
def test_the_command_and_its_workers_reuse_freed_memory_instead_of_faulting_fresh_pages(monkeypatch):
    """Six 64 MB arrays one after another: by default each is mapped afresh (16 k page faults each); in the
    command's process and the processes it starts, freed memory is reused."""
    monkeypatch.delenv("GLIBC_TUNABLES", raising=False)
    monkeypatch.setenv(pages.ADVICE_VARIABLE, "0")  # the same pages either way: only the allocator differs

    def faults(code: str, *args: str) -> list[int]:
        out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, check=True)
        return [int(line) for line in out.stdout.split()]

    (plain,) = faults(FAULTS_OF_REPEATED_ARRAYS)
    command, worker = faults(IN_A_COMMAND, FAULTS_OF_REPEATED_ARRAYS)
    assert plain > 6 * 16_000 * 0.9  # 6 x 64 MB of fresh 4 KiB pages
    assert command < plain / 4 and worker < plain / 4


FAULTS_OF_ARRAYS_ON_A_THREAD = """
import resource, threading, numpy as np
a = np.ones(8 << 20); del a  # 64 MB freed by the main thread
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
def work():
    for _ in range(6):
        a = np.ones(8 << 20); del a
thread = threading.Thread(target=work); thread.start(); thread.join()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator settings")
def test_in_the_command_and_its_workers_a_thread_reuses_memory_the_main_thread_freed(monkeypatch):
    """A thread's six 64 MB arrays after the main thread freed one: with an arena of its own the thread maps each
    afresh (an arena of a thread holds at most 64 MB: 16 k page faults each); with one arena for all threads it
    reuses the freed memory."""
    monkeypatch.delenv("GLIBC_TUNABLES", raising=False)
    monkeypatch.setenv(pages.ADVICE_VARIABLE, "0")

    def faults(code: str, *args: str) -> list[int]:
        out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, check=True)
        return [int(line) for line in out.stdout.split()]

    (plain,) = faults(FAULTS_OF_ARRAYS_ON_A_THREAD)
    command, worker = faults(IN_A_COMMAND, FAULTS_OF_ARRAYS_ON_A_THREAD)
    assert plain > 6 * 16_000 * 0.9  # 6 x 64 MB of fresh 4 KiB pages
    assert command < plain / 4 and worker < plain / 4


def test_a_users_own_allocator_settings_are_kept(monkeypatch):
    monkeypatch.setenv("GLIBC_TUNABLES", "glibc.malloc.arena_max=1")
    pages._reuse_freed_memory()
    assert os.environ["GLIBC_TUNABLES"] == "glibc.malloc.arena_max=1"


FAULTS_AFTER_HEAP_AHEAD = """
import resource, sys, numpy as np
from nlipscalib.core import pages
pages.ordinary_pages_for_command()
thread = pages.populate_heap_ahead(int(sys.argv[1]))
if thread is not None:
    thread.join()
before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
arrays = [np.ones(8 << 20) for _ in range(3)]  # 3 x 64 MB, all alive
print(resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before)
"""


def _kernel_at_least(major: int, minor: int) -> bool:
    """Whether this Linux kernel's version is ``major.minor`` or later."""
    numbers = os.uname().release.split("-")[0].split(".")
    try:
        return (int(numbers[0]), int(numbers[1])) >= (major, minor)
    except (IndexError, ValueError):
        return False


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or not _kernel_at_least(5, 14), reason="glibc, MADV_POPULATE_WRITE"
)
def test_memory_mapped_ahead_spares_the_arrays_their_page_faults(monkeypatch):
    """Three 64 MB arrays alive at once on the main thread: ~48 k fresh pages faulted by it; after the heap was
    mapped ahead on the thread, next to none."""
    monkeypatch.delenv("GLIBC_TUNABLES", raising=False)
    monkeypatch.setenv(pages.ADVICE_VARIABLE, "0")

    def faults(nbytes: int) -> int:
        code = FAULTS_AFTER_HEAP_AHEAD
        out = subprocess.run([sys.executable, "-c", code, str(nbytes)], capture_output=True, text=True, check=True)
        return int(out.stdout)

    plain, ahead = faults(0), faults(256 << 20)
    assert plain > 3 * 16_000 * 0.9  # 3 x 64 MB of fresh 4 KiB pages
    assert ahead < plain / 10


def test_nothing_is_mapped_ahead_outside_the_commands_allocator_settings(monkeypatch):
    """Without the command's thresholds a block this large is mapped apart and unmapped when freed: nothing to
    map ahead (a test session, a Python program calling ``cli.main``, a user's own ``GLIBC_TUNABLES``)."""
    monkeypatch.setattr(pages, "_kept", [False])
    assert pages.populate_heap_ahead(64 << 20) is None
