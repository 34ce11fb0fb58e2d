"""The benchmark scripts still start: each one's ``--help``, every package name it imports, two tiny runs.

Why: the suite never ran benchmarks/, and the code under them moved (s22-bench found ``bench_gpu_infer.py
stream`` importing ``MismatchWatch`` from a module it had left). Nothing here times anything (speed lives in
benchmarks/RESULTS.md), and no run here writes RESULTS.md.
"""

from __future__ import annotations

import ast
import importlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "benchmarks").glob("bench_*.py"))
OURS = ("nlipscalib", "tests", "common", "bench_command", "bench_render")
"""Top-level modules of this checkout; any other missing module is an optional dependency not installed here."""
GPU_STEPS = ("pack", "run", "stream", "boxes", "moving", "parity")


def _script(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """``python benchmarks/...`` as a lab runs it, with this checkout's package."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env, cwd=ROOT, timeout=timeout)


def _skip_if_optional_missing(done: subprocess.CompletedProcess) -> None:
    """Skip when the script stopped on a third-party module missing here (torch, mitsuba, cv2 extras)."""
    marker = "ModuleNotFoundError: No module named '"
    if marker in done.stderr:
        name = done.stderr.split(marker, 1)[1].split("'", 1)[0]
        if name.split(".")[0] not in OURS:
            pytest.skip(f"optional dependency {name} not installed")


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.stem)
def test_each_script_answers_help(script):
    done = _script(str(script.relative_to(ROOT)), "--help")
    _skip_if_optional_missing(done)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith("usage:")


def test_each_gpu_step_answers_help():
    for step in GPU_STEPS:
        done = _script("benchmarks/bench_gpu_infer.py", step, "--help")
        assert done.returncode == 0, f"{step}: {done.stderr[-2000:]}"
        assert "--model" in done.stdout or step == "pack"


def _package_imports(script: Path) -> list[tuple[str, str | None, int]]:
    """(module, imported name or None, line) of every import of this checkout's modules in ``script``, those
    inside functions included (most scripts import there, where ``--help`` never reaches)."""
    found = []
    for node in ast.walk(ast.parse(script.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module.split(".")[0] in OURS[:2]:
            found += [(node.module, alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.Import):
            found += [(a.name, None, node.lineno) for a in node.names if a.name.split(".")[0] in OURS[:2]]
    return found


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.stem)
def test_every_package_name_a_script_imports_exists(script):
    imports = _package_imports(script)
    assert imports, f"{script.name}: no import of nlipscalib found (the parse is wrong)"
    missing = []
    for module, name, line in imports:
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if (exc.name or "").split(".")[0] in OURS:
                missing.append(f"{script.name}:{line}: no module {exc.name}")
            continue  # an optional dependency not installed here
        if name is not None and not hasattr(mod, name):
            try:
                importlib.import_module(f"{module}.{name}")
            except ModuleNotFoundError:
                missing.append(f"{script.name}:{line}: {module} has no {name}")
    assert not missing, "\n".join(missing)


def test_train_step_tiny_run():
    pytest.importorskip("torch")
    done = _script("benchmarks/bench_train_step.py", "--batch", "32", "--rounds", "1", "--steps", "2", "--threads", "1")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "| torch.nn.Dropout |" in done.stdout
    assert "| byte-mask dropout (the net's) |" in done.stdout
    assert "Step time ratio byte-mask / torch.nn.Dropout:" in done.stdout


def test_gpu_step_without_a_gpu_says_so_in_one_line(tmp_path):
    torch = pytest.importorskip("torch")
    if torch.cuda.is_available():
        pytest.skip("a CUDA device is here")
    done = _script("benchmarks/bench_gpu_infer.py", "boxes", "--model", "absent.pt", "--out", str(tmp_path))
    assert done.returncode == 1
    assert "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines() == [done.stderr.strip()]
    assert done.stderr.startswith("bench_gpu_infer.py boxes: --device cuda")


@pytest.mark.parametrize("mode", [("--device", "cuda"), ("--dataset", "absent", "--devices", "cpu,cuda")])
def test_train_timing_on_an_absent_gpu_says_so_in_one_line(mode):
    torch = pytest.importorskip("torch")
    if torch.cuda.is_available():
        pytest.skip("a CUDA device is here")
    done = _script("benchmarks/bench_train_step.py", *mode)
    assert done.returncode == 1
    assert "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines() == [done.stderr.strip()]
    assert done.stderr.startswith("bench_train_step.py: --device cuda")


def test_gpu_render_steps_answer_help_and_a_missing_gel_in_one_line(tmp_path):
    for step in ("pack", "run"):
        done = _script("benchmarks/bench_gpu_render.py", step, "--help")
        assert done.returncode == 0, f"{step}: {done.stderr[-2000:]}"
        assert "--out" in done.stdout
    done = _script(
        "benchmarks/bench_gpu_render.py", "run", "--gel", str(tmp_path / "absent.npz"), "--out", str(tmp_path)
    )
    assert done.returncode == 1
    assert (
        done.stderr.strip()
        == f"bench_gpu_render.py run: {tmp_path / 'absent.npz'}: no such file (make it with the pack step)"
    )
