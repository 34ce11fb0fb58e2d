"""What the watched-folder tests of `nlips infer --watch` and `nlips live --watch` share: a writer that drops frames
the way camera programs write them, started once the command says it is watching, and the command bounded by a
limit (:data:`GIVE_UP_S`) that turns a wait that never ends into a failure. No timing asserts and no sleeps but the
polling of :func:`wait_for`."""

import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from nlipscalib.cli import main
from nlipscalib.core.imageio import write_png16

from ..processes import as_from_a_terminal

GIVE_UP_S = 600.0
"""A watch still waiting then has missed a file: the test ends it (Ctrl-C) and fails on what it counts. Generous: the
limit counts the command's start too (importing torch and loading the model took over 120 s on the 2-core VM at load
29, s38)."""
REPO = Path(__file__).resolve().parents[2]


def tiny_model_frames(tmp_path_factory, name: str) -> tuple[Path, list[Path]]:
    """A tiny model of the exact-data sensor (64x48, no rendering; tests/learn/test_infer's) and its presses'
    tri-colour frames."""
    from tests.learn.test_infer import tiny_model_and_presses
    from tests.learn.test_resume import NAMES

    out, root = tiny_model_and_presses(tmp_path_factory.mktemp(name))
    return out, [root / n / "tricolor.png" for n in NAMES]


def drop(folder: Path, name: str, frame: Path | np.ndarray) -> None:
    """A frame renamed into place, as camera programs write them (a hidden temporary first)."""
    tmp = folder / f".{name}.part"
    if isinstance(frame, np.ndarray):
        write_png16(tmp, frame)
    else:
        shutil.copyfile(frame, tmp)
    os.replace(tmp, folder / name)


def writer_once_watching(monkeypatch, write: Callable[[], None]) -> threading.Thread:
    """``write()`` on a thread of its own once the command says it is watching (``cli._watch.say_watching``)."""
    from nlipscalib.cli import _watch

    started = threading.Event()
    say_watching = _watch.say_watching

    def said(*args):
        say_watching(*args)
        started.set()

    monkeypatch.setattr(_watch, "say_watching", said)

    def run() -> None:
        assert started.wait(GIVE_UP_S)
        write()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def main_bounded(argv: list[str], thread: threading.Thread) -> int:
    """``nlips ARGV``, ended by Ctrl-C after :data:`GIVE_UP_S` (a failure, not a hang), then the writer joined."""
    timer = threading.Timer(GIVE_UP_S, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        return main(argv)
    finally:
        timer.cancel()
        thread.join(GIVE_UP_S)


def wait_for(what: Callable[[], bool], seconds: float = GIVE_UP_S) -> None:
    deadline = time.monotonic() + seconds
    while not what():
        assert time.monotonic() < deadline, "waited past the test's limit"
        time.sleep(0.05)


def watch_until_signalled(argv: list[str], watched: Path, out: Path, frames: list, sig: int) -> tuple[int, str]:
    """``nlips ARGV`` (a watch with ``--out OUT``) in a process of its own as from a terminal: once it says it is
    watching, ``frames`` are dropped into ``watched`` as f0.png, f1.png, ...; once OUT/frames.tsv names them all,
    ``sig`` is sent. Returns its exit status and its stderr."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])))
    code = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
    proc = as_from_a_terminal([sys.executable, "-c", code, *argv], env=env)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True)
    reader.start()
    try:
        wait_for(lambda: any(line.startswith("watching ") for line in lines) or proc.poll() is not None)
        assert proc.poll() is None, "".join(lines)
        for i, frame in enumerate(frames):
            drop(watched, f"f{i}.png", frame)
        tsv = out / "frames.tsv"
        wait_for(lambda: tsv.is_file() and len(tsv.read_text(encoding="utf-8").splitlines()) == len(frames) + 1)
        proc.send_signal(sig)
        proc.wait(GIVE_UP_S)
    finally:
        proc.kill()
        proc.wait()
        reader.join(10)
    return proc.returncode, "".join(lines)
