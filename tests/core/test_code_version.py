"""The code's fingerprint in the reuse key: it changes with the code that makes results, not with the rest."""

import importlib.resources
import shutil
from pathlib import Path

from nlipscalib.core import code_version
from nlipscalib.core.code_version import RESULT_CODE, code_fingerprint, python_sources, source_digest


def _tree(root: Path) -> Path:
    for name in ("__init__.py", "solver/nlips.py", "core/formats.py", "cli/solve.py", "learn/net.py"):
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(f"# {name}\n", encoding="utf-8")
    return root


def test_the_fingerprint_changes_with_the_code_that_makes_results_only(tmp_path):
    pkg = _tree(tmp_path / "pkg")
    before = source_digest(python_sources(pkg, RESULT_CODE))
    (pkg / "cli" / "solve.py").write_text(
        "# another help text\n", encoding="utf-8"
    )  # the command line only chooses settings
    (pkg / "solver" / "__pycache__").mkdir()
    (pkg / "solver" / "__pycache__" / "nlips.cpython-311.pyc").write_bytes(b"compiled")  # compiled or not: alike
    (pkg / "solver" / "notes.txt").write_text("not code", encoding="utf-8")
    assert source_digest(python_sources(pkg, RESULT_CODE)) == before
    for edit in ("solver/nlips.py", "core/formats.py", "learn/net.py"):
        (pkg / edit).write_text((pkg / edit).read_text(encoding="utf-8") + "x = 1\n", encoding="utf-8")
        after = source_digest(python_sources(pkg, RESULT_CODE))
        assert after != before, edit
        before = after
    shutil.move(pkg / "solver" / "nlips.py", pkg / "solver" / "nlips2.py")  # a renamed module: other code
    assert source_digest(python_sources(pkg, RESULT_CODE)) != before


def test_the_fingerprint_is_the_installed_packages_computed_once():
    installed = importlib.resources.files("nlipscalib")
    names = [name for name, _ in python_sources()]
    assert (
        "solver/nlips.py" in names
        and "core/code_version.py" in names
        and names == sorted(names, key=lambda n: n.split("/"))
    )
    assert code_fingerprint() == source_digest(python_sources(installed, RESULT_CODE))
    assert len(code_fingerprint()) == 32 and code_version._fingerprint.cache_info().currsize == 1


def test_the_disk_cache_salt_hashes_the_whole_package(monkeypatch):
    """The disk cache's keys change with any source file (a formula anywhere), not only the result code's."""
    from nlipscalib.core import diskcache

    every = [name for name, _ in python_sources()]
    assert "cli/solve.py" in every and "__init__.py" in every and "solver/nlips.py" in every
    monkeypatch.setattr(diskcache, "_salt", None)
    salt = diskcache._source_salt()
    monkeypatch.setattr(diskcache, "_salt", None)
    monkeypatch.setattr(code_version, "python_sources", lambda: python_sources(subpackages=RESULT_CODE))
    assert diskcache._source_salt() != salt


def test_the_disk_cache_salt_holds_every_library_that_shapes_a_solve(monkeypatch):
    """It held NumPy's and SciPy's versions only: an upgraded OpenCV (the smoothed undeformed shading kept on disk is
    its blur) or pyamg was served entries made by the old one."""
    from nlipscalib.core import diskcache, libraries

    monkeypatch.setattr(diskcache, "_salt", None)
    salt = diskcache._source_salt()
    installed = libraries.installed_version
    for name in ("opencv", "pyamg", "numpy"):
        with monkeypatch.context() as patch:
            patch.setattr(diskcache, "_salt", None)
            patch.setattr(libraries, "installed_version", lambda n, name=name: "0.1" if n == name else installed(n))
            assert diskcache._source_salt() != salt, name
