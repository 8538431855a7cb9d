#!/usr/bin/env bash
# Install pydynrad's wheel where there is no compiler, and use it.
#
#   tools/check_wheel.sh [WHEEL]
#
# Without WHEEL, builds one first (tools/build_wheel.sh, into a temporary folder). Then: a fresh
# virtual environment; PATH reduced to that environment's bin/ (python, pip) and the linker `ld`
# that PoCL needs at run time (no cc, gcc, clang, make, as: checked) and CC/CXX pointing nowhere; `pip install WHEEL`, with every
# dependency from the package index (pip's cache makes reruns quick); then, from a folder
# outside the source tree: import it (from the environment, not the checkout), compute a small
# closed box's form factors on PoCL (rows sum to 1), `pydynrad info`, and check that the base
# install names the extra a Dask or matplotlib call needs. Prints each step's seconds.
# PYTHON=/path/to/python picks the interpreter (default: python3 on PATH).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
python="${PYTHON:-python3}"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
now() { echo "${EPOCHREALTIME/,/.}"; }
took() { "$python" -c 'import sys, time; print(f"{time.time() - float(sys.argv[1]):.1f}")' "$1"; }

t=$(now)
if [ $# -ge 1 ]; then
    wheel="$(cd "$(dirname "$1")" && pwd)/$(basename "$1")"
else
    wheel="$(PYTHON="$python" "$root/tools/build_wheel.sh" "$tmp/dist" 2>"$tmp/build.log")" \
        || { cat "$tmp/build.log" >&2; echo "check_wheel: the wheel build failed" >&2; exit 1; }
    echo "check_wheel: built $(basename "$wheel") in $(took "$t") s"
fi

t=$(now)
"$python" -m venv "$tmp/venv"
mkdir "$tmp/run" "$tmp/linker"
# PoCL (pocl-binary-distribution) links each kernel it compiles with the system linker: `ld` from
# binutils, which is not a compiler but must be on PATH (without it PoCL aborts the process).
ld="$(command -v ld || true)"
[ -n "$ld" ] && ln -s "$ld" "$tmp/linker/ld"
# Every command from here runs with PATH = the environment's own bin/ (python, pip and what pip
# installs there; symlinks elsewhere would take python out of its venv) plus that one linker, and
# no compiler reachable; only this script's own shell keeps the full PATH.
bare() { env -u PYTHONPATH -u VIRTUAL_ENV PATH="$tmp/venv/bin:$tmp/linker" CC=/nonexistent CXX=/nonexistent LDSHARED=/nonexistent \
             POCL_CACHE_DIR="$tmp/pocl" MPLBACKEND=Agg PIP_DISABLE_PIP_VERSION_CHECK=1 "$@"; }
cd "$tmp/run"
bare python - <<'PY'
import shutil
found = {c: shutil.which(c) for c in ("cc", "gcc", "clang", "c++", "g++", "make", "as") if shutil.which(c)}
assert not found, f"a compiler is still on PATH: {found}"
PY
bare pip install --quiet "$wheel"
echo "check_wheel: fresh venv and pip install (dependencies from the index) in $(took "$t") s"

t=$(now)
bare python - "$tmp/venv" <<'PY'
import sys
from pathlib import Path

import numpy as np

import pydynrad
from pydynrad.scenes import closed_box

here = Path(pydynrad.__file__).resolve()
assert Path(sys.argv[1]).resolve() in here.parents, f"imported {here}, not the installed wheel"
assert (here.parent / "py.typed").is_file() and (here.parent / "kernels" / "hemicube.cl").is_file()
scene = closed_box(subdivisions=2)
F = pydynrad.form_factors(scene, resolution=16)
sums = np.asarray(F.sum(axis=1)).ravel()
assert F.shape == (len(scene), len(scene)) and np.abs(sums - 1).max() < 0.02, sums
print(f"pydynrad {pydynrad.__version__} from {here.parent}: {len(scene)} patches, "
      f"row sums of F in [{sums.min():.4f}, {sums.max():.4f}] on {pydynrad.default_device().name}")
PY
bare "$tmp/venv/bin/pydynrad" info
echo "check_wheel: import, form factors on PoCL (fresh kernel cache) and pydynrad info in $(took "$t") s"

bare python - <<'PY'
import numpy as np

from pydynrad.errors import MissingExtraError
from pydynrad.photometry import plot_work_plane, work_plane
from pydynrad.precompute.distributed import precompute_distributed

plane = work_plane([[0, 0], [1, 0], [1, 1], [0, 1]], 0.8, spacing=0.5)
for call, extra in ((lambda: precompute_distributed("cornell_box", "ff", resolution=8), "dask"),
                    (lambda: plot_work_plane("p.png", plane, np.ones(len(plane))), "plot")):
    try:
        call()
    except MissingExtraError as exc:
        assert f"pip install 'pydynrad[{extra}]'" in str(exc), exc
        print(f"base install: {exc}")
    else:
        raise AssertionError(f"the base install has the {extra} extra's packages")
PY
echo "check_wheel: ok"
