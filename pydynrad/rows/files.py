"""Form factors on disk, one entry point for both layouts.

* a single ``.npz`` file (:func:`save_form_factors` / :func:`load_form_factors`): the CSR
  arrays of F plus a JSON header (format, scene geometry hash, N, resolution, samples); read whole
  into memory, for scenes whose F fits in RAM;
* a form-factor store folder (:class:`pydynrad.FormFactorStore`): F in compressed row
  blocks, read on demand, for scenes whose F does not fit.

:func:`open_form_factors` takes either and returns what :class:`~pydynrad.DynamicRadiosity`
and :func:`pydynrad.walk` accept: a CSR matrix for a file, a ``RowSource`` for a store
(behind a bounded :class:`~pydynrad.rows.cache.RowCache` when ``cache_bytes`` is given).
Both refuse data made for another scene geometry.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from ..atomic import check_parent_folder, write_atomic
from ..checks import resolution as checked_resolution
from ..checks import sparse_structure
from ..errors import InvalidInputError
from ..formfactors import checked_samples
from ..geometry.loading import checked_scene
from .cache import RowCache
from .sources import RowSource
from .store import FormFactorStore, StoreIncompleteError

__all__ = [
    "FF_FORMAT",
    "is_form_factor_file",
    "load_form_factors",
    "open_form_factors",
    "recorded_resolution",
    "save_form_factors",
    "whole_matrix",
]

FF_FORMAT = "pydynrad-form-factors"
FF_VERSION = 1


def save_form_factors(scene, path, F, resolution: int, samples: int = 1) -> Path:
    """Save sparse F (N, N) of ``scene`` at ``path`` as ``.npz`` with a JSON header; returns the path.

    The header records the format, the scene's name and geometry hash, N, the hemicube
    ``resolution``, the hemicubes per row ``samples`` (:func:`pydynrad.form_factors`) and nnz.
    Written whole (temporary file in the same folder, then rename).
    """
    scene = checked_scene(scene)
    resolution = checked_resolution(resolution)
    samples = checked_samples(samples, resolution)
    path = check_parent_folder(path)
    if path.suffix.lower() != ".npz":
        raise InvalidInputError(f"form-factor file {str(path)!r} must end in .npz")
    F = sp.csr_matrix(F)
    n = len(scene)
    if F.shape != (n, n):
        raise InvalidInputError(f"F must have shape ({n}, {n}) for this {n}-patch scene; got {F.shape}")
    header = {
        "format": FF_FORMAT,
        "version": FF_VERSION,
        "scene": scene.name,
        "geometry_hash": scene.geometry_hash(),
        "n_patches": n,
        "resolution": resolution,
        "samples": samples,
        "nnz": int(F.nnz),
    }
    buf = io.BytesIO()
    np.savez(
        buf,
        header=np.array(json.dumps(header)),
        data=F.data.astype(np.float32),
        indices=F.indices.astype(np.int32),
        indptr=F.indptr.astype(np.int64),
    )
    write_atomic(path, buf.getvalue())
    return path


def load_form_factors(
    scene, path, *, resolution: int | None = None, samples: int | None = None
) -> tuple[sp.csr_matrix, dict]:
    """Read a file written by :func:`save_form_factors` for ``scene``; returns (F (N, N) float32 CSR, header).

    The header's ``samples`` is 1 for files written before it was recorded (they were all
    single hemicubes). Raises :class:`InvalidInputError` when the file is missing, malformed,
    made for another scene geometry, or, where ``resolution`` or ``samples`` is given, made
    with another one.
    """
    scene = checked_scene(scene)
    path = Path(path)
    if not path.is_file():
        why = "no such file" if not path.exists() else "not a regular file"
        raise InvalidInputError(f"form-factor file {str(path)!r}: {why}")
    header, (data, indices, indptr) = _read(path, arrays=True)
    n = int(header["n_patches"])
    if header.get("geometry_hash") != scene.geometry_hash():
        raise InvalidInputError(
            f"form-factor file {str(path)!r} was computed for another scene geometry "
            f"({header.get('scene')!r}, {n} patches; this scene has {len(scene)} patches): "
            "recompute it with `pydynrad formfactors`"
        )
    if n != len(scene) or data.ndim != 1:
        raise InvalidInputError(
            f"form-factor file {str(path)!r} is damaged: header says {n} patches, "
            f"data has shape {data.shape}; this scene has {len(scene)} patches"
        )
    if data.dtype not in (np.float32, np.float64):  # float16, complex or text: scipy would fail or warn inside
        raise InvalidInputError(
            f"form-factor file {str(path)!r} holds {data.dtype} values; form factors are float32 "
            "or float64: recompute it with `pydynrad formfactors`"
        )
    _check_parameters(path, header, resolution, samples)
    # Before scipy sees them: its kernels index memory with these arrays unchecked.
    sparse_structure(indptr, indices, (n, n), f"form-factor file {str(path)!r}", nnz=len(data))
    return sp.csr_matrix((data, indices, indptr), shape=(n, n)), header


def _check_parameters(path: Path, header: dict, resolution: int | None, samples: int | None) -> None:
    """The header's resolution and samples (1 when absent) valid, and equal to those requested."""
    header.setdefault("samples", 1)
    try:
        have = {"resolution": checked_resolution(header.get("resolution"))}
        have["samples"] = checked_samples(header["samples"], have["resolution"])
    except InvalidInputError as exc:
        raise InvalidInputError(f"form-factor file {str(path)!r} is damaged: {exc}") from None
    want = {"resolution": None if resolution is None else checked_resolution(resolution), "samples": samples}
    if want["samples"] is not None:
        want["samples"] = checked_samples(samples, want["resolution"] or have["resolution"])
    diff = [f"{k} {have[k]}, requested {v}" for k, v in want.items() if v is not None and have[k] != v]
    if diff:
        raise InvalidInputError(
            f"form-factor file {str(path)!r} was computed with other parameters "
            f"({'; '.join(diff)}): recompute it with `pydynrad formfactors`"
        )


def _read(path: Path, arrays: bool) -> tuple[dict, tuple]:
    """(header, (data, indices, indptr) or ()) of a file written by :func:`save_form_factors`;
    InvalidInputError for anything else."""
    try:
        with np.load(path, allow_pickle=False) as z:
            header = json.loads(str(z["header"]))
            int(header["n_patches"])  # a header without a patch count is not ours either
            found = tuple(z[k] for k in ("data", "indices", "indptr")) if arrays else ()
    except Exception as exc:  # zipfile, KeyError, ValueError, JSON: all mean "not our file"
        raise InvalidInputError(f"form-factor file {str(path)!r} is not a pydynrad form-factor file ({exc})") from None
    if header.get("format") != FF_FORMAT:
        raise InvalidInputError(f"form-factor file {str(path)!r} is not a pydynrad form-factor file")
    return header, found


def is_form_factor_file(path) -> bool:
    """True when ``path`` is a file :func:`save_form_factors` wrote (for whatever scene); reads its header only."""
    try:
        _read(Path(path), arrays=False)
    except InvalidInputError:
        return False
    return True


def _open_store(scene, path: Path, samples: int | None = None, resolution: int | None = None):
    """The complete store at ``path``, checked against ``scene`` with the parameters it records
    (and with ``samples`` and ``resolution`` where given)."""
    params = FormFactorStore.read_header(path)["params"]
    store = FormFactorStore.open(
        scene,
        path,
        resolution=params["resolution"] if resolution is None else resolution,
        patching=params["patching"],
        samples=params.get("samples", 1) if samples is None else samples,
    )
    missing = store.missing_blocks()
    if missing and len(missing) == store.n_blocks and store.complete_clusters:
        raise StoreIncompleteError(
            f"form-factor store {str(path)!r} holds G alone (made with --no-f), not F's rows, "
            "which the CLI's commands need: from Python, DynamicRadiosity(scene, None, "
            "cluster_form_factors=store.cluster_form_factors(...)); or store F too, without --no-f"
        )
    if missing:
        raise StoreIncompleteError(
            f"form-factor store {str(path)!r} is unfinished ({len(missing)} of {store.n_blocks} "
            "blocks missing): run `pydynrad formfactors` with the same options again to finish it"
        )
    return store


def open_form_factors(
    scene, path, cache_bytes: int | None = None, *, samples: int | None = None, resolution: int | None = None
):
    """F of ``scene`` from a ``.npz`` file or a form-factor store folder.

    Returns a float32 CSR matrix (N, N) for a file. For a store, the
    :class:`~pydynrad.FormFactorStore` itself (every row read goes to disk) or, with
    ``cache_bytes``, a :class:`~pydynrad.rows.cache.RowCache` of that many bytes over it (LRU,
    with background prefetch; close it when done). ``cache_bytes`` does not apply to a file,
    which is in memory whole. With ``samples``, F must have been computed with that many
    hemicubes per row (:func:`pydynrad.form_factors`; files and stores from before it was
    recorded hold 1), and with ``resolution`` at that hemicube resolution
    (:func:`recorded_resolution` reads the one it was).

    Raises :class:`InvalidInputError` for a missing path or a file that is not a pydynrad
    form-factor file, :class:`~pydynrad.rows.StoreMismatchError` for a store made for
    another scene geometry (or other parameters, ``samples`` among them; a file with other
    ``samples`` raises InvalidInputError), :class:`~pydynrad.rows.StoreIncompleteError`
    for a store not finished yet.
    """
    scene = checked_scene(scene)
    path = Path(path)
    if path.is_dir():
        store = _open_store(scene, path, samples, resolution)
        return store if cache_bytes is None else RowCache(store, cache_bytes)
    if not path.exists():
        raise InvalidInputError(f"form factors {str(path)!r}: no such file or store folder")
    return load_form_factors(scene, path, resolution=resolution, samples=samples)[0]


def recorded_resolution(path) -> int:
    """The hemicube resolution a form-factor file or store folder at ``path`` records, read from
    its header alone (checked as :func:`open_form_factors` checks it)."""
    path = Path(path)
    if path.is_dir():
        header = FormFactorStore.read_header(path).get("params")
        header = header if isinstance(header, dict) else {}
    elif path.exists():
        header = _read(path, arrays=False)[0]
    else:
        raise InvalidInputError(f"form factors {str(path)!r}: no such file or store folder")
    try:
        return checked_resolution(header.get("resolution"))
    except InvalidInputError as exc:
        raise InvalidInputError(f"form factors {str(path)!r} are damaged: {exc}") from None


def whole_matrix(form_factors) -> sp.csr_matrix:
    """All of F (N, N) as CSR in memory, from a matrix or any RowSource (a RowCache reads past its cache).

    For the full radiosity solve, which needs every row; only for scenes whose F fits in RAM.
    """

    if isinstance(form_factors, RowCache):
        form_factors = form_factors.source  # reading all rows through the cache would only evict it
    if isinstance(form_factors, RowSource):
        return sp.csr_matrix(form_factors.rows(np.arange(int(form_factors.n_patches))))
    return sp.csr_matrix(form_factors)
