"""What a lab gets from a wheel or an sdist, not a checkout: every file the code reads, and commands that find them.

The wheel and the sdist are built from a copy of the checkout (an in-tree build leaves build/, whose stale
files would go into every later wheel) with the setuptools of this environment (no build isolation, so
nothing is downloaded). The installed copy runs from a folder outside any checkout, inside a git repository of
its own, as a lab's project with its .venv holds it.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import tarfile
import textwrap
import zipfile
from pathlib import Path

import pytest

from nlipscalib.core.errors import ConfigError
from nlipscalib.sim.scene import DATASETS_DIR, dataset_spec_path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "nlipscalib"
NOT_SOURCE = ("__pycache__", ".pytest_cache", ".ruff_cache", "*.egg-info", "*.py[cod]")
"""What the package folder may hold that is not part of it (caches, build metadata)."""
PROJECT = ("README.md", "LICENSE", "pyproject.toml", "setup.sh", "scenes", "docs", "firmware", "tests", "benchmarks")
"""What an sdist carries besides the package: the firmware to flash, the docs the commands name, the tests."""


def package_files() -> set[str]:
    """Every file of the package as its path in a wheel (``nlipscalib/...``), the data it reads at run time
    (scenes, dataset specs, indenter meshes, baselines) included: the scenes link is followed, as a build does."""
    files = set()
    for folder, dirs, names in os.walk(PACKAGE, followlinks=True):
        dirs[:] = [d for d in dirs if not any(Path(d).match(p) for p in NOT_SOURCE)]
        files |= {
            (Path(folder) / n).relative_to(PACKAGE.parent).as_posix()
            for n in names
            if not any(Path(n).match(p) for p in NOT_SOURCE)
        }
    return files


def _copy_checkout(dest: Path) -> Path:
    """The checkout's project files in ``dest`` (its nlipscalib/scenes link kept a link, as git has it)."""
    dest.mkdir(parents=True)
    ignore = shutil.ignore_patterns(*NOT_SOURCE, "build", "dist")
    for name in (*PROJECT, "nlipscalib", "MANIFEST.in"):
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, dest / name, symlinks=True, ignore=ignore)
        elif src.is_file():
            shutil.copy2(src, dest / name)
    return dest


def _run(args: list[str], cwd: Path, **env: str) -> subprocess.CompletedProcess:
    environ = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | env
    return subprocess.run(args, cwd=cwd, env=environ, capture_output=True, text=True, timeout=300)


def _can_build() -> None:
    """Skip where this environment cannot build without downloading (no pip or no setuptools to build with)."""
    for module in ("pip", "setuptools"):
        if importlib.util.find_spec(module) is None:
            pytest.skip(f"{module} is not installed: the wheel cannot be built offline here")


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """(wheel, sdist) built from a copy of the checkout."""
    _can_build()
    tmp = tmp_path_factory.mktemp("packaging")
    src = _copy_checkout(tmp / "src")
    dist = tmp / "dist"
    res = _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", str(dist), "."], src)
    assert res.returncode == 0, res.stdout + res.stderr
    code = f"from setuptools import build_meta; print(build_meta.build_sdist({str(dist)!r}))"
    res = _run([sys.executable, "-c", code], src)
    assert res.returncode == 0, res.stdout + res.stderr
    (tmp / "sdist.log").write_text(res.stdout + res.stderr, encoding="utf-8")  # setuptools' warnings on pyproject.toml
    (wheel,) = dist.glob("*.whl")
    return wheel, dist / res.stdout.strip().splitlines()[-1]


def test_pyproject_uses_no_setuptools_feature_with_an_end_date(built):
    """setuptools 84 warned that `license = { text = "MIT" }` is deprecated and that builds stop working after
    2027-02-18; its SPDX string (`license = "MIT"`, setuptools >= 77) is what it asks for."""
    wheel, _ = built
    log = (wheel.parent.parent / "sdist.log").read_text(encoding="utf-8")
    assert "deprecated" not in log.lower(), log
    info = "-".join(wheel.name.split("-")[:2]) + ".dist-info"  # nlipscalib-0.1.0.dist-info
    metadata = zipfile.ZipFile(wheel).read(f"{info}/METADATA").decode()
    assert "License-Expression: MIT" in metadata.splitlines()
    assert f"{info}/licenses/LICENSE" in zipfile.ZipFile(wheel).namelist()


def test_the_wheel_holds_every_file_of_the_package_and_the_data_it_reads(built):
    wheel, _ = built
    names = set(zipfile.ZipFile(wheel).namelist())
    assert "nlipscalib/scenes/datasets/train50.toml" in package_files()  # the link was followed
    missing = package_files() - names
    assert not missing, f"not in the wheel (add them to [tool.setuptools.package-data]): {sorted(missing)}"


def test_the_sdist_is_the_whole_project_and_builds_the_same_wheel(built, tmp_path):
    wheel, sdist = built
    with tarfile.open(sdist) as tar:
        top = tar.getnames()[0].split("/")[0]
        names = {n.removeprefix(f"{top}/") for n in tar.getnames()}
        tar.extractall(tmp_path, **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))  # 3.11.4+
    src = _copy_checkout(tmp_path / "checkout")
    expected = {p.relative_to(src).as_posix() for p in src.rglob("*") if p.is_file() and "nlipscalib" not in p.parts}
    assert {"setup.sh", "firmware/Makefile", "firmware/simavr/harness.c", "docs/formats.md"} <= expected
    missing = expected - names
    assert not missing, f"not in the sdist (MANIFEST.in): {sorted(missing)}"
    res = _run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", str(tmp_path / "w"), "."],
        tmp_path / top,
    )
    assert res.returncode == 0, res.stdout + res.stderr
    (again,) = (tmp_path / "w").glob("*.whl")
    assert set(zipfile.ZipFile(again).namelist()) == set(zipfile.ZipFile(wheel).namelist())


INSTALLED_CHECK = textwrap.dedent(
    """
    import sys
    from pathlib import Path

    import nlipscalib
    from nlipscalib.experiments.provenance import software
    from nlipscalib.sim.dataset import load_dataset_spec
    from nlipscalib.sim.scene import DEFAULT_SCENE, SCENES_DIR, dataset_spec_path, load_scene

    site = Path(sys.argv[1]).resolve()
    assert Path(nlipscalib.__file__).resolve().is_relative_to(site), nlipscalib.__file__
    assert DEFAULT_SCENE.is_file() and load_scene("fingertip").name == "fingertip"
    for name in ("demo", "train50"):
        assert dataset_spec_path(name).resolve().is_relative_to(site), dataset_spec_path(name)
        load_dataset_spec(dataset_spec_path(name))
    assert (SCENES_DIR / "indenters" / "pyramid.stl").is_file()
    assert software()["git_commit"] is None, software()["git_commit"]  # not the commit of the lab's repository
    print("installed copy ok")
    """
)


def test_an_installed_wheel_finds_its_data_outside_any_checkout(built, tmp_path):
    """From a lab's own git repository holding the install: scenes, dataset specs by name, the indenter mesh,
    and no git commit of that repository reported as nlipscalib's."""
    wheel, _ = built
    lab = tmp_path / "lab"
    lab.mkdir()
    if shutil.which("git"):  # the lab's project is a git repository with one commit
        for args in (
            ["init", "-q"],
            ["-c", "user.name=x", "-c", "user.email=x@x", "commit", "-q", "--allow-empty", "-m", "x"],
        ):
            assert _run(["git", *args], lab).returncode == 0
    site = lab / ".venv-site"
    res = _run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index", "--target", str(site), str(wheel)],
        lab,
    )
    assert res.returncode == 0, res.stdout + res.stderr
    res = _run([sys.executable, "-c", INSTALLED_CHECK, str(site)], lab, PYTHONPATH=str(site))
    assert res.returncode == 0, res.stdout + res.stderr
    assert "installed copy ok" in res.stdout
    res = _run([sys.executable, "-m", "nlipscalib", "dataset", "train5O", "--out", "x"], lab, PYTHONPATH=str(site))
    assert res.returncode != 0 and "nor a shipped dataset spec (demo, train50)" in res.stderr, res.stderr


def test_a_bare_name_is_a_shipped_dataset_spec_even_beside_a_folder_of_that_name(tmp_path, monkeypatch):
    """`nlips dataset train50 --out train50` resumes: the output folder it made is not taken for the spec."""
    monkeypatch.chdir(tmp_path)
    assert dataset_spec_path("train50") == DATASETS_DIR / "train50.toml"
    (tmp_path / "train50").mkdir()
    assert dataset_spec_path("train50") == DATASETS_DIR / "train50.toml"
    (tmp_path / "mine").write_text("", encoding="utf-8")
    assert dataset_spec_path("mine") == Path("mine")  # a file of the user's, without a suffix
    assert dataset_spec_path("specs/x.toml") == Path("specs/x.toml")  # load_dataset_spec says it is missing
    with pytest.raises(ConfigError, match=r"^dataset spec 'train5O': no such file, nor a shipped dataset spec"):
        dataset_spec_path("train5O")


def test_messages_naming_checkout_files_say_where_they_are():
    """An error line "Is the nlips LED firmware flashed (firmware/README.md)?" sent a wheel's user to a file it
    lacks. Every string the code shows (not a docstring) that names docs/, firmware/, scenes/ or the README says
    where it is, or is help text of a command's ``register`` (whose help then carries ``cli.SOURCE_NOTE``,
    tests/cli/test_help.py)."""
    import ast
    import re

    names = re.compile(r"\b(docs|firmware|scenes|benchmarks)/|README")
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        skip = set()  # docstrings, and the strings of the commands' register functions
        for node in ast.walk(tree):
            body = getattr(node, "body", None)
            for st in body if isinstance(body, list) else []:
                if isinstance(st, ast.Expr) and isinstance(st.value, ast.Constant):
                    skip.add(id(st.value))
            if isinstance(node, ast.FunctionDef) and node.name == "register" and path.parent.name == "cli":
                skip |= {id(n) for n in ast.walk(node)}
        for node in ast.walk(tree):
            text = node.value if isinstance(node, ast.Constant) else None
            if isinstance(text, str) and id(node) not in skip and names.search(text):
                if "source distribution" not in text:
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {text!r}")
    assert not found, "\n".join(found)
