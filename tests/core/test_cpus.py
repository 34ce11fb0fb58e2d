"""The cores a process may use: its CPU affinity, else every core."""

import os

from nlipscalib.core.cpus import usable_cores


def test_usable_cores_follows_the_affinity_and_falls_back_to_the_core_count(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3}, raising=False)
    assert usable_cores() == 1  # a process pinned to one core (taskset, a container's cpuset)
    monkeypatch.delattr(os, "sched_getaffinity", raising=False)  # no affinity (macOS, Windows)
    monkeypatch.setattr(os, "cpu_count", lambda: 6)
    assert usable_cores() == 6
    monkeypatch.setattr(os, "cpu_count", lambda: None)
    assert usable_cores() == 1
