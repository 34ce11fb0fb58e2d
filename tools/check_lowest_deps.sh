#!/usr/bin/env bash
# Checks that pyproject.toml's lower bounds are true: installs the lowest versions it allows of every direct
# dependency (all extras; uv's --resolution lowest-direct, indirect ones at their newest) into a throw-away venv,
# runs the given test folders and `nlips demo` there, and removes the venv.
#
#   bash tools/check_lowest_deps.sh                      # tests/core tests/solver tests/cli, not the slow ones
#   bash tools/check_lowest_deps.sh tests/sim tests/learn
#   KEEP=1 VENV=/tmp/lowest bash tools/check_lowest_deps.sh   # keep the venv (and uv's cache) for a rerun
#
# Not part of .ci/run: it needs PyPI and minutes, and about 6 GB of disk, most of it the CUDA packages of PyPI's torch
# (PyPI's Linux torch wheels are CUDA builds). PYTHON picks the interpreter (default python3.11).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PYTHON="${PYTHON:-python3.11}"
VENV="${VENV:-$(mktemp -d /tmp/nlips-lowest.XXXXXX)}"
TESTS=("$@")
[ ${#TESTS[@]} -gt 0 ] || TESTS=(tests/core tests/solver tests/cli)
export UV_CACHE_DIR="$VENV/uv-cache"  # removed with the venv

cleanup() { [ "${KEEP:-0}" = 1 ] || rm -rf "$VENV"; }
trap cleanup EXIT

[ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q uv
"$VENV/bin/uv" pip compile -q --resolution lowest-direct --all-extras --python "$VENV/bin/python" \
    "$ROOT/pyproject.toml" -o "$VENV/lowest.txt"
# with the build system's setuptools (a venv starts with Python's old bundled one): tests/test_packaging builds the
# wheel and sdist without build isolation, and setuptools < 77 rejects pyproject.toml's `license = "MIT"`
"$VENV/bin/uv" pip install -q --python "$VENV/bin/python" -r "$VENV/lowest.txt" "setuptools>=77"
"$VENV/bin/uv" pip install -q --python "$VENV/bin/python" --no-deps -e "$ROOT"
echo "lowest direct versions (indirect ones as resolved):"
grep -E '^[a-z]' "$VENV/lowest.txt" | tr '\n' ' '
echo

cd "$ROOT"
status=0
"$VENV/bin/python" -m pytest -q -p no:cacheprovider -m "not slow" "${TESTS[@]}" || status=1
demo="$(mktemp -d /tmp/nlips-lowest-demo.XXXXXX)"
"$VENV/bin/nlips" demo --out "$demo" || status=1
rm -rf "$demo"
[ $status = 0 ] && echo "lowest dependency versions: passed" || echo "lowest dependency versions: FAILED (above)"
exit $status
