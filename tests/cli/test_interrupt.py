"""Ctrl-C during a command: one line, exit 130, whatever exception the interrupted code turned it into."""

from __future__ import annotations

import os
import signal

import pytest

from nlipscalib import cli
from nlipscalib.cli import cache, main


@pytest.fixture
def default_sigint():
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # as a command-line process has it
    yield
    signal.signal(signal.SIGINT, previous)


def _interrupted_inside_a_native_library(args):
    try:
        os.kill(os.getpid(), signal.SIGINT)
        raise AssertionError("the interrupt did not arrive")
    except KeyboardInterrupt as exc:  # what drjit does with it: its own exception
        raise RuntimeError("drjit.custom(...): error while performing a custom differentiable operation") from exc


def test_ctrl_c_turned_into_another_exception_still_reads_as_an_interruption(monkeypatch, capsys, default_sigint):
    monkeypatch.setattr(cache, "run", _interrupted_inside_a_native_library)
    assert main(["cache"]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "Traceback" not in err and "drjit" not in err
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handler is put back


def test_the_same_exception_without_ctrl_c_is_not_hidden(monkeypatch, default_sigint):
    def fails(args):
        raise RuntimeError("a real bug")

    monkeypatch.setattr(cache, "run", fails)
    with pytest.raises(RuntimeError, match="a real bug"):
        main(["cache"])
    assert not cli._INTERRUPTED


TERMINATED = "nlips solve: terminated; finished work is kept, run again to resume"

BATCH = 36
"""Presses of the solve batches below: when the first result appears, 34 or more are left for two workers, over
a second of solving (0.1-0.3 s a press), so the batch cannot end before the signal does (with 6, it could)."""


def _batch(root) -> None:
    """:data:`BATCH` 64x48 presses in ``root``: six rendered, the others copies of them (copying costs nothing)."""
    import shutil

    from tests.solver import synth

    for i in range(6):
        synth.make_press(root / f"p{i:02d}", "sphere" if i % 2 else "cube", depth=1.0 + 0.1 * i, size=(64, 48))
    for i in range(6, BATCH):
        shutil.copytree(root / f"p{i % 6:02d}", root / f"p{i:02d}")


def test_sigterm_of_a_parallel_solve_is_one_line_without_leaked_semaphore_warnings(tmp_path):
    """`kill -TERM -PGID` of `nlips solve DATASET --workers 2`: the one line, exit 143, nothing after it.

    The worker pool's named semaphores used to outlive the process (os._exit skips multiprocessing's
    finalizers), and its resource tracker then printed "There appear to be N leaked semaphore objects".
    """
    import contextlib
    import subprocess
    import sys
    import time

    _batch(tmp_path)  # enough presses that the pool is still busy when the first result appears
    command = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
    argv = [sys.executable, "-c", command, "--no-progress", "solve", str(tmp_path), "--workers", "2", "--no-figures"]
    proc = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not list(tmp_path.glob("*/nlips/result.npz")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        os.killpg(proc.pid, signal.SIGTERM)  # a scheduler's time limit: the whole process group
        _, err = proc.communicate(timeout=60)  # to EOF: the resource tracker's stderr too
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 128 + signal.SIGTERM, err
    not_log = [line for line in err.splitlines() if not line.startswith(("INFO ", "WARNING "))]
    assert not_log == [TERMINATED], err
    assert not [p for p in tmp_path.rglob("*") if p.name.startswith((".claim-", ".tmp-"))]


FREED_BEFORE_THE_WORKERS_END = """
import multiprocessing
from multiprocessing import synchronize, util

from nlipscalib import cli

lock = multiprocessing.get_context("spawn").Lock()  # a pool's or a Dask nanny's queue lock: a named semaphore


def stop_workers():  # what is still to be freed when the workers end (and other threads free their queues)
    left = [f for f in list(util._finalizer_registry.values()) if f._callback is synchronize.SemLock._cleanup]
    print(len(left), flush=True)


cli._stop_workers = stop_workers
cli._end_at_once(None, 0)
"""


def test_a_terminated_command_frees_its_semaphores_before_its_workers_end():
    """After SIGTERM of `nlips experiment --scheduler local:2` (2 runs in 4 under load), the resource tracker warned
    of "1 leaked semaphore objects" and "'/mp-...': [Errno 2] No such file or directory" after the command's line:
    the workers' end made the nannies' event loop thread free their queues, and a semaphore's finalizer, which
    runs once in the first thread that calls it, was still between unlinking and unregistering there when the
    command's os._exit came. The command now frees them itself, in its handler, before it ends its workers."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", FREED_BEFORE_THE_WORKERS_END], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "0"  # none left to free by another thread
    assert done.stderr == ""  # the resource tracker found nothing to warn of


def _live_members(group: int) -> list[int]:
    """Processes of the process group ``group`` that still run (zombies, whose reaping init may delay, excepted)."""
    from pathlib import Path

    pids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text(encoding="utf-8")
        except OSError:  # ended meanwhile
            continue
        state, _, pgrp = text[text.rindex(")") + 2 :].split()[:3]
        if int(pgrp) == group and state not in ("Z", "X"):
            pids.append(int(stat.parent.name))
    return pids


def _wait_until_gone(group: int, seconds: float) -> list[int]:
    import time

    deadline = time.monotonic() + seconds
    while _live_members(group) and time.monotonic() < deadline:
        time.sleep(0.1)
    return _live_members(group)


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads the process table from /proc")
def test_sigterm_of_the_command_alone_stops_its_workers(tmp_path):
    """`kill PID` of `nlips solve DATASET --workers 2` (the command's process only, not its group): the parent
    printed "terminated" and exited 143, but its workers went on, published results after that line and then
    waited forever for tasks. Now they end with it, releasing their claims."""
    import contextlib
    import subprocess
    import sys
    import time

    _batch(tmp_path)
    command = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
    argv = [sys.executable, "-c", command, "--no-progress", "solve", str(tmp_path), "--workers", "2", "--no-figures"]
    log = tmp_path / "stderr.txt"
    with open(log, "w", encoding="utf-8") as err:  # a file, not a pipe: workers left running would hold a pipe open
        proc = subprocess.Popen(argv, stderr=err, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not list(tmp_path.glob("*/nlips/result.npz")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert proc.poll() is None, log.read_text(
            encoding="utf-8"
        )  # still solving: the rest of the batch is in the pool
        os.kill(proc.pid, signal.SIGTERM)  # the command's process only
        assert proc.wait(timeout=60) == 128 + signal.SIGTERM, log.read_text(encoding="utf-8")
        assert _wait_until_gone(proc.pid, 30) == []  # no worker (nor forkserver) left running
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    not_log = [
        line for line in log.read_text(encoding="utf-8").splitlines() if not line.startswith(("INFO ", "WARNING "))
    ]
    assert not_log == [TERMINATED]
    assert not [p for p in tmp_path.rglob("*") if p.name.startswith((".claim-", ".tmp-"))]


DATASET_POOL = """
import sys
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

from nlipscalib import cli
from nlipscalib.progress import worker_logging
from nlipscalib.sim import dataset_pool
from tests.cli.test_interrupt import _render_forever

cli._terminate_cleanly("dataset")  # as `nlips dataset` runs: its handler, its pool
out = Path(sys.argv[1])
context, init = get_context("spawn"), dataset_pool._worker_init
with ProcessPoolExecutor(2, mp_context=context, initializer=init, initargs=worker_logging()) as pool:
    for future in [pool.submit(_render_forever, out / f"press_{i:04d}") for i in range(2)]:
        future.result()
"""


def _render_forever(press) -> None:
    """A render worker's task that never ends: the press claimed, its folder half-written, and its pid noted."""
    import time

    from nlipscalib.core.atomic import atomic_dir
    from nlipscalib.core.claims import claim

    with claim(press) as mine, atomic_dir(press) as tmp:
        assert mine
        (tmp / "led_01.png").write_bytes(b"half")
        (press.parent / f"worker.{os.getpid()}").touch()
        time.sleep(120)


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads the process table from /proc")
def test_sigterm_of_a_dataset_run_ends_its_render_workers_which_release_their_claims(tmp_path):
    """`nlips dataset --workers 2` uses a pool of its own (spawn): a plain `kill PID` left its render workers
    running, and a worker that was terminated left its claim and half-written folder. Now the command ends
    them and each releases its claim and removes its temporary folder."""
    import contextlib
    import subprocess
    import sys
    import time
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
    log = tmp_path / "stderr.txt"
    with open(log, "w", encoding="utf-8") as err:
        proc = subprocess.Popen(
            [sys.executable, "-c", DATASET_POOL, str(tmp_path)], stderr=err, env=env, start_new_session=True
        )
    try:
        deadline = time.monotonic() + 120
        while len(list(tmp_path.glob("worker.*"))) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(list(tmp_path.glob("worker.*"))) == 2, log.read_text(encoding="utf-8")
        assert len(list(tmp_path.glob(".claim-press_*"))) == 2
        os.kill(proc.pid, signal.SIGTERM)
        assert proc.wait(timeout=60) == 128 + signal.SIGTERM, log.read_text(encoding="utf-8")
        assert _wait_until_gone(proc.pid, 30) == []
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert (
        log.read_text(encoding="utf-8").strip()
        == "nlips dataset: terminated; finished work is kept, run again to resume"
    )
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith((".claim-", ".tmp-"))]


INFER_STREAM = "the stream stopped (a stream does not resume; frames already saved with --out are kept)"


def test_infer_of_a_stream_says_the_stream_stopped_not_run_again_to_resume(tmp_path, monkeypatch, capsys):
    """`nlips infer MODEL --camera 0` (or --emulate, --port nlipsemu://ID, a video) stopped by SIGTERM or Ctrl-C
    said "finished work is kept, run again to resume": a stream starts over when run again. The line is chosen
    from the arguments; presses and frames keep theirs."""
    import subprocess
    import sys
    from pathlib import Path

    from nlipscalib.cli import build_parser, infer

    (tmp_path / "clip.mp4").write_bytes(b"")
    (tmp_path / "frame.png").write_bytes(b"")
    streams = [
        ["--camera", "0"],
        ["--emulate", "nlipstac"],
        ["--port", "nlipsemu://stopped"],
        [str(tmp_path / "clip.mp4")],
        [str(tmp_path / "img_%04d.png")],
    ]
    for inputs in streams:
        assert cli._stopped(build_parser().parse_args(["infer", "m.pt", *inputs])) == INFER_STREAM, inputs
    for inputs in ([str(tmp_path / "frame.png")], [str(tmp_path)]):
        assert cli._stopped(build_parser().parse_args(["infer", "m.pt", *inputs])) == cli.RESUMABLE, inputs
    assert cli._stopped(build_parser().parse_args(["solve", "x"])) == cli.RESUMABLE
    assert cli._stopped(build_parser().parse_args(["live"])).startswith("the stream stopped")

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(infer, "run", interrupted)  # Ctrl-C before the stream's own loop (loading the model)
    assert main(["infer", "m.pt", "--camera", "0"]) == 130
    assert capsys.readouterr().err.strip() == f"nlips infer: interrupted; {INFER_STREAM}"

    code = (
        "import os, signal, sys, time\nfrom nlipscalib.cli import infer, main\n"
        "def run(args):\n    os.kill(os.getpid(), signal.SIGTERM)\n    time.sleep(30)\n"
        "infer.run = run\nsys.exit(main(sys.argv[1:]))"
    )
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    for inputs, line in ((["--emulate", "nlipstac"], INFER_STREAM), ([str(tmp_path / "frame.png")], cli.RESUMABLE)):
        argv = [sys.executable, "-c", code, "infer", "m.pt", *inputs]
        proc = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=60)
        assert proc.returncode == 128 + signal.SIGTERM, proc.stderr
        assert proc.stderr.strip().splitlines()[-1] == f"nlips infer: terminated; {line}"


AFTER_THE_WORK = """
import atexit, sys, time
from nlipscalib.cli import cache, command

def exiting():  # a slow exit (a library's teardown, e.g. torch's after `nlips export` printed its line)
    print("exiting", flush=True)
    time.sleep(30)

cache.run = lambda args: 0
atexit.register(exiting)
sys.exit(command())
"""


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_after_the_work_ended_is_one_line_and_the_signals_status(signum):
    """Ctrl-C after `nlips export` printed its line (the process still exiting) printed an "Exception ignored in
    atexit callback" traceback and exited 0, or no line at all (exit 130) in the interpreter's teardown; SIGTERM
    then killed it with no line. Now both say the work had ended and keep the signal's status."""
    import sys
    from pathlib import Path

    from tests.processes import as_from_a_terminal

    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    proc = as_from_a_terminal([sys.executable, "-c", AFTER_THE_WORK, "cache"], env=env)
    try:
        assert proc.stdout.readline() == "exiting\n"
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    how = "interrupted" if signum == signal.SIGINT else "terminated"
    assert err.strip() == f"nlips cache: {how} {cli.AFTER_THE_WORK}", err
    assert proc.returncode == 128 + signum


INTERRUPTED_THEN_EXITING = """
import atexit, os, signal, sys, time
from nlipscalib.cli import cache, command

def exiting():  # a slow exit after the interruption (torch's teardown after `nlips train` was interrupted)
    print("exiting", flush=True)
    time.sleep(30)

def run(args):
    os.kill(os.getpid(), signal.SIGINT)  # the first Ctrl-C, during the work
    time.sleep(30)

cache.run = run
atexit.register(exiting)
sys.exit(command())
"""


def test_a_second_ctrl_c_while_an_interrupted_command_exits_adds_no_line():
    """A user's second Ctrl-C, as the interrupted `nlips train` was exiting, added "nlips train: interrupted after its
    work ended; what it wrote is kept" under "interrupted; finished work is kept, run again to resume": the work had
    not ended. Now the first line stands alone, and the status is still the interruption's."""
    import sys
    from pathlib import Path

    from tests.processes import as_from_a_terminal

    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    proc = as_from_a_terminal([sys.executable, "-c", INTERRUPTED_THEN_EXITING, "cache"], env=env)
    try:
        assert proc.stdout.readline() == "exiting\n"
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert err.strip() == f"nlips cache: interrupted; {cli.RESUMABLE}", err
    assert proc.returncode == 130


def test_a_stream_takes_sigterm_as_a_flag_once_armed_and_hands_a_second_to_the_handler_before():
    """``_stream.SigtermEndsStream``: before :meth:`arm` (the model loading, the emulator rendering its script) the
    command's own handler keeps SIGTERM (it ends the process at once); armed, SIGTERM only sets the flag the stream
    reads before each frame; a second goes to the handler before (a read that never returns); the ``with`` block
    puts that handler back."""
    from nlipscalib.cli._stream import SigtermEndsStream

    seen = []
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: seen.append(signum))
    try:
        with SigtermEndsStream() as term:
            os.kill(os.getpid(), signal.SIGTERM)
            assert seen == [signal.SIGTERM] and not term()  # not armed: the handler before has it
            term.arm()
            os.kill(os.getpid(), signal.SIGTERM)
            assert term() and term.received and seen == [signal.SIGTERM]
            os.kill(os.getpid(), signal.SIGTERM)
            assert seen == [signal.SIGTERM] * 2
        os.kill(os.getpid(), signal.SIGTERM)
        assert seen == [signal.SIGTERM] * 3
        # a handler installed before it and put back inside the block (the LED board's lights-off, closed with the
        # stream) is not brought back by the block's end: the one before both stays
        before = signal.getsignal(signal.SIGTERM)
        with SigtermEndsStream() as term:
            stale = signal.signal(signal.SIGTERM, lambda signum, frame: None)
            term.arm()
            signal.signal(signal.SIGTERM, stale)
        assert signal.getsignal(signal.SIGTERM) is before
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_an_ignored_ctrl_c_stays_ignored_for_a_background_job():
    """A script's background job (`nlips live ... &` in a non-interactive shell) starts with SIGINT ignored, so that
    Ctrl-C in that terminal stops the script, not the jobs it left running: the command keeps it so (README, live;
    such a stream is stopped with `kill PID`, which ends it with its summary)."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        assert cli._note_interrupts() is None
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)


EARLY_SIGINT = {
    # a Ctrl-C as the command's modules load: sent as the CLI's help module is looked up
    "loading": (
        "import importlib.abc, os, signal, sys\n"
        "class CtrlC(importlib.abc.MetaPathFinder):\n"
        "    def find_spec(self, name, path, target=None):\n"
        "        if name == 'nlipscalib.cli.help':\n"
        "            os.kill(os.getpid(), signal.SIGINT)\n"
        "sys.meta_path.insert(0, CtrlC())\n"
        "sys.argv = ['nlips', 'solve', '--help']\n"
        "from nlipscalib.__main__ import command\n"
        "command()\n"
    ),
    # a Ctrl-C as the command's parser is built (its arguments not read yet, its handlers not set)
    "parsing": (
        "import os, signal, sys\n"
        "sys.argv = ['nlips', 'solve', '--help']\n"
        "from nlipscalib import cli\n"
        "real = cli.build_parser\n"
        "def build():\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    return real()\n"
        "cli.build_parser = build\n"
        "from nlipscalib.__main__ import command\n"
        "command()\n"
    ),
}


@pytest.mark.parametrize("when", sorted(EARLY_SIGINT))
def test_a_ctrl_c_before_the_command_began_is_one_line_and_130(when):
    """A Ctrl-C in the first ~0.3 s of any command (~1 s under load: its modules loading, its arguments read, before
    it set its own Ctrl-C handling) printed a KeyboardInterrupt traceback of the imports, and the process ended by the
    signal (status -2). Now: one line, exit 130, as any interrupt."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    run = subprocess.run(
        [sys.executable, "-c", EARLY_SIGINT[when]], capture_output=True, text=True, cwd=root, timeout=120
    )
    assert run.stderr.splitlines() == ["nlips: interrupted before the command began; nothing was done"], run.stderr
    assert run.returncode == 130 and run.stdout == ""


STOPPED_BEFORE_THE_FIRST_WRITE = """
import importlib
import sys
import time
from pathlib import Path

from nlipscalib.cli import main

ready, target, argv = sys.argv[1], sys.argv[2], sys.argv[3:]


def working(*args, **kwargs):  # the command's work under way: its holds and probes made its folders, nothing written
    Path(ready).touch()
    time.sleep(120)


module, name = target.rsplit(".", 1)
setattr(importlib.import_module(module), name, working)
sys.exit(main(argv))
"""
"""A command whose work (``target``, a dotted name) waits, after saying so in the file ``ready``."""


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["sigterm", "ctrl-c"])
@pytest.mark.parametrize(
    "command, target",
    [
        ("calibrate-leds", "nlipscalib.solver.calibrate_leds"),
        ("experiment", "nlipscalib.experiments.framework.run_experiment"),
        ("render", "nlipscalib.sim.press.render_press"),
    ],
)
def test_a_command_stopped_before_its_first_write_leaves_no_folder_it_made(tmp_path, command, target, signum):
    """Ctrl-C or SIGTERM of a command before its first write left the output folders its holds and probes had made,
    empty (`nlips calibrate-leds REF --out new/leds.json`: new/; `nlips experiment q1 --out new`: new/q1-quick/ and
    its report/; `nlips render`, `dataset`, `train` alike), which the next run took for work begun. SIGTERM's
    handler ends the process at once, so it removes them itself (cli.folders.remove_all_left_empty)."""
    import subprocess
    import sys
    import time

    from tests.solver import synth

    new = tmp_path / "new"
    if command == "calibrate-leds":
        synth.make_press(tmp_path / "reference", "none", size=(64, 48))
        argv = [command, str(tmp_path / "reference"), "--out", str(new / "leds" / "leds.json")]
    elif command == "render":
        argv = [command, "--width", "64", "--height", "48", "--out", str(new / "twin" / "press")]
    else:
        argv = [command, "q1", "--out", str(new / "work")]
    ready = tmp_path / "working"
    script = [sys.executable, "-c", STOPPED_BEFORE_THE_FIRST_WRITE, str(ready), target, *argv, "--no-progress"]
    proc = subprocess.Popen(script, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not ready.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert ready.exists(), proc.stderr.read() if proc.poll() is not None else "not working after 60 s"
        assert new.is_dir()  # made for the work (a claim's folder, a writability probe's)
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 128 + signum, err
    assert not new.exists(), sorted(str(p.relative_to(new)) for p in new.rglob("*"))


def test_ctrl_c_as_a_claim_is_taken_leaves_no_claim_file(tmp_path, monkeypatch):
    """Ctrl-C just after a claim's file was linked, before the claim was taken (core.claims.claim), left the file:
    a claim of this live process, which a later run in the same process waited on, and another took for a killed
    run's (`nlips calibrate` and `nlips train` stopped at once left `.claim-calibration`, `.claim-m.pt~train`)."""
    from nlipscalib.core import claims

    linked = claims._create

    def create_then_interrupted(path, me):
        assert linked(path, me)
        raise KeyboardInterrupt

    monkeypatch.setattr(claims, "_create", create_then_interrupted)
    with pytest.raises(KeyboardInterrupt), claims.claim(tmp_path / "out"):
        pass
    assert list(tmp_path.iterdir()) == []
    assert claims._HELD == {}
