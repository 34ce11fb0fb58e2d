"""Several `nlips dataset` processes on one folder (one of them killed): every press rendered once, all whole."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest

from nlipscalib.core.capture import load_press
from tests.processes import until_each_waits_or_exits
from tests.specs import TINY_SPEC as SPEC

pytest.importorskip("mitsuba")

ROOT = Path(__file__).resolve().parents[2]
NAMES = ["reference", "press_0001", "press_0002", "press_0003", "press_0004"]


def _start(spec: Path, out: Path, log: Path) -> subprocess.Popen:
    code = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
    args = ["-v", "--log-file", str(log), "dataset", str(spec), "--out", str(out), "--workers", "1"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen([sys.executable, "-c", code, *args], env=env, stderr=subprocess.PIPE, text=True)


def _rendered(logs: list[Path]) -> Counter:
    text = "".join(p.read_text(encoding="utf-8") for p in logs if p.exists())
    return Counter(re.findall(r"press (\w+): rendered", text))


def _check_folder(out: Path) -> None:
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == sorted([*NAMES, "dataset.json"])
    for name in NAMES:
        press = load_press(out / name)  # complete and loadable
        assert press.led_images.shape[0] == 12
    assert not list(out.glob(".tmp-*"))


@pytest.mark.parametrize("n", [2, 3])
def test_concurrent_runs_render_each_press_once(tmp_path, n):
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC, encoding="utf-8")
    out, logs = tmp_path / "out", [tmp_path / f"log{i}.txt" for i in range(n)]
    procs = [_start(spec, out, log) for log in logs]
    errs = [p.communicate(timeout=600)[1] for p in procs]
    assert [p.returncode for p in procs] == [0] * n, errs
    assert not any("Traceback" in e for e in errs), errs
    assert _rendered(logs) == Counter(NAMES)  # every press exactly once, across all processes
    _check_folder(out)


def test_killed_run_is_taken_over(tmp_path):
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC, encoding="utf-8")
    out, logs = tmp_path / "out", [tmp_path / f"log{i}.txt" for i in range(3)]
    victim = _start(spec, out, logs[0])
    deadline = time.time() + 300
    while not any(_owned_by(c, victim.pid) for c in out.glob(".claim-*")):  # kill it mid-render
        assert time.time() < deadline and victim.poll() is None, "the victim never claimed a press"
        time.sleep(0.05)
    survivors = [_start(spec, out, log) for log in logs[1:]]
    time.sleep(0.5)
    victim.send_signal(signal.SIGKILL)
    victim.wait()
    errs = [p.communicate(timeout=600)[1] for p in survivors]
    assert [p.returncode for p in survivors] == [0, 0], errs
    assert not any("Traceback" in e for e in errs), errs
    counts = _rendered(logs)
    assert max(counts.values()) == 1  # nothing rendered twice
    _check_folder(out)  # the victim's press was taken over and finished
    assert not list(out.glob(".claim-*"))


def _owned_by(claim: Path, pid: int) -> bool:
    try:
        return json.loads(claim.read_text(encoding="utf-8"))["pid"] == pid
    except (OSError, ValueError, KeyError):
        return False


def test_terminated_run_releases_its_claims(tmp_path):
    """SIGTERM (a scheduler's time limit) unwinds: exit 143, its claim and half-written folder gone."""
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC, encoding="utf-8")
    out = tmp_path / "out"
    proc = _start(spec, out, tmp_path / "log.txt")
    deadline = time.time() + 300
    while not any(_owned_by(c, proc.pid) for c in out.glob(".claim-*")):
        assert time.time() < deadline and proc.poll() is None, "it never claimed a press"
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 143 and "terminated" in err and "Traceback" not in err, err
    assert not list(out.glob(".claim-*")) and not list(out.glob(".tmp-*"))


def test_concurrent_runs_of_different_specs_leave_one_spec(tmp_path):
    """Two runs of specs differing in their seed, into one folder at once, both exited 2 ("rendered from a
    different scene or spec") and left the presses each had published: a dataset of two specs. Now the first
    claims the folder for its spec and finishes; the second is refused before it writes anything. To make both
    start before either publishes, this process holds every press's claim until each run waits or has exited."""
    import contextlib

    from nlipscalib.core.claims import claim
    from nlipscalib.sim.dataset import expand_jobs, load_dataset_spec
    from nlipscalib.sim.press import recorded_spec_hash, render_spec_hash

    out, specs, logs = tmp_path / "out", [tmp_path / "a.toml", tmp_path / "b.toml"], []
    for path, seed in zip(specs, ("1", "2")):
        path.write_text(SPEC.replace("seed = 1", f"seed = {seed}").replace("[0.0, 15.0]", "[0.0]"), encoding="utf-8")
    with contextlib.ExitStack() as held:
        for name in ("reference", "press_0001", "press_0002"):
            assert held.enter_context(claim(out / name))
        procs = []
        for i, path in enumerate(specs):
            logs.append(tmp_path / f"log{i}.txt")
            procs.append(_start(path, out, logs[-1]))
        until_each_waits_or_exits(procs, logs, "waiting for", timeout=300)
    errs = [p.communicate(timeout=600)[1] for p in procs]
    assert sorted(p.returncode for p in procs) == [0, 2], errs
    winner, loser = (0, 1) if procs[0].returncode == 0 else (1, 0)
    lines = [line for line in errs[loser].splitlines() if not line.startswith(("DEBUG ", "INFO "))]  # -v logs
    assert len(lines) == 1 and "a run of a different spec is rendering into it" in lines[0], errs[loser]
    assert "rendered" not in _text(logs[loser])  # refused before it published anything
    spec, scene = load_dataset_spec(specs[winner])
    expected = {j.name: render_spec_hash(scene, j.press, j.seed) for j in expand_jobs(spec)}
    found = {
        p.name: recorded_spec_hash(json.loads((p / "meta.json").read_text(encoding="utf-8"))["provenance"])
        for p in out.iterdir()
        if p.is_dir() and not p.name.startswith(".")
    }
    assert found == expected  # every press of the winner's spec, none of the other's
    assert json.loads((out / "dataset.json").read_text(encoding="utf-8"))["spec"]["seed"] == spec.seed
    assert not list(out.glob(".claim-*")) and not list(out.glob(".tmp-*"))


def _text(path: Path) -> str:
    return path.read_text(encoding="utf-8") if path.exists() else ""
