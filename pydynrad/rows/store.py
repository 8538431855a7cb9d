"""An on-disk form-factor store: F in row blocks, compressed, checksummed, resumable.

The paper (section 4.2) streams form factors of big scenes from disk; this module is that
disk. A store is a folder::

    STORE/header.json          scene geometry hash, N, block size, form-factor parameters
    STORE/blocks/b000000.npz   rows [0, block_rows) as one CSR block
    STORE/blocks/b000001.npz   rows [block_rows, 2 block_rows), ...

and, when the far field's patch-to-cluster form factors G = F Pr are stored beside F::

    STORE/clusters.json        C, G's hemicube resolution, the prolongation's SHA-256, parameters
    STORE/prolongation.npz     Pr (N, C), float32, as one CSR block (the clusters G was made with)
    STORE/gblocks/g000000.npz  rows [0, block_rows) of G, ...

and, for moving objects whose poses are known in advance (:func:`pydynrad.precompute.precompute_poses`)::

    STORE/poses.json           the objects (geometry hashes, in order) and the rows' resolution
    STORE/poses/p<sha256>.npz  one configuration's rows, named by the SHA-256 of its transforms

A store may hold G without F's rows (``compute_f=False``): a dynamic solution then computes
F's rows on demand and takes G from the store,
``DynamicRadiosity(scene, None, clusters=Clusters.from_labels(scene, store.cluster_labels()),
cluster_form_factors=store.cluster_form_factors())``. G from other clusters is refused
(:class:`StoreMismatchError`), never mixed in.

Format choice. Each block is a standard NumPy ``.npz`` (a zip archive, DEFLATE-compressed)
holding ``indptr.npy`` (int64, block-local), ``indices.npy`` (int32 column = patch index),
``data.npy`` (float32 F[i, j]) and ``meta.json`` (block index, row range, nnz and the
SHA-256 of the three arrays). Anyone can read a block with ``numpy.load`` alone. Zarr (v3,
as installed here) was considered and not used: its arrays need a regular chunk grid, and a
CSR block's nnz differs from block to block, so ragged rows would need either padding to the
longest row (several times the bytes) or one Zarr group of three arrays per block, whose
several files cannot be replaced in one atomic step. One file per block makes "a chunk is
written whole" exactly one ``os.replace``.

Guarantees:

* a block file is written to a temporary name in the same folder, flushed to disk, then
  renamed over its final name, so a reader sees either no block or a whole one;
* every read verifies the block's SHA-256 (and the zip CRCs); a mismatch raises
  :class:`StoreCorruptError` and no row of that block is served;
* a store interrupted mid-way is resumed by :func:`~pydynrad.precompute.store.compute_store` (or the distributed
  :func:`~pydynrad.precompute.precompute_distributed`): finished blocks are kept, missing
  ones computed, stale temporary files removed;
* opening a store for another scene geometry or other form-factor parameters raises
  :class:`StoreMismatchError`, naming the fields that differ.

One writer run per store at a time: concurrent runs would compute the same blocks twice (the
results stay correct, each block is still replaced whole).

See docs/design.md, 'Row sources, stores and caches'.
"""

from __future__ import annotations

import hashlib
import io
import json
import struct
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from .._version import __version__
from ..atomic import TMP_MARK, write_atomic
from ..checks import integer, patch_indices, sparse_structure
from ..checks import resolution as checked_resolution
from ..errors import InvalidInputError, PydynradError
from ..formfactors import checked_samples
from ..geometry.loading import checked_scene
from .prolongation import LINEAR_FUNCTIONS, as_prolongation, g_samples, labels_of_linear, split_prolongation

__all__ = [
    "FormFactorStore",
    "StoreCorruptError",
    "StoreIncompleteError",
    "StoreMismatchError",
]

FORMAT = "pydynrad-formfactor-store"
FORMAT_VERSION = 1
HEADER = "header.json"
BLOCK_DIR = "blocks"
CLUSTER_HEADER = "clusters.json"
PROLONGATION = "prolongation.npz"
#: The per-pose rows of moving objects: which objects, and one file per configuration.
POSE_HEADER, POSE_DIR = "poses.json", "poses"
#: The two matrices a store holds: F (N columns) and G (C columns), each in its own block folder.
PARTS = {"F": (BLOCK_DIR, "b"), "G": ("gblocks", "g")}
DEFAULT_BLOCK_ROWS = 256
DEFAULT_TASK_ROWS = 4096
# DEFLATE level 1: F's float32 mantissas are nearly incompressible, so higher levels cost
# several times the CPU time for a few percent of size.
COMPRESS_LEVEL = 1

RowFunction = Callable[..., sp.csr_matrix]


class StoreMismatchError(InvalidInputError):
    """The store on disk was computed for another scene geometry or other parameters."""


class StoreCorruptError(PydynradError):
    """A block file on disk fails its checksum or cannot be decoded; it is never served."""


class StoreIncompleteError(PydynradError):
    """Rows were requested from a block that has not been computed yet."""


def _digest(indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, binding: str = "") -> str:
    """SHA-256 of a block's arrays, after ``binding`` (what the block belongs to, see
    :meth:`FormFactorStore._binding`): a block copied from another store, or moved within one,
    then fails its checksum even though its own bytes are intact."""
    h = hashlib.sha256(binding.encode())
    for a in (indptr, indices, data):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _write_csr(path: Path, k: int, rows: range, block, n_cols: int, binding: str = "") -> int:
    """Write a (len(rows), n_cols) sparse block as one compressed, checksummed .npz, atomically; returns bytes."""
    csr = sp.csr_matrix(block, copy=True)  # canonicalised below: never touch the caller's arrays
    if csr.shape != (len(rows), n_cols):
        raise InvalidInputError(f"block {k} must have shape ({len(rows)}, {n_cols}); got {csr.shape}")
    csr.sum_duplicates()
    csr.sort_indices()
    data = csr.data.astype(np.float32)
    if not np.all(np.isfinite(data)) or (data.size and data.min() < 0):
        raise InvalidInputError(f"block {k} holds negative, NaN or infinite form factors")
    indptr = csr.indptr.astype(np.int64)
    indices = csr.indices.astype(np.int32)
    meta = {
        "block": int(k),
        "row_start": rows.start,
        "row_stop": rows.stop,
        "nnz": int(indices.size),
        "sha256": _digest(indptr, indices, data, binding),
        "bound": bool(binding),
    }
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=COMPRESS_LEVEL) as zf:
        for name, a in (("indptr", indptr), ("indices", indices), ("data", data)):
            with zf.open(f"{name}.npy", "w", force_zip64=True) as f:
                np.lib.format.write_array(f, a, allow_pickle=False)
        zf.writestr("meta.json", json.dumps(meta))
    payload = buf.getvalue()
    write_atomic(path, payload)
    return len(payload)


#: Every error decoding a stored file can raise: the zip's structure and CRCs (BadZipFile, EOFError,
#: struct.error), a broken DEFLATE stream (zlib.error, which zipfile lets through), an unknown
#: compression or an encrypted member (NotImplementedError, RuntimeError), the .npy headers and
#: meta.json (ValueError, UnicodeDecodeError, KeyError, TypeError, AttributeError, IndexError).
DECODE_ERRORS = (
    OSError,
    ValueError,
    KeyError,
    EOFError,
    zipfile.BadZipFile,
    zlib.error,
    struct.error,
    NotImplementedError,
    RuntimeError,
    TypeError,
    AttributeError,
    IndexError,
    OverflowError,
)


def _read_csr(
    path: Path, k: int, rows: range, n_cols: int, what: str, store: Path, binding: str = "", legacy: bool = True
) -> sp.csr_matrix:
    """Read and verify a block written by :func:`_write_csr`; ``what`` names it in errors. Every
    decoding or parse error is a :class:`StoreCorruptError` naming the block. ``legacy``: the
    store's blocks may be of the format from before checksums were bound (decided once per
    store, :attr:`FormFactorStore.legacy`); where False a block without the binding is refused."""
    try:
        with zipfile.ZipFile(path) as zf:
            meta = json.loads(zf.read("meta.json"))
            if not isinstance(meta, dict):
                raise ValueError("meta.json is not an object")
            arrays = {
                n: np.lib.format.read_array(zf.open(f"{n}.npy"), allow_pickle=False)
                for n in ("indptr", "indices", "data")
            }
    except FileNotFoundError:
        raise StoreIncompleteError(
            f"{what} of store {store} has not been computed; run compute_store to finish the store"
        ) from None
    except DECODE_ERRORS as exc:
        raise StoreCorruptError(
            f"{what} of store {store} is corrupt: file {path} cannot be decoded "
            f"({type(exc).__name__}: {exc}); run pydynrad formfactors with --verify (or "
            "compute_store(..., verify=True)) to recompute it"
        ) from exc
    indptr, indices, data = arrays["indptr"], arrays["indices"], arrays["data"]
    if binding and not legacy and meta.get("bound") is not True:
        raise StoreCorruptError(
            f"{what} of store {store}: file {path} has the unbound checksum of a store from "
            "before checksums were bound, in a store whose blocks are bound (a block from "
            "elsewhere); run pydynrad formfactors with --verify to recompute it"
        )
    # Blocks written before checksums were bound to their store carry no "bound" flag.
    bound = binding if meta.get("bound") else ""
    if (
        meta.get("block") != k
        or meta.get("row_start") != rows.start
        or meta.get("row_stop") != rows.stop
        or meta.get("sha256") != _digest(indptr, indices, data, bound)
    ):
        raise StoreCorruptError(
            f"{what} of store {store}: file {path} fails its checksum or belongs to another "
            "store or block; run pydynrad formfactors with --verify (or compute_store(..., "
            "verify=True)) to recompute it"
        )
    try:  # a consistent checksum over hand-made arrays still must not send scipy past memory
        sparse_structure(indptr, indices, (len(rows), n_cols), f"file {path}", nnz=len(data))
    except InvalidInputError as exc:
        raise StoreCorruptError(f"{exc}; delete it and re-run compute_store to recompute it") from None
    return sp.csr_matrix((data, indices, indptr), shape=(len(rows), n_cols))


def _is_bound(path: Path) -> bool:
    """Whether the block file at ``path`` records a checksum bound to its store (False where
    it is missing or unreadable: :func:`_read_csr` says what is wrong with it)."""
    try:
        with zipfile.ZipFile(path) as zf:
            meta = json.loads(zf.read("meta.json"))
    except FileNotFoundError:
        return False
    except DECODE_ERRORS:
        return False
    return isinstance(meta, dict) and meta.get("bound") is True


def _intact(path: Path) -> bool:
    """Whether the zip file at ``path`` decodes whole with every member's CRC holding: its bytes
    are as written, so a checksum it fails is another store's or block's, not damage."""
    try:
        with zipfile.ZipFile(path) as zf:
            return zf.testzip() is None
    except DECODE_ERRORS:
        return False


def _canonical_params(resolution: int, patching: dict | None, samples: int = 1) -> dict:
    resolution = checked_resolution(resolution)
    samples = checked_samples(samples, resolution)
    try:
        # A JSON round trip makes tuples lists, so the recorded and the requested values compare equal.
        patch = json.loads(json.dumps(dict(patching or {}), sort_keys=True))
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(
            f"patching parameters must be JSON-serialisable (numbers, strings, lists): {exc}"
        ) from exc
    return {
        "resolution": int(resolution),
        "samples": samples,
        "patching": patch,
        "pydynrad_version": __version__,
        "dtype": "float32",
    }


#: The most rows a block may hold (a block is one file read whole: 2^31 rows is past any use,
#: and 10**20 had made a store no reader could index).
MAX_BLOCK_ROWS = 2**31 - 1


def _described(pose_header: dict) -> list[str]:
    """Each object of a pose header as 'name (patches, hash prefix)'."""
    return [
        f"{o.get('name')} ({o.get('n_patches')} patches, {str(o.get('geometry_hash'))[:8]})"
        for o in pose_header.get("objects", [])
    ]


def _check_header_fields(path: Path, header: dict) -> None:
    """StoreCorruptError naming the first field of a store header that every reader relies on
    and that is missing or of the wrong kind (block_rows 0, a string, no params, ...)."""

    def positive_int(v) -> bool:  # within int64: numpy indexes with them (10**20 had crashed a read)
        return isinstance(v, int) and not isinstance(v, bool) and 1 <= v < 2**62

    params = header.get("params")
    sub = params if isinstance(params, dict) else {}
    fields = (
        ("n_patches", header.get("n_patches"), positive_int, "a positive integer"),
        ("block_rows", header.get("block_rows"), positive_int, "a positive integer"),
        ("geometry_hash", header.get("geometry_hash"), lambda v: isinstance(v, str), "a string"),
        ("params", params, lambda v: isinstance(v, dict), "an object"),
        ("params.resolution", sub.get("resolution"), positive_int, "a positive integer"),
        ("params.samples", sub.get("samples", 1), positive_int, "a positive integer"),
        ("params.patching", sub.get("patching"), lambda v: isinstance(v, dict), "an object"),
    )
    for name, value, ok, kind in fields:
        if not ok(value):
            raise StoreCorruptError(f"store header {path / HEADER}: {name} must be {kind}; got {value!r}")


class FormFactorStore:
    """Form-factor rows of one scene on disk, in CSR blocks of ``block_rows`` rows.

    Create with :meth:`create`, reopen with :meth:`open`; both check the scene and the
    parameters against the header. Implements the ``RowSource`` protocol
    (:meth:`rows`, :attr:`n_patches`), so it can feed a :class:`~pydynrad.rows.cache.RowCache`.
    """

    def __init__(self, path: Path, header: dict) -> None:
        self.path = Path(path)  # a str too (it had raised a bare TypeError at the first block)
        if not isinstance(header, dict):
            raise InvalidInputError(
                f"header must be a store header (a dict, FormFactorStore.read_header); got {type(header).__name__}"
            )
        _check_header_fields(self.path, header)
        self.header = header
        self._legacy: bool | None = None  # decided once, on the first read (legacy)
        self.n_patches = int(header["n_patches"])
        self.block_rows = int(header["block_rows"])
        self.n_blocks = -(-self.n_patches // self.block_rows)
        self._cluster_header = self._read_cluster_header()

    # -- creation and opening --------------------------------------------------------------
    @classmethod
    def create(
        cls,
        scene,
        path,
        *,
        resolution: int,
        block_rows: int = DEFAULT_BLOCK_ROWS,
        patching: dict | None = None,
        exist_ok: bool = False,
        samples: int = 1,
    ) -> FormFactorStore:
        """Make a new, empty store for ``scene`` at ``path`` (a folder).

        ``resolution`` and ``samples`` are the hemicube resolution and the hemicubes per row
        the rows will be computed with (:func:`pydynrad.form_factors`);
        ``patching`` records how the scene was patched (e.g. ``{"max_area": 0.01}``), so a
        store is never reused for another patching of the same input. With ``exist_ok`` an
        existing store with a matching header is opened (to resume it); a mismatching one
        always raises :class:`StoreMismatchError`.
        """
        scene = checked_scene(scene)
        path = Path(path)
        integer(block_rows, "block_rows", 1, MAX_BLOCK_ROWS)
        params = _canonical_params(resolution, patching, samples)
        if (path / HEADER).exists():
            if not exist_ok:
                raise InvalidInputError(
                    f"a form-factor store already exists at {path}; open it, or pass exist_ok=True to resume it"
                )
            store = cls.open(scene, path, resolution=resolution, patching=patching, samples=samples)
            if store.block_rows != block_rows:
                raise StoreMismatchError(f"store {path} has block_rows={store.block_rows}, not {block_rows}")
            return store
        if path.exists() and (not path.is_dir() or any(path.iterdir())):
            raise InvalidInputError(
                f"{path} exists and is not an empty folder; a form-factor store needs its own folder"
            )
        header = {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "scene_name": scene.name,
            "geometry_hash": scene.geometry_hash(),
            "n_patches": int(len(scene)),
            "block_rows": int(block_rows),
            "params": params,
            "checksums": "bound",  # every block's checksum is bound to this store (legacy)
        }
        (path / BLOCK_DIR).mkdir(parents=True, exist_ok=True)
        write_atomic(path / HEADER, json.dumps(header, indent=2, sort_keys=True).encode())
        return cls(path, header)

    @classmethod
    def read_header(cls, path) -> dict:
        """The header of the store at ``path``, checked for format and version only."""
        path = Path(path)
        try:
            header = json.loads((path / HEADER).read_text())
        except FileNotFoundError:
            raise InvalidInputError(f"no form-factor store at {path} (missing {HEADER})") from None
        except (OSError, ValueError) as exc:
            raise StoreCorruptError(f"unreadable store header {path / HEADER}: {exc}") from exc
        if not isinstance(header, dict) or header.get("format") != FORMAT:
            raise InvalidInputError(f"{path} is not a pydynrad form-factor store")
        if header.get("format_version") != FORMAT_VERSION:
            raise StoreMismatchError(
                f"store {path} has format version {header.get('format_version')}; this pydynrad reads {FORMAT_VERSION}"
            )
        _check_header_fields(path, header)
        return header

    @classmethod
    def open(cls, scene, path, *, resolution: int, patching: dict | None = None, samples: int = 1) -> FormFactorStore:
        """Open the store of ``scene`` at ``path``, refusing it unless it was made for this scene and
        parameters (a store from before ``samples`` was recorded holds 1)."""
        scene = checked_scene(scene)
        path = Path(path)
        header = cls.read_header(path)
        want = {
            "geometry_hash": scene.geometry_hash(),
            "n_patches": int(len(scene)),
            **_canonical_params(resolution, patching, samples),
        }
        have = {
            "geometry_hash": header["geometry_hash"],
            "n_patches": header["n_patches"],
            "samples": 1,
            **header["params"],
        }
        diff = [f"{k}: store has {have.get(k)!r}, requested {v!r}" for k, v in want.items() if have.get(k) != v]
        if diff:
            raise StoreMismatchError(f"form-factor store {path} does not match the request ({'; '.join(diff)})")
        return cls(path, header)

    @property
    def samples(self) -> int:
        """Hemicubes per row of F's rows (:func:`pydynrad.form_factors`)."""
        return int(self.header["params"].get("samples", 1))

    @property
    def cluster_samples(self) -> int:
        """Hemicubes per row of G: F's at F's resolution (G is then F Pr of the stored rows), else 1."""
        return g_samples(self.header["params"]["resolution"], self.samples, self.cluster_resolution)

    # -- layout ----------------------------------------------------------------------------
    def block_path(self, k: int, part: str = "F") -> Path:
        """The file of block ``k`` of F (``part="F"``) or of G (``part="G"``)."""
        folder, prefix = PARTS[part]
        return self.path / folder / f"{prefix}{k:06d}.npz"

    def block_range(self, k: int) -> range:
        """The scene rows held by block ``k``."""
        if not 0 <= k < self.n_blocks:
            raise InvalidInputError(f"block index {k} outside 0..{self.n_blocks - 1}")
        return range(k * self.block_rows, min(self.n_patches, (k + 1) * self.block_rows))

    def _columns(self, part: str) -> int:
        if part == "F":
            return self.n_patches
        if part == "G":
            return self._require_clusters()["n_clusters"]
        raise InvalidInputError(f'part must be "F" or "G"; got {part!r}')

    # -- writing ---------------------------------------------------------------------------
    def write_block(self, k: int, block, part: str = "F") -> int:
        """Write rows ``block_range(k)`` of F (or of G) as one compressed, checksummed file; returns its size in bytes.

        ``block`` is a sparse (rows in block, N) matrix (C columns for G) of float32-representable
        form factors (finite, >= 0). The file appears whole or not at all.
        """
        rows = self.block_range(k)
        return _write_csr(self.block_path(k, part), k, rows, block, self._columns(part), self._binding(k, part))

    def _binding(self, k: int, part: str) -> str:
        """What block ``k`` of ``part`` belongs to, hashed into its checksum: this store's scene
        geometry and parameters (resolution, samples, patching; for G its clusters), the part and the block."""
        h = self.header
        key = {
            "geometry_hash": h["geometry_hash"],
            "n_patches": h["n_patches"],
            "block_rows": h["block_rows"],
            "params": h["params"],
            "part": part,
            "block": int(k),
        }
        if part == "G":
            key["prolongation_sha256"] = self._require_clusters().get("prolongation_sha256")
        return json.dumps(key, sort_keys=True)

    @property
    def legacy(self) -> bool:
        """Whether this store's blocks may carry the plain checksum of the format from before
        checksums were bound to their store. Decided once per store, from its header
        (``"checksums": "bound"``, which every store made since records) or, for a header
        without it, from its blocks: legacy only where no finished block of F or G (nor a pose
        file) is bound. A block from another store rewritten in the old format then fails in a
        store of bound blocks, rather than being checked with the plain checksum."""
        if self._legacy is None:
            if self.header.get("checksums") == "bound":
                self._legacy = False
            else:
                files = [self.block_path(k, part) for part in PARTS for k in range(self.n_blocks)]
                self._legacy = not any(_is_bound(f) for f in files + self.pose_files())
        return self._legacy

    def remove_stale_temporaries(self) -> int:
        """Delete temporary files left by interrupted writers; returns how many. Not while a writer runs."""
        n = 0
        for p in (*(self.path / folder for folder, _ in PARTS.values()), self.path / POSE_DIR, self.path):
            for t in p.glob(f"*{TMP_MARK}*"):
                t.unlink(missing_ok=True)
                n += 1
        return n

    # -- reading ---------------------------------------------------------------------------
    def read_block(self, k: int, part: str = "F") -> sp.csr_matrix:
        """Block ``k`` of F (or of G) as a (rows in block, N or C) float32 CSR matrix, checksum verified."""
        rows = self.block_range(k)
        what = f"block {k} (rows {rows.start}..{rows.stop - 1})" + (" of G" if part == "G" else "")
        return _read_csr(
            self.block_path(k, part), k, rows, self._columns(part), what, self.path, self._binding(k, part), self.legacy
        )

    def rows(self, idx, part: str = "F") -> sp.csr_matrix:
        """Rows ``idx`` of F (or of G) as a (len(idx), N or C) float32 CSR matrix, in the order given."""
        idx = patch_indices(idx, self.n_patches, "row indices")
        if idx.size == 0:
            return sp.csr_matrix((0, self._columns(part)), dtype=np.float32)
        blocks = idx // self.block_rows
        order = np.argsort(blocks, kind="stable")
        parts = []
        for k, first, count in zip(*np.unique(blocks[order], return_index=True, return_counts=True)):
            sel = order[first : first + count]
            parts.append(self.read_block(int(k), part)[idx[sel] - k * self.block_rows])
        stacked = sp.vstack(parts, format="csr")
        # stacked holds the rows in block order; put them back in the caller's order.
        return stacked[np.argsort(order, kind="stable")].astype(np.float32)

    # -- the far field's G -----------------------------------------------------------------
    def _read_cluster_header(self) -> dict | None:
        try:
            header = json.loads((self.path / CLUSTER_HEADER).read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as exc:
            raise StoreCorruptError(f"unreadable {self.path / CLUSTER_HEADER}: {exc}") from exc
        # Every field a reader takes, checked once here ({} and "n_clusters": "48" had crashed them).
        where = self.path / CLUSTER_HEADER
        if not isinstance(header, dict):
            raise StoreCorruptError(f"{where} must hold a JSON object; got {type(header).__name__}")
        positive = lambda v: isinstance(v, int) and not isinstance(v, bool) and 1 <= v < 2**31  # noqa: E731
        for name, ok, kind in (
            ("n_clusters", positive, "a positive integer"),
            ("resolution", positive, "a positive integer"),
            ("prolongation_sha256", lambda v: isinstance(v, str), "a string"),
            ("basis", lambda v: v in CLUSTER_BASES, f"one of {CLUSTER_BASES}"),
            ("params", lambda v: isinstance(v, dict), "an object"),
        ):
            if name in header or name in ("n_clusters", "resolution", "prolongation_sha256"):
                if not ok(header.get(name)):
                    raise StoreCorruptError(f"{where}: {name} must be {kind}; got {header.get(name)!r}")
        return header

    def _require_clusters(self) -> dict:
        if self._cluster_header is None:
            raise StoreIncompleteError(
                f"store {self.path} holds no patch-to-cluster form factors G; compute them with "
                "compute_store(..., clusters=...) or `pydynrad formfactors SCENE -o STORE --clusters C`"
            )
        return self._cluster_header

    @property
    def has_clusters(self) -> bool:
        """Whether clusters (a prolongation) are recorded, so G's blocks can be written and read."""
        return self._cluster_header is not None

    @property
    def n_clusters(self) -> int:
        """G's columns: C, or 3C for the linear basis (:attr:`cluster_count` is C)."""
        return int(self._require_clusters()["n_clusters"])

    @property
    def cluster_count(self) -> int:
        """C, the clusters G was made for."""
        return self.n_clusters // (LINEAR_FUNCTIONS if self.cluster_basis == "linear" else 1)

    @property
    def cluster_params(self) -> dict:
        """How the clusters were made, as recorded by :meth:`set_clusters`."""
        return dict(self._require_clusters().get("params", {}))

    @property
    def cluster_resolution(self) -> int:
        """The hemicube resolution G is computed with."""
        return int(self._require_clusters()["resolution"])

    def set_clusters(self, clusters, *, resolution: int, params: dict | None = None, basis: str = "indicator") -> None:
        """Record the prolongation Pr (N, C) that G = F Pr is made with, and G's resolution.

        ``clusters``: Pr itself, (N,) cluster labels or a :class:`pydynrad.farfield.Clusters`
        (both meaning the indicator). Entries are stored in float32 (G's precision). Setting the same clusters again is a
        no-op; other clusters or another resolution raise :class:`StoreMismatchError` (a
        store holds one G). ``params`` (JSON) records how the clusters were made.
        """
        integer(resolution, "cluster resolution (G's hemicube pixels per side)")
        pr, digest = self._canonical_prolongation(clusters)
        _check_basis(pr, basis)
        try:
            extra = json.loads(json.dumps(dict(params or {}), sort_keys=True))
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(f"cluster parameters must be JSON-serialisable: {exc}") from exc
        header = {
            "n_clusters": int(pr.shape[1]),
            "resolution": int(resolution),
            "prolongation_sha256": digest,
            "basis": basis,
        }
        if self._cluster_header is not None:
            self._match_clusters(header)  # params are a record of how, not part of what G is
            try:
                self.prolongation()
            except (StoreCorruptError, StoreIncompleteError):
                # Damaged or lost: these clusters are the recorded ones (their digest matched), so
                # the file is rewritten from them; G's blocks are bound to the digest, not the file.
                _write_csr(self.path / PROLONGATION, 0, range(self.n_patches), pr, pr.shape[1])
            return
        header["params"] = extra
        _write_csr(self.path / PROLONGATION, 0, range(self.n_patches), pr, pr.shape[1])
        (self.path / PARTS["G"][0]).mkdir(exist_ok=True)
        write_atomic(self.path / CLUSTER_HEADER, json.dumps(header, indent=2, sort_keys=True).encode())
        self._cluster_header = header

    def _match_clusters(self, want: dict) -> None:
        have = {"basis": "indicator", **self._require_clusters()}  # stores from before the linear basis
        diff = [f"{k}: store has {have.get(k)!r}, requested {v!r}" for k, v in want.items() if have.get(k) != v]
        if diff:
            raise StoreMismatchError(
                f"store {self.path} holds G for other clusters or parameters ({'; '.join(diff)}); use another "
                f"store, or delete {CLUSTER_HEADER}, {PROLONGATION} and {PARTS['G'][0]}/ there to replace G"
            )

    def _canonical_prolongation(self, clusters) -> tuple[sp.csr_matrix, str]:
        pr = as_prolongation(clusters, self.n_patches).astype(np.float32)
        return pr, _digest(pr.indptr.astype(np.int64), pr.indices.astype(np.int32), pr.data)

    def check_clusters(self, clusters) -> None:
        """Raise :class:`StoreMismatchError` unless ``clusters`` (as for :meth:`set_clusters`) are the ones G was made with."""
        pr, digest = self._canonical_prolongation(clusters)
        self._match_clusters({"n_clusters": int(pr.shape[1]), "prolongation_sha256": digest})

    def prolongation(self) -> sp.csr_matrix:
        """The (N, C) float32 prolongation G was made with, checksum verified."""
        h = self._require_clusters()
        pr = _read_csr(
            self.path / PROLONGATION, 0, range(self.n_patches), h["n_clusters"], "the prolongation", self.path
        )
        if _digest(pr.indptr.astype(np.int64), pr.indices, pr.data) != h["prolongation_sha256"]:
            raise StoreCorruptError(f"{self.path / PROLONGATION} is not the prolongation {CLUSTER_HEADER} records")
        return pr

    def cluster_labels(self) -> np.ndarray:
        """(N,) int: each patch's cluster (-1 for none), for a prolongation with one entry per row
        or a piecewise-linear one (:func:`pydynrad.farfield.clusters.linear_basis`)."""

        pr = self.prolongation()
        single = split_prolongation(pr) if self.cluster_basis != "linear" else None
        labels = single[0] if single is not None else labels_of_linear(pr)
        if labels is None:
            raise InvalidInputError(f"the prolongation of store {self.path} puts some patches in several clusters")
        return labels

    @property
    def cluster_basis(self) -> str:
        """The coarse basis G was made for: "indicator", "linear"
        (:func:`pydynrad.farfield.clusters.linear_basis`) or "given" (a prolongation matrix)."""
        return self._require_clusters().get("basis", "indicator")

    def cluster_rows(self, idx) -> sp.csr_matrix:
        """Rows ``idx`` of G as a (len(idx), C) float32 CSR matrix, in the order given."""
        return self.rows(idx, part="G")

    def check_whole_g(self, clusters=None) -> None:
        """Raise unless every block of G is here (:class:`StoreIncompleteError`) and, given
        ``clusters``, G was made with them (:class:`StoreMismatchError`)."""
        if clusters is not None:
            self.check_clusters(clusters)
        missing = self.missing_blocks(part="G")
        if missing:
            raise StoreIncompleteError(
                f"{len(missing)} of {self.n_blocks} blocks of G in store {self.path} have not "
                "been computed; run compute_store with the same clusters to finish them"
            )

    def cluster_form_factors(self, clusters=None) -> sp.csr_matrix:
        """The whole (N, C) float32 G; with ``clusters``, first checked to be the ones G was made with."""
        self.check_whole_g(clusters)
        return sp.vstack([self.read_block(k, "G") for k in range(self.n_blocks)], format="csr")

    # -- per-pose rows of moving objects ---------------------------------------------------
    # The paper's precomputed variant (docs/design.md, 'Moving objects'): for each configuration
    # of the objects' transforms, the rows of the object patches and of the static patches that
    # may see them, over the world's patches (the static scene's N, then each object's). A
    # separate part of the store: POSE_HEADER names the objects (their geometry hashes, in
    # order) and the rows' resolution; each configuration is one (world N, world N) CSR file
    # in POSE_DIR holding only its rows, bound to the objects and to its transforms.
    def _pose_layout(self, key: str) -> tuple[int, str]:
        """(world N, checksum binding) of configuration ``key``, from one read of POSE_HEADER."""
        h, objects = self.header, self._require_pose_header()
        n = self.n_patches + sum(int(o["n_patches"]) for o in objects["objects"])
        return n, json.dumps(
            {
                "geometry_hash": h["geometry_hash"],
                "n_patches": h["n_patches"],
                "part": "pose",
                "objects": objects,
                "transforms_sha256": key,
            },
            sort_keys=True,
        )

    def _require_pose_header(self) -> dict:
        try:
            header = json.loads((self.path / POSE_HEADER).read_text())
        except FileNotFoundError:
            raise StoreIncompleteError(
                f"store {self.path} holds no per-pose rows of moving objects; precompute them "
                "with pydynrad.precompute.precompute_poses(..., store=...)"
            ) from None
        except (OSError, ValueError) as exc:
            raise StoreCorruptError(f"unreadable {self.path / POSE_HEADER}: {exc}") from exc
        objects = header.get("objects") if isinstance(header, dict) else None
        if not (isinstance(objects, list) and all(isinstance(o, dict) for o in objects)):
            raise StoreCorruptError(f"{self.path / POSE_HEADER} must hold an object with a list of 'objects'")
        return header

    @staticmethod
    def _pose_objects(objects, resolution: int) -> dict:
        objs = [{"name": o.name, "geometry_hash": o.scene.geometry_hash(), "n_patches": len(o)} for o in objects]
        return {"objects": objs, "resolution": int(checked_resolution(resolution))}

    def set_pose_objects(self, objects, *, resolution: int) -> None:
        """Record which moving objects (RigidObjects, in order) the per-pose rows are of, at
        hemicube ``resolution``. The same objects again is a no-op; others raise
        :class:`StoreMismatchError` (a store holds the poses of one set of objects)."""
        want = self._pose_objects(objects, resolution)
        if (self.path / POSE_HEADER).exists():
            self.check_pose_objects(objects, resolution=resolution)
            return
        (self.path / POSE_DIR).mkdir(exist_ok=True)
        write_atomic(self.path / POSE_HEADER, json.dumps(want, indent=2, sort_keys=True).encode())

    def check_pose_objects(self, objects, *, resolution: int) -> None:
        """Raise :class:`StoreMismatchError` unless the per-pose rows are of ``objects`` at ``resolution``."""
        want, have = self._pose_objects(objects, resolution), self._require_pose_header()

        def strip(h: dict) -> tuple:
            return h.get("resolution"), [(o.get("geometry_hash"), o.get("n_patches")) for o in h.get("objects", [])]

        if strip(want) != strip(have):
            raise StoreMismatchError(
                f"store {self.path} holds per-pose rows of other objects or another resolution (store: "
                f"{_described(have)} at R = {have.get('resolution')}; requested: {_described(want)} at R = "
                f"{want['resolution']}; objects of the same name differ in geometry where their hashes do)"
            )

    @staticmethod
    def pose_key(transforms) -> str:
        """SHA-256 of a configuration: the (n_objects, 4, 4) float64 transforms' bytes."""
        return hashlib.sha256(np.ascontiguousarray(np.asarray(transforms, np.float64)).tobytes()).hexdigest()

    def _pose_path(self, key: str) -> Path:
        return self.path / POSE_DIR / f"p{key[:32]}.npz"

    def has_pose(self, transforms) -> bool:
        return self._pose_path(self.pose_key(transforms)).exists()

    def pose_files(self) -> list[Path]:
        """The files of the pose configurations written so far (one per configuration)."""
        return sorted((self.path / POSE_DIR).glob("p*.npz"))

    def verify_poses(self, remove: bool = False) -> dict[str, list[Path]]:
        """Check every per-pose file: ``{"verified": [...], "corrupt": [...]}`` (paths). A file's
        name keeps part of its configuration's key, not the whole one its checksum is bound to, so
        this checks that it decodes whole (every zip CRC) and holds a square CSR block of the
        world's N; :meth:`read_pose` checks the binding when it is read. With ``remove`` the
        corrupt files are deleted: :func:`pydynrad.precompute.precompute_poses` (``pydynrad
        formfactors --poses``) then computes those configurations again."""
        found: dict[str, list[Path]] = {"verified": [], "corrupt": []}
        files = self.pose_files()
        n = self.n_patches + sum(int(o["n_patches"]) for o in self._require_pose_header()["objects"]) if files else 0
        for path in files:
            ok = _intact(path)
            if ok:
                try:
                    with zipfile.ZipFile(path) as zf:
                        meta = json.loads(zf.read("meta.json"))
                    ok = isinstance(meta, dict) and meta.get("row_start") == 0 and meta.get("row_stop") == n
                except DECODE_ERRORS:
                    ok = False
            found["verified" if ok else "corrupt"].append(path)
        if remove:
            for path in found["corrupt"]:
                path.unlink(missing_ok=True)
        return found

    def write_pose(self, transforms, patches: np.ndarray, rows) -> int:
        """Write the rows ``rows`` (len(patches), world N) of ``patches`` at ``transforms``, one
        checksummed file, atomically; returns its size in bytes."""
        key = self.pose_key(transforms)
        n, binding = self._pose_layout(key)
        patches = patch_indices(patches, n, "pose patches", unique=True)
        rows = sp.csr_matrix(rows)
        if rows.shape != (len(patches), n):
            raise InvalidInputError(f"pose rows must have shape ({len(patches)}, {n}); got {rows.shape}")
        place = sp.csr_matrix((np.ones(len(patches)), (patches, np.arange(len(patches)))), shape=(n, len(patches)))
        full = sp.csr_matrix(place @ rows)
        return _write_csr(self._pose_path(key), 0, range(n), full, n, binding)

    def read_pose(self, transforms) -> tuple[np.ndarray, sp.csr_matrix] | None:
        """(patch indices, their rows, float32) stored for ``transforms``, checksum verified, or
        None when this configuration was not precomputed. A row written empty is not told apart
        from one not written: a reader computes it again (and gets it empty)."""
        key = self.pose_key(transforms)
        path = self._pose_path(key)
        if not path.exists():
            return None
        n, binding = self._pose_layout(key)
        full = _read_csr(path, 0, range(n), n, f"per-pose rows {path.name}", self.path, binding, self.legacy)
        patches = np.flatnonzero(np.diff(full.indptr))
        return patches, full[patches]

    # -- state -----------------------------------------------------------------------------
    def missing_blocks(self, verify: bool = False, part: str = "F") -> list[int]:
        """Blocks of F (or of G) not yet on disk; with ``verify``, also blocks whose checksum fails."""
        if not verify:
            self._columns(part)
            return [k for k in range(self.n_blocks) if not self.block_path(k, part).exists()]
        found = self.verify(part)
        self._refuse_edited_header(found, part)  # before any of them is recomputed over
        return sorted(found["missing"] + found["corrupt"])

    def verify(self, part: str = "F", remove: bool = False) -> dict[str, list[int]]:
        """Read every finished block of F (or of G) and check it against its checksum, bound to this store.

        Returns ``{"verified": [...], "missing": [...], "corrupt": [...]}``: block indices that
        pass, that are not on disk, and that fail (unreadable, another store's or block's, or
        altered). With ``remove`` the corrupt files are deleted, so :func:`compute_store`
        (or ``pydynrad formfactors`` run again) recomputes them with the missing ones.
        """
        self._columns(part)
        found: dict[str, list[int]] = {"verified": [], "missing": [], "corrupt": []}
        for k in range(self.n_blocks):
            try:
                self.read_block(k, part)
                found["verified"].append(k)
            except StoreIncompleteError:
                found["missing"].append(k)
            except StoreCorruptError:
                found["corrupt"].append(k)
        if remove:
            self._refuse_edited_header(found, part)  # before anything is removed
            for k in found["corrupt"]:
                self.block_path(k, part).unlink(missing_ok=True)
        return found

    def _refuse_edited_header(self, found: dict[str, list[int]], part: str) -> None:
        """StoreMismatchError where no finished block verifies and two or more are intact (every
        zip CRC holds) yet fail their checksum: they were bound to another header, so this
        header was edited after they were written (or the whole folder is another store's).
        Deleting or recomputing them would throw away valid work before the parameters could be
        told apart; a resume over an edited header had deleted 36 valid blocks before refusing."""
        if found["verified"]:
            return
        intact = [k for k in found["corrupt"] if _intact(self.block_path(k, part))]
        if len(intact) >= 2:
            raise StoreMismatchError(
                f"store {self.path}: none of its {len(found['corrupt'])} finished blocks"
                f"{' of G' if part == 'G' else ''} matches its header, though {len(intact)} are intact: "
                f"{HEADER} was edited after they were written (or they are another store's). Nothing was "
                f"deleted; restore {HEADER}, or remove the folder to compute the store afresh"
            )

    @property
    def complete(self) -> bool:
        """Every block of F is on disk."""
        return not self.missing_blocks()

    @property
    def complete_clusters(self) -> bool:
        """Clusters are recorded and every block of G is on disk."""
        return self.has_clusters and not self.missing_blocks(part="G")

    @property
    def nbytes_on_disk(self) -> int:
        """Bytes of the headers, the prolongation and every finished block file of F and G."""
        files = [
            self.path / HEADER,
            self.path / CLUSTER_HEADER,
            self.path / PROLONGATION,
            self.path / POSE_HEADER,
            *(f for folder, prefix in PARTS.values() for f in (self.path / folder).glob(f"{prefix}*.npz")),
            *self.pose_files(),
        ]
        return sum(p.stat().st_size for p in files if p.exists())

    def to_csr(self) -> sp.csr_matrix:
        """The whole (N, N) matrix in memory: only for stores that fit in RAM."""
        return sp.vstack([self.read_block(k) for k in range(self.n_blocks)], format="csr")

    def __repr__(self) -> str:
        done = self.n_blocks - len(self.missing_blocks())
        g = ""
        if self.has_clusters:
            g = (
                f", G: C={self.n_clusters}, {self.n_blocks - len(self.missing_blocks(part='G'))}/{self.n_blocks} "
                f"blocks, resolution={self.cluster_resolution}"
            )
        return (
            f"FormFactorStore({str(self.path)!r}, N={self.n_patches}, {done}/{self.n_blocks} blocks of "
            f"{self.block_rows} rows, resolution={self.header['params']['resolution']}{g})"
        )


#: The coarse bases a store records G for: those of :data:`pydynrad.farfield.gather.BASES`, or a
#: prolongation matrix given as it is.
CLUSTER_BASES = ("indicator", "linear", "given")


def _check_basis(pr: sp.csr_matrix, basis: str) -> None:
    """InvalidInputError unless ``pr`` has the layout of ``basis``: what the store records is what
    :attr:`FormFactorStore.cluster_labels` and :attr:`FormFactorStore.cluster_count` read back."""
    if basis not in CLUSTER_BASES:
        raise InvalidInputError(f"the cluster basis must be one of {CLUSTER_BASES}; got {basis!r}")
    if basis == "indicator":
        ok = np.all(np.diff(pr.indptr) == 1) and np.all(pr.data == 1)
    elif basis == "linear":
        # Three functions per cluster summing to 1 on each patch; those in columns >= C are u/2 and v/2.
        C = pr.shape[1] // LINEAR_FUNCTIONS
        sums = np.asarray(pr.sum(axis=1)).ravel()
        ok = (
            labels_of_linear(pr) is not None
            and np.allclose(sums, 1.0, rtol=0, atol=1e-6)
            and np.all(pr.data[pr.indices >= C] <= 0.5 + 1e-6)
        )
    else:
        ok = True
    if not ok:
        raise InvalidInputError(
            f"the prolongation is not one of the {basis!r} basis "
            "(pydynrad.farfield.gather.basis_prolongation); record it with basis='given'"
        )
