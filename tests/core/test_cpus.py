"""The cores and memory a process may use (its CPU affinity, else every core; MemAvailable), and the worker
processes that fit them."""

import logging
import os

from nlipscalib.core import cpus
from nlipscalib.core.cpus import (
    RENDER_MEMORY,
    SOLVE_ROI_MEMORY,
    SOLVE_WHOLE_MEMORY,
    WorkerMemory,
    available_memory,
    usable_cores,
    worker_count,
)


def test_usable_cores_follows_the_affinity_and_falls_back_to_the_core_count(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3}, raising=False)
    assert usable_cores() == 1  # a process pinned to one core (taskset, a container's cpuset)
    monkeypatch.delattr(os, "sched_getaffinity", raising=False)  # no affinity (macOS, Windows)
    monkeypatch.setattr(os, "cpu_count", lambda: 6)
    assert usable_cores() == 6
    monkeypatch.setattr(os, "cpu_count", lambda: None)
    assert usable_cores() == 1


GB = 10**9
SOLVE = WorkerMemory("solve", base_bytes=0, per_pixel_bytes=1000)  # 1.2288 GB a worker at 1280x960


def test_available_memory_reads_memavailable_in_bytes(tmp_path):
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:       16318480 kB\nMemFree:         1000000 kB\nMemAvailable:   12000000 kB\n")
    assert available_memory(meminfo) == 12_000_000 * 1024
    meminfo.write_text("MemTotal:       16318480 kB\nMemFree:         1000000 kB\n")  # a kernel before 3.14
    assert available_memory(meminfo) is None
    assert available_memory(tmp_path / "missing") is None  # not Linux


def test_the_default_count_is_lowered_to_what_memory_holds_and_said_once(caplog):
    caplog.set_level(logging.INFO, logger="nlipscalib.core.cpus")
    # an 8-core PC with 10 GB available, 1.23 GB a worker: 7 fit in 90 % of it
    assert worker_count(None, 8, SOLVE, 1280, 960, available=10 * GB) == 7
    lines = [r for r in caplog.records if r.levelno == logging.INFO]
    assert len(lines) == 1
    assert "7 workers instead of 8" in lines[0].message and "1280x960" in lines[0].message
    assert "--workers N overrides" in lines[0].message
    caplog.clear()
    assert worker_count(0, 8, SOLVE, 640, 480, available=10 * GB) == 8  # 0.3 GB each: the cores decide, no line
    assert caplog.records == []
    assert worker_count(None, 8, SOLVE, 1280, 960, available=GB // 2) == 1  # never below one
    assert "1 worker instead of 8" in caplog.text


def test_an_explicit_count_is_kept_with_a_warning_when_it_likely_exceeds_memory(caplog):
    caplog.set_level(logging.INFO, logger="nlipscalib.core.cpus")
    assert worker_count(8, 2, SOLVE, 1280, 960, available=4 * GB) == 8
    assert [r.levelno for r in caplog.records] == [logging.WARNING]
    assert "--workers 8" in caplog.text and "4.0 GB is available" in caplog.text
    caplog.clear()
    assert worker_count(3, 2, SOLVE, 1280, 960, available=4 * GB) == 3  # 3.7 GB: fits, nothing said
    assert worker_count(1, 2, SOLVE, 1280, 960, available=GB // 2) == 1  # one worker is the least there is
    assert caplog.records == []


def test_without_a_memory_reading_the_cores_decide(monkeypatch, tmp_path):
    monkeypatch.setattr(cpus, "MEMINFO", tmp_path / "missing")
    assert worker_count(None, 6, SOLVE, 1280, 960) == 6


def test_the_worker_models_grow_with_the_pixels_as_measured():
    # the measured peaks the models were fitted to (core.cpus docstrings): within 30 % at 160x120 (the libraries'
    # floor), 10 % above
    measured = {
        SOLVE_ROI_MEMORY: {(160, 120): 0.155e9, (640, 480): 0.602e9, (1280, 960): 1.85e9},
        SOLVE_WHOLE_MEMORY: {(160, 120): 0.203e9, (640, 480): 1.721e9, (1280, 960): 6.62e9},
        RENDER_MEMORY: {(160, 120): 0.398e9, (640, 480): 1.081e9, (1280, 960): 2.74e9},
    }
    for model, peaks in measured.items():
        for (w, h), peak in peaks.items():
            share = 0.3 if w * h < 100_000 else 0.1
            assert abs(model.estimate(w, h) - peak) <= share * peak, (model.job, w, h)
