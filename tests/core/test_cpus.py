"""The cores and memory a process may use (its CPU affinity, else every core; MemAvailable and the cgroup's memory
limit), and the worker processes that fit them."""

import logging
import os

from nlipscalib.core import cpus
from nlipscalib.core.cpus import (
    RENDER_MEMORY,
    SOLVE_ROI_MEMORY,
    SOLVE_WHOLE_MEMORY,
    WorkerMemory,
    available_memory,
    cgroup_cpu_limit,
    cgroup_memory_room,
    solve_workers_default,
    threads_per_worker,
    usable_cores,
    worker_count,
)


def test_usable_cores_follows_the_affinity_and_falls_back_to_the_core_count(monkeypatch, tmp_path):
    monkeypatch.setattr(cpus, "PROC_CGROUP", tmp_path / "missing")  # no CPU quota, also where tests run in one
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
    no_cgroups = tmp_path / "missing"  # this machine's own cgroups (a container's limit) kept out of the test
    meminfo.write_text(
        "MemTotal:       16318480 kB\nMemFree:         1000000 kB\nMemAvailable:   12000000 kB\n", encoding="utf-8"
    )
    assert available_memory(meminfo, no_cgroups) == 12_000_000 * 1024
    meminfo.write_text(
        "MemTotal:       16318480 kB\nMemFree:         1000000 kB\n", encoding="utf-8"
    )  # a kernel before 3.14
    assert available_memory(meminfo, no_cgroups) is None
    assert available_memory(tmp_path / "missing", no_cgroups) is None  # not Linux


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
    monkeypatch.setattr(cpus, "PROC_CGROUP", tmp_path / "missing")  # also where the tests run in a container
    assert worker_count(None, 6, SOLVE, 1280, 960) == 6
    monkeypatch.setattr(cpus, "MEMINFO", _meminfo(tmp_path, available_kb=2_000_000))  # 2 GB: one 1.23 GB worker
    assert worker_count(None, 6, SOLVE, 1280, 960) == 1


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


def _meminfo(tmp_path, available_kb=12_000_000):
    meminfo = tmp_path / "meminfo"
    meminfo.write_text(f"MemTotal:       16318480 kB\nMemAvailable:   {available_kb} kB\n", encoding="utf-8")
    return meminfo


def _cgroup_files(folder, **files):
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (folder / name.replace("_", ".", 1)).write_text(text, encoding="utf-8")


def test_a_cgroup_v2_limit_below_memavailable_decides(tmp_path):
    meminfo = _meminfo(tmp_path)  # the host: 12.3 GB available
    proc_cgroup = tmp_path / "cgroup"
    proc_cgroup.write_text("0::/kubepods/pod1/box\n", encoding="utf-8")
    root = tmp_path / "sys"
    # the container: 2 GB limit, 0.5 GB used of which 0.1 GB droppable file cache
    _cgroup_files(
        root / "kubepods/pod1/box",
        memory_max=f"{2 * GB}\n",
        memory_current=f"{GB // 2}\n",
        memory_stat=f"anon 400000000\ninactive_file {GB // 10}\nactive_file 0\n",
    )
    assert available_memory(meminfo, proc_cgroup, root) == 2 * GB - (GB // 2 - GB // 10)
    # the pod above it has less room left (its other containers use memory): the least room wins
    _cgroup_files(root / "kubepods/pod1", memory_max=f"{3 * GB}\n", memory_current=f"{2 * GB}\n")
    assert available_memory(meminfo, proc_cgroup, root) == GB
    # a group over its limit has no room, never a negative count
    _cgroup_files(root / "kubepods/pod1", memory_max=f"{GB}\n", memory_current=f"{2 * GB}\n")
    assert available_memory(meminfo, proc_cgroup, root) == 0
    # the worker count follows: one worker where the container has no room
    assert worker_count(None, 8, SOLVE, 1280, 960, available=available_memory(meminfo, proc_cgroup, root)) == 1


def test_a_cgroup_v2_without_a_limit_leaves_memavailable(tmp_path):
    meminfo = _meminfo(tmp_path)
    proc_cgroup = tmp_path / "cgroup"
    proc_cgroup.write_text("0::/user.slice/session-1.scope\n", encoding="utf-8")
    root = tmp_path / "sys"
    _cgroup_files(root / "user.slice/session-1.scope", memory_max="max\n", memory_current="123456\n")
    assert available_memory(meminfo, proc_cgroup, root) == 12_000_000 * 1024
    assert cgroup_memory_room(proc_cgroup, root) is None
    # a limit far above MemAvailable does not raise it
    _cgroup_files(root / "user.slice", memory_max=f"{100 * GB}\n", memory_current="0\n")
    assert available_memory(meminfo, proc_cgroup, root) == 12_000_000 * 1024


def test_a_cgroup_v1_memory_hierarchy_is_read_and_its_huge_count_means_no_limit(tmp_path):
    meminfo = _meminfo(tmp_path)
    proc_cgroup = tmp_path / "cgroup"
    # a hybrid system (as this project's VM): v1 holds the memory controller, v2's tree has none
    proc_cgroup.write_text("4:memory:/slurm/job7\n3:cpu,cpuacct:/slurm/job7\n0::/\n", encoding="utf-8")
    root = tmp_path / "sys"
    _cgroup_files(root / "memory/slurm/job7", memory_limit_in_bytes=f"{4 * GB}\n", memory_usage_in_bytes=f"{GB}\n")
    _cgroup_files(root / "memory", memory_limit_in_bytes="9223372036854771712\n", memory_usage_in_bytes="6112911360\n")
    assert available_memory(meminfo, proc_cgroup, root) == 3 * GB
    (root / "memory/slurm/job7/memory.limit_in_bytes").write_text("9223372036854771712\n", encoding="utf-8")  # no limit
    assert available_memory(meminfo, proc_cgroup, root) == 12_000_000 * 1024
    assert cgroup_memory_room(proc_cgroup, root) is None  # not 9.2e18 bytes of room


def test_a_container_that_sees_its_group_as_the_mount_root_reads_the_root(tmp_path):
    # Docker on cgroup v1 without a cgroup namespace: /proc/self/cgroup names the host's path, the mount is the
    # container's own group
    meminfo = _meminfo(tmp_path)
    proc_cgroup = tmp_path / "cgroup"
    proc_cgroup.write_text("9:memory:/docker/0123abcd\n", encoding="utf-8")
    root = tmp_path / "sys"
    _cgroup_files(root / "memory", memory_limit_in_bytes=f"{GB}\n", memory_usage_in_bytes=f"{GB // 4}\n")
    assert available_memory(meminfo, proc_cgroup, root) == GB - GB // 4


def test_without_cgroups_or_with_unreadable_files_memavailable_alone_decides(tmp_path):
    meminfo = _meminfo(tmp_path)
    root = tmp_path / "sys"
    assert available_memory(meminfo, tmp_path / "missing", root) == 12_000_000 * 1024  # not Linux, no cgroups
    proc_cgroup = tmp_path / "cgroup"
    proc_cgroup.write_text("0::/box\n", encoding="utf-8")
    assert available_memory(meminfo, proc_cgroup, root) == 12_000_000 * 1024  # no cgroup files mounted
    _cgroup_files(root / "box", memory_max=f"{GB}\n")  # memory.current missing: not a reading
    assert available_memory(meminfo, proc_cgroup, root) == 12_000_000 * 1024
    (root / "box/memory.current").write_text("garbled\n", encoding="utf-8")
    assert available_memory(meminfo, proc_cgroup, root) == 12_000_000 * 1024
    (root / "box/memory.current").unlink()
    (root / "box/memory.current").mkdir()  # unreadable (a folder: root reads any file mode)
    assert available_memory(meminfo, proc_cgroup, root) == 12_000_000 * 1024
    (root / "box/memory.current").rmdir()
    # neither reading: unknown, the cores decide
    assert available_memory(tmp_path / "missing", tmp_path / "missing", root) is None
    # the cgroup alone (no MemAvailable line): its room is the answer
    (root / "box/memory.current").write_text(f"{GB // 2}\n", encoding="utf-8")
    assert available_memory(tmp_path / "missing", proc_cgroup, root) == GB // 2


def test_a_cgroup_v2_cpu_quota_caps_the_cores_rounded_up(monkeypatch, tmp_path):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(64)), raising=False)  # the host's 64 cores
    proc_cgroup = tmp_path / "cgroup"
    proc_cgroup.write_text("0::/kubepods/pod1/box\n", encoding="utf-8")
    root = tmp_path / "sys"
    _cgroup_files(root / "kubepods/pod1/box", cpu_max="200000 100000\n")  # docker run --cpus=2
    assert cgroup_cpu_limit(proc_cgroup, root) == 2
    assert usable_cores(proc_cgroup, root) == 2
    (root / "kubepods/pod1/box/cpu.max").write_text(
        "150000 100000\n", encoding="utf-8"
    )  # 1.5 cores' time: two threads still help
    assert usable_cores(proc_cgroup, root) == 2
    (root / "kubepods/pod1/box/cpu.max").write_text(
        "20000 100000\n", encoding="utf-8"
    )  # a fifth of a core: never below one
    assert usable_cores(proc_cgroup, root) == 1
    # the pod above it has the smaller quota: it decides
    (root / "kubepods/pod1/box/cpu.max").write_text("800000 100000\n", encoding="utf-8")
    _cgroup_files(root / "kubepods/pod1", cpu_max="300000 100000\n")
    assert usable_cores(proc_cgroup, root) == 3
    # a quota above the affinity does not raise it (taskset to 4 cores in a 16-core container)
    _cgroup_files(root / "kubepods", cpu_max="1600000 100000\n")
    (root / "kubepods/pod1/cpu.max").write_text("max 100000\n", encoding="utf-8")
    (root / "kubepods/pod1/box/cpu.max").write_text("max 100000\n", encoding="utf-8")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    assert usable_cores(proc_cgroup, root) == 4


def test_a_cgroup_v2_without_a_cpu_quota_leaves_the_affinity(monkeypatch, tmp_path):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(8)), raising=False)
    proc_cgroup = tmp_path / "cgroup"
    proc_cgroup.write_text("0::/user.slice/session-1.scope\n", encoding="utf-8")
    root = tmp_path / "sys"
    assert usable_cores(proc_cgroup, root) == 8  # no cgroup files mounted
    _cgroup_files(root / "user.slice/session-1.scope", cpu_max="max 100000\n")  # "max": no quota
    assert cgroup_cpu_limit(proc_cgroup, root) is None
    assert usable_cores(proc_cgroup, root) == 8
    _cgroup_files(root / "user.slice", cpu_max="garbled\n")  # unreadable: no reading, not a crash
    assert usable_cores(proc_cgroup, root) == 8
    assert usable_cores(tmp_path / "missing", root) == 8  # not Linux, no cgroups


def test_a_cgroup_v1_cpu_quota_is_read_from_the_cpu_hierarchy(monkeypatch, tmp_path):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(64)), raising=False)
    proc_cgroup = tmp_path / "cgroup"
    # a hybrid system (as this project's VM): v1 holds the cpu controller (with cpuacct), v2's tree has none
    proc_cgroup.write_text(
        "5:memory:/docker/0123abcd\n3:cpu,cpuacct:/docker/0123abcd\n2:cpuset:/\n0::/\n", encoding="utf-8"
    )
    root = tmp_path / "sys"
    # mounted under the hierarchy's own name (no cpu -> cpu,cpuacct link)
    _cgroup_files(root / "cpu,cpuacct/docker/0123abcd", cpu_cfs_quota_us="400000\n", cpu_cfs_period_us="100000\n")
    _cgroup_files(root / "cpu,cpuacct", cpu_cfs_quota_us="-1\n", cpu_cfs_period_us="100000\n")  # the root: none
    assert cgroup_cpu_limit(proc_cgroup, root) == 4
    assert usable_cores(proc_cgroup, root) == 4
    (root / "cpu,cpuacct/docker/0123abcd/cpu.cfs_quota_us").write_text("-1\n", encoding="utf-8")  # no quota
    assert cgroup_cpu_limit(proc_cgroup, root) is None
    assert usable_cores(proc_cgroup, root) == 64
    # Docker without a cgroup namespace: the file names the host's path, the mount ``cpu`` is the container's group
    _cgroup_files(root / "cpu", cpu_cfs_quota_us="250000\n", cpu_cfs_period_us="100000\n")
    assert usable_cores(proc_cgroup, root) == 3  # 2.5 cores rounded up
    # the memory limit is still read from its own hierarchy
    _cgroup_files(root / "memory", memory_limit_in_bytes=f"{GB}\n", memory_usage_in_bytes="0\n")
    assert cgroup_memory_room(proc_cgroup, root) == GB


def test_the_cpu_quota_lowers_the_pools_that_count_usable_cores(monkeypatch, tmp_path):
    # the solver's thread pool follows usable_cores(): a --cpus=2 container on a 64-core host runs 2 threads
    from nlipscalib.solver import threads

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(64)), raising=False)
    proc_cgroup = tmp_path / "cgroup"
    proc_cgroup.write_text("0::/box\n", encoding="utf-8")
    _cgroup_files(tmp_path / "sys/box", cpu_max="200000 100000\n")
    monkeypatch.setattr(cpus, "PROC_CGROUP", proc_cgroup)
    monkeypatch.setattr(cpus, "CGROUP_ROOT", tmp_path / "sys")
    monkeypatch.delenv("NLIPS_THREADS", raising=False)
    monkeypatch.setattr(threads, "_workers", None)
    assert threads.workers() == 2


def test_solver_workers_default_to_one_per_two_cores_and_share_the_cores_as_threads():
    # a press's solve already runs on two threads: one worker on 2 or 3 cores, two on 4, four on 8
    assert [solve_workers_default(cores) for cores in (1, 2, 3, 4, 8, 64)] == [1, 1, 1, 2, 4, 32]
    # the cores shared out among the workers, never below one thread
    assert threads_per_worker(2, cores=8) == 4  # two presses on an 8-core machine
    assert threads_per_worker(1, cores=2) == 2
    assert threads_per_worker(2, cores=2) == 1  # --workers 2 on this project's 2-core VM: one each, as before
    assert threads_per_worker(8, cores=2) == 1
