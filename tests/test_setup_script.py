"""setup.sh: a second run on an installed checkout only checks; a changed pyproject.toml installs again.

The checkout is a temporary copy (setup.sh, pyproject.toml, the package as a link) whose ``.venv/bin/python``
is a wrapper around the interpreter running the tests: it logs ``-m pip`` calls instead of running them (no
network, nothing installed anywhere), answers setup.sh's torch probe and runs everything else for real, so the
up-to-date check reads the metadata of the environment the tests run in. apt-get and sudo are stubs that log too.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")


def _exe(path: Path, text: str) -> None:
    path.write_text(text, encoding="utf-8")
    path.chmod(0o755)


@pytest.fixture
def checkout(tmp_path):
    try:
        from importlib.metadata import distribution

        distribution("nlipscalib")
    except Exception:
        pytest.skip("nlipscalib is not installed in this environment (no metadata to check against)")
    repo = tmp_path / "repo"
    repo.mkdir()
    shutil.copy(ROOT / "setup.sh", repo)
    shutil.copy(ROOT / "pyproject.toml", repo)
    (repo / "nlipscalib").symlink_to(ROOT / "nlipscalib", target_is_directory=True)
    bin_dir = repo / ".venv" / "bin"
    bin_dir.mkdir(parents=True)
    log = tmp_path / "calls.log"
    _exe(
        bin_dir / "python",
        f"""#!/usr/bin/env bash
if [ "$1" = "-m" ] && [ "$2" = "pip" ]; then
  echo "pip $*" >>"{log}"
  case "$*" in *--index-url*) [ -e "{tmp_path}/cpu-index-down" ] && exit 1;; esac
  exit 0
fi
if [ "$1" = "-c" ] && [ "$2" = "import torch" ]; then [ -e "{tmp_path}/no-torch" ] && exit 1; exit 0; fi
PYTHONPATH="{repo}" exec "{sys.executable}" "$@"
""",
    )
    _exe(bin_dir / "nlips", "#!/bin/sh\n")
    stubs = tmp_path / "stubs"
    stubs.mkdir()
    _exe(stubs / "apt-get", f'#!/bin/sh\necho "apt-get $*" >>"{log}"\n')
    _exe(stubs / "sudo", '#!/bin/sh\nexec "$@"\n')
    return repo, log, stubs


def _setup(repo: Path, stubs: Path, *args: str, path: str | None = None, **env: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PATH=f"{stubs}{os.pathsep}{path or os.environ['PATH']}", **env)
    env.pop("PYTHONPATH", None)
    return subprocess.run(["bash", str(repo / "setup.sh"), *args], env=env, capture_output=True, text=True, timeout=300)


def _installs(log: Path) -> int:
    """How many times setup.sh ran ``pip install -e .[all]``."""
    return log.read_text(encoding="utf-8").count("-e .[all]") if log.exists() else 0


def test_second_run_only_checks_and_a_changed_pyproject_installs_again(checkout):
    repo, log, stubs = checkout
    first = _setup(repo, stubs)
    assert first.returncode == 0, first.stderr
    assert _installs(log) == 1  # a fresh checkout installs, as before
    stamp = repo / ".venv" / ".nlipscalib-pyproject.sha256"
    assert stamp.is_file()

    second = _setup(repo, stubs)
    assert second.returncode == 0, second.stderr
    assert _installs(log) == 1, "the second run installed again"
    assert "nothing to install" in second.stdout

    (repo / "pyproject.toml").write_text(
        (repo / "pyproject.toml").read_text(encoding="utf-8") + "\n# changed\n", encoding="utf-8"
    )
    assert _setup(repo, stubs).returncode == 0
    assert _installs(log) == 2  # pyproject.toml changed since the last install
    assert _setup(repo, stubs).returncode == 0
    assert _installs(log) == 2  # ... and recorded again

    assert _setup(repo, stubs, "--force").returncode == 0
    assert _installs(log) == 3


def test_an_environment_that_no_longer_matches_installs(checkout):
    repo, log, stubs = checkout
    assert _setup(repo, stubs).returncode == 0 and _installs(log) == 1
    # a requirement the installed metadata does not have (pip install was never run with it)
    text = (
        (repo / "pyproject.toml")
        .read_text(encoding="utf-8")
        .replace('"numpy>=1.26",', '"numpy>=1.26",\n  "not-a-real-package>=1",')
    )
    (repo / "pyproject.toml").write_text(text, encoding="utf-8")
    stamp = repo / ".venv" / ".nlipscalib-pyproject.sha256"
    stamp.write_text(hashlib.sha256(text.encode()).hexdigest(), encoding="utf-8")  # even with a matching stamp
    assert _setup(repo, stubs).returncode == 0
    assert _installs(log) == 2
    # another checkout is what the venv imports (the package's own install, not this copy)
    (repo / "pyproject.toml").write_text((ROOT / "pyproject.toml").read_text(encoding="utf-8"), encoding="utf-8")
    assert _setup(repo, stubs).returncode == 0 and _installs(log) == 3
    assert _setup(repo, stubs).returncode == 0 and _installs(log) == 3
    (repo / "nlipscalib").unlink()
    assert _setup(repo, stubs).returncode == 0
    assert _installs(log) == 4
    # ... also when the checkout has its package but the venv imports another one: the check must not
    # import from the current directory
    (repo / "nlipscalib").mkdir()
    shutil.copy(ROOT / "nlipscalib" / "__init__.py", repo / "nlipscalib")
    wrapper = repo / ".venv" / "bin" / "python"
    wrapper.write_text(
        "".join(line for line in wrapper.read_text(encoding="utf-8").splitlines(True) if "PYTHONPATH" not in line),
        encoding="utf-8",
    )
    wrapper.write_text(wrapper.read_text(encoding="utf-8") + f'exec "{sys.executable}" "$@"\n', encoding="utf-8")
    assert _setup(repo, stubs).returncode == 0
    assert _installs(log) == 5


def test_unknown_argument_is_one_line_and_non_zero(checkout):
    repo, log, stubs = checkout
    res = _setup(repo, stubs, "--frobnicate")
    assert res.returncode == 2 and res.stderr.strip().count("\n") == 0 and "--frobnicate" in res.stderr
    assert _installs(log) == 0


def test_torch_comes_from_the_cpu_index_not_pypis_cuda_build(checkout):
    """A venv without torch gets PyTorch's CPU build: a plain `pip install torch==X` takes PyPI's Linux
    wheel, a CUDA build with several GB of nvidia-* packages (the README promises none)."""
    repo, log, stubs = checkout
    (repo.parent / "no-torch").touch()
    assert _setup(repo, stubs).returncode == 0
    torch_calls = [line for line in log.read_text(encoding="utf-8").splitlines() if "torch==" in line]
    assert len(torch_calls) == 1
    assert "--index-url https://download.pytorch.org/whl/cpu" in torch_calls[0]
    (repo.parent / "no-torch").unlink()
    assert _setup(repo, stubs).returncode == 0
    assert (
        sum("torch==" in line for line in log.read_text(encoding="utf-8").splitlines()) == 1
    )  # installed: not asked again


def test_torch_falls_back_to_the_configured_index_when_the_cpu_index_fails(checkout):
    """Where pip cannot reach PyTorch's index nor find the wheel locally (a mirror set as its index), setup.sh
    still installs: the same version from the configured index, with a warning that says what that costs."""
    repo, log, stubs = checkout
    (repo.parent / "no-torch").touch()
    (repo.parent / "cpu-index-down").touch()
    res = _setup(repo, stubs)
    assert res.returncode == 0, res.stderr
    torch_calls = [line for line in log.read_text(encoding="utf-8").splitlines() if "torch==" in line]
    assert len(torch_calls) == 2 and "--index-url" in torch_calls[0] and "--index-url" not in torch_calls[1]
    assert "setup: warning: torch's CPU build is not reachable" in res.stderr


def test_a_python_older_than_3_11_is_refused_in_one_line_before_anything_is_installed(checkout, tmp_path):
    """Ubuntu 22.04's python3 is 3.10: pip refused the package only after downloading torch, and a missing venv
    made the run end on `.venv/bin/python: No such file or directory`."""
    repo, log, stubs = checkout
    (repo / ".venv" / "bin" / "python").unlink()
    old = tmp_path / "python3.10"
    _exe(old, '#!/bin/sh\n[ "$1" = --version ] && echo "Python 3.10.12" && exit 0\n[ "$1" = -c ] && exit 1\nexit 0\n')
    res = _setup(repo, stubs, PYTHON=str(old))
    assert res.returncode == 1 and res.stderr.strip().count("\n") == 0, res.stderr
    assert "needs Python >= 3.11" in res.stderr and "is Python 3.10.12" in res.stderr
    assert not log.exists(), log.read_text(encoding="utf-8")  # neither apt-get nor pip ran


def test_a_python_without_its_venv_package_gets_it_before_the_venv_is_made(checkout, tmp_path):
    """Debian's and Ubuntu's python3 has no ensurepip until pythonX.Y-venv is installed: `python3 -m venv`
    failed on a fresh machine, the first command of the README."""
    repo, log, stubs = checkout
    wrapper = repo / ".venv" / "bin" / "python"
    saved = tmp_path / "venv-python"
    shutil.move(wrapper, saved)
    bare = tmp_path / "python3"
    _exe(
        bare,
        f"""#!/bin/sh
case "$*" in
  *ensurepip*) [ -e "{tmp_path}/venv-installed" ] || exit 1 ;;
  "-m venv .venv") cp "{saved}" .venv/bin/python; exit 0 ;;
esac
exec "{sys.executable}" "$@"
""",
    )
    res = _setup(repo, stubs, PYTHON=str(bare))
    assert res.returncode == 0, res.stderr
    package = f"python{sys.version_info[0]}.{sys.version_info[1]}-venv"
    assert f"apt-get install -y -qq {package}" in log.read_text(encoding="utf-8")
    assert _installs(log) == 1


def test_ldconfig_off_the_path_as_for_debians_users_still_finds_llvm(checkout):
    """/sbin is not on a Debian user's PATH: `ldconfig` was not found, so LLVM looked missing and every run
    installed libllvm19 again (apt-get update included), contrary to "a second run only checks"."""
    ldconfig = next((p for p in ("/sbin/ldconfig", "/usr/sbin/ldconfig") if os.access(p, os.X_OK)), None)
    if ldconfig is None or "libLLVM" not in subprocess.run([ldconfig, "-p"], capture_output=True, text=True).stdout:
        pytest.skip("no ldconfig in /sbin listing an LLVM here")
    listing = subprocess.run([ldconfig, "-p"], capture_output=True, text=True).stdout
    if not any(f"libLLVM-{v}" in listing or f"libLLVM.so.{v}" in listing for v in range(16, 30)):
        pytest.skip("no LLVM >= 16 installed here")
    repo, log, stubs = checkout
    path = os.pathsep.join(d for d in os.environ["PATH"].split(os.pathsep) if not d.rstrip("/").endswith("sbin"))
    res = _setup(repo, stubs, path=path)
    assert res.returncode == 0, res.stderr
    assert "libllvm19" not in (log.read_text(encoding="utf-8") if log.exists() else "")


def test_a_machine_without_python3_gets_debians_before_anything_else(checkout, tmp_path):
    """A minimal Debian image (docker's debian:12, a bare cloud VM) has no python3: the README's first command
    ended on "needs Python >= 3.11; python3 is not installed". setup.sh installs the distribution's python3 as it
    installs the other system packages (Debian 12's is 3.11)."""
    repo, log, stubs = checkout
    saved = tmp_path / "venv-python"
    shutil.move(repo / ".venv" / "bin" / "python", saved)
    bare = tmp_path / "bin-without-python"  # the system's tools, every python* left out
    bare.mkdir()
    for folder in ("/usr/bin", "/bin"):
        for tool in Path(folder).iterdir():
            if not tool.name.startswith("python") and not (bare / tool.name).exists():
                (bare / tool.name).symlink_to(tool)
    _exe(  # apt-get installing python3 puts one on the PATH; the venv it makes is setup's own wrapper again
        stubs / "apt-get",
        f"""#!/bin/sh
echo "apt-get $*" >>"{log}"
case "$*" in
  *"install -y -qq python3") printf '#!/bin/sh\\n[ "$1 $2" = "-m venv" ] && exec cp "{saved}" .venv/bin/python\\n'\\
'exec "{sys.executable}" "$@"\\n' >"{stubs}/python3"; chmod +x "{stubs}/python3" ;;
esac
""",
    )
    res = _setup(repo, stubs, path=str(bare))
    assert "apt-get install -y -qq python3" in log.read_text(encoding="utf-8"), (
        res.stderr,
        log.read_text(encoding="utf-8"),
    )
    assert "installing python3 (none on the PATH)" in res.stdout
    assert res.returncode == 0 and _installs(log) == 1, res.stderr


def test_an_ldconfig_still_writing_when_grep_has_its_match_does_not_look_like_missing_llvm(checkout):
    """With pipefail, `ldconfig -p | grep -q` failed whenever grep stopped at its match before ldconfig had written
    the rest (SIGPIPE): LLVM looked missing at random and the run installed libllvm19 again (seen in CI)."""
    repo, log, stubs = checkout
    _exe(
        stubs / "ldconfig",
        '#!/bin/sh\necho "\tlibLLVM.so.19.1 (libc6,x86-64) => /lib/libLLVM.so.19.1"\nsleep 0.3\n'
        'i=0; while [ $i -lt 2000 ]; do echo "\tlibother$i.so => /lib/libother$i.so"; i=$((i+1)); done\n',
    )
    res = _setup(repo, stubs)
    assert res.returncode == 0, res.stderr
    assert "libllvm19" not in (log.read_text(encoding="utf-8") if log.exists() else "")
