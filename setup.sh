#!/usr/bin/env bash
# Install nlipscalib and everything it needs into ./.venv on a fresh Debian/Ubuntu machine.
# Idempotent: a second run only checks (no download, no pip install) unless pyproject.toml changed
# since the last install or the installed environment no longer matches it.
# Usage: bash setup.sh [--force]   (--force: run pip install even when everything matches)
set -euo pipefail
cd "$(dirname "$0")"
FORCE=0
case "${1:-}" in
  "") ;;
  --force) FORCE=1 ;;
  *) echo "setup: unknown argument '$1' (usage: bash setup.sh [--force])" >&2; exit 2 ;;
esac
SUDO=""; [ "$(id -u)" != 0 ] && command -v sudo >/dev/null && SUDO="sudo"

# pyproject.toml's requires-python, checked before anything is installed: pip would refuse the package only
# after torch's download (Ubuntu 22.04's python3 is 3.10).
PY=${PYTHON:-python3}
# A minimal Debian/Ubuntu image (a container, a cloud VM) has no python3 at all: Debian 12's is 3.11, Ubuntu 24.04's
# 3.12 (an older one is refused below, in one line).
if [ -z "${PYTHON:-}" ] && [ ! -x .venv/bin/python ] && ! command -v python3 >/dev/null && command -v apt-get >/dev/null; then
  echo "setup: installing python3 (none on the PATH)"
  { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq python3 >/dev/null; } \
    || echo "setup: warning: could not install python3" >&2
fi
VENV_PY=.venv/bin/python; [ -x "$VENV_PY" ] || VENV_PY=$PY
if ! "$VENV_PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
  FOUND=$("$VENV_PY" --version 2>/dev/null) || FOUND="not installed"
  echo "setup: nlipscalib needs Python >= 3.11; $VENV_PY is $FOUND" \
    "(PYTHON=python3.11 bash setup.sh uses another; rm -r .venv if it was made with an older one)" >&2
  exit 1
fi

# drjit's LLVM backend aborts the whole process with Debian 12's default LLVM 15
# ("Cannot select ... fminimum"); LLVM 19 works. Without it we fall back to the slow scalar_rgb.
# ldconfig is in /sbin, which Debian leaves off a user's PATH: without it every run would install again.
# The listing is read whole before grep: with pipefail, `ldconfig -p | grep -q` fails when grep stops at the first
# match while ldconfig still writes (SIGPIPE), and LLVM then looked missing at random (seen in CI).
LDCONFIG=$(command -v ldconfig || echo /sbin/ldconfig)
LIBRARIES=$("$LDCONFIG" -p 2>/dev/null || true)
if ! grep -qE 'libLLVM(\.so\.|-)(1[6-9]|2[0-9])' <<<"$LIBRARIES"; then
  if command -v apt-get >/dev/null; then
    echo "setup: installing libllvm19 for Mitsuba's LLVM backend"
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq libllvm19 >/dev/null \
      || echo "setup: warning: could not install libllvm19; rendering will use the slow scalar_rgb variant" >&2
  else
    echo "setup: warning: no apt-get; install LLVM >= 16 yourself for fast rendering" >&2
  fi
fi

# LED controller firmware (firmware/): AVR toolchain to build it, simavr to test it without a board.
# The firmware tests skip without these (and fail when NLIPS_REQUIRE_DEVICE_TOOLS=1, as in CI).
if ! { command -v avr-g++ >/dev/null && [ -e /usr/lib/avr/include/avr/io.h ] \
       && [ -e /usr/include/simavr/sim_avr.h ] && command -v cc >/dev/null && command -v make >/dev/null; }; then
  if command -v apt-get >/dev/null; then
    echo "setup: installing the AVR toolchain and simavr for the LED firmware"
    { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq gcc-avr avr-libc binutils-avr simavr \
        libsimavr-dev libsimavrparts1 gcc make >/dev/null; } \
      || echo "setup: warning: could not install gcc-avr/avr-libc/simavr; the firmware tests will be skipped" >&2
  else
    echo "setup: warning: no apt-get; install gcc-avr, avr-libc and simavr to build and test firmware/" >&2
  fi
fi

# Debian's and Ubuntu's Python makes no venv without its pythonX.Y-venv package (no ensurepip).
if [ ! -x .venv/bin/python ] && ! "$PY" -c 'import ensurepip, venv' 2>/dev/null && command -v apt-get >/dev/null; then
  VENV_PKG=$("$PY" -c 'import sys; print("python%d.%d-venv" % sys.version_info[:2])')
  echo "setup: installing $VENV_PKG ($PY cannot make a venv without it)"
  { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq "$VENV_PKG" >/dev/null; } \
    || echo "setup: warning: could not install $VENV_PKG; making .venv will fail" >&2
fi
[ -x .venv/bin/python ] || "$PY" -m venv .venv
PIP=(.venv/bin/python -m pip install -q --disable-pip-version-check)
# Install torch's CPU build first, from PyTorch's CPU index: PyPI's Linux torch wheels are CUDA builds
# (several GB of nvidia-* packages), whatever the version pin. The project itself only asks for a range
# (torch>=2.6,<3), which this satisfies, so nothing more is downloaded. Offline, pip's own find-links and
# extra indexes still serve it (after a retry warning); where pip cannot get it that way (a mirror set
# as its index), the configured index is asked for the same version.
TORCH_CPU_INDEX=https://download.pytorch.org/whl/cpu
if ! .venv/bin/python -c "import torch" 2>/dev/null; then
  # bounded: where that index cannot be reached, pip's default (5 retries of up to PIP_DEFAULT_TIMEOUT) can wait minutes
  "${PIP[@]}" --retries 1 --timeout 30 --index-url "$TORCH_CPU_INDEX" "torch==2.13.0" || {
    echo "setup: warning: torch's CPU build is not reachable ($TORCH_CPU_INDEX); installing torch==2.13.0" \
      "from pip's configured index (on Linux, PyPI's is a CUDA build of several GB)" >&2
    "${PIP[@]}" "torch==2.13.0"
  }
fi

# The editable install is what a second run skips: pip resolves every requirement against the index
# (network, tens of seconds) even when nothing changes. Skipped only when the hash of pyproject.toml
# recorded after the last successful install still matches, nlipscalib imports from this checkout, and
# every requirement of nlipscalib[all] in the installed metadata (which must be pyproject.toml's) is
# installed at a satisfying version. Anything unexpected in the check means "install".
STAMP=.venv/.nlipscalib-pyproject.sha256
installed_matches() {
  [ -x .venv/bin/nlips ] || return 1
  # -P: the checkout (the current directory) must not be on sys.path, or it would always be what imports
  .venv/bin/python -P - "$STAMP" <<'PY' 2>/dev/null
import hashlib, importlib.metadata as md, pathlib, sys, tomllib

try:
    from packaging.requirements import Requirement
except ImportError:  # not installed by itself in every venv; pip always carries a copy
    from pip._vendor.packaging.requirements import Requirement

stamp, pyproject = pathlib.Path(sys.argv[1]), pathlib.Path("pyproject.toml")
if stamp.read_text().strip() != hashlib.sha256(pyproject.read_bytes()).hexdigest():
    sys.exit(1)
import nlipscalib

if pathlib.Path(nlipscalib.__file__).resolve().parent != pathlib.Path("nlipscalib").resolve():
    sys.exit(1)  # another checkout (or a regular install) is what this venv imports
project = tomllib.loads(pyproject.read_text())["project"]
dist = md.distribution("nlipscalib")
if dist.version != project["version"]:
    sys.exit(1)


def key(req):
    return req.name.lower().replace("_", "-"), frozenset(str(s) for s in req.specifier)


wanted = {key(Requirement(r)) for r in project["dependencies"]}
wanted |= {key(Requirement(r)) for reqs in project["optional-dependencies"].values() for r in reqs}
extras = set(dist.metadata.get_all("Provides-Extra") or [])
have = set()
for text in dist.requires or []:
    req = Requirement(text)
    have.add(key(req))
    if req.marker is not None and not any(req.marker.evaluate({"extra": e}) for e in extras | {""}):
        continue  # another platform's requirement: nothing to have installed
    if req.name != "nlipscalib" and not req.specifier.contains(md.version(req.name), prereleases=True):
        sys.exit(1)  # raises PackageNotFoundError (exit 1) when one is missing
if have != wanted:
    sys.exit(1)  # the installed metadata was built from another pyproject.toml
PY
}
if [ "$FORCE" = 0 ] && [ -f "$STAMP" ] && installed_matches; then
  echo "setup: .venv already matches pyproject.toml; nothing to install (bash setup.sh --force reinstalls)"
else
  rm -f "$STAMP"  # an interrupted install must not look complete
  "${PIP[@]}" -e ".[all]"
  .venv/bin/python -c 'import hashlib; print(hashlib.sha256(open("pyproject.toml", "rb").read()).hexdigest())' \
    >"$STAMP"
fi
echo "setup: done. Run: .venv/bin/nlips demo   or   .venv/bin/python -m pytest"
