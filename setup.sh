#!/usr/bin/env bash
# Install nlipscalib and everything it needs into ./.venv on a fresh Debian/Ubuntu machine.
# Idempotent: a second run only checks. Usage: bash setup.sh
set -euo pipefail
cd "$(dirname "$0")"

# drjit's LLVM backend aborts the whole process with Debian 12's default LLVM 15
# ("Cannot select ... fminimum"); LLVM 19 works. Without it we fall back to the slow scalar_rgb.
if ! ldconfig -p 2>/dev/null | grep -qE 'libLLVM(\.so\.|-)(1[6-9]|2[0-9])'; then
  SUDO=""; [ "$(id -u)" != 0 ] && command -v sudo >/dev/null && SUDO="sudo"
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
  SUDO=""; [ "$(id -u)" != 0 ] && command -v sudo >/dev/null && SUDO="sudo"
  if command -v apt-get >/dev/null; then
    echo "setup: installing the AVR toolchain and simavr for the LED firmware"
    { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq gcc-avr avr-libc binutils-avr simavr \
        libsimavr-dev libsimavrparts1 gcc make >/dev/null; } \
      || echo "setup: warning: could not install gcc-avr/avr-libc/simavr; the firmware tests will be skipped" >&2
  else
    echo "setup: warning: no apt-get; install gcc-avr, avr-libc and simavr to build and test firmware/" >&2
  fi
fi

PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
PIP=(.venv/bin/python -m pip install -q --disable-pip-version-check)
# Pin torch to the CPU build first: an unpinned torch pulls a multi-GB CUDA build. The project itself
# only asks for a range (torch>=2.2,<3), which this satisfies, so nothing more is downloaded.
.venv/bin/python -c "import torch" 2>/dev/null || "${PIP[@]}" "torch==2.13.0"
"${PIP[@]}" -e ".[all]"
echo "setup: done. Run: .venv/bin/nlips demo   or   .venv/bin/python -m pytest"
