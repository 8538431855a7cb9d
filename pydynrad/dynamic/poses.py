"""The rows of F at each stored pose of the moving objects (the paper's variant: every pose of a
path precomputed), held in memory or read back from a store.

See docs/design.md, 'Moving objects'.
"""

from __future__ import annotations

import threading

import numpy as np
import scipy.sparse as sp

from ..errors import InvalidInputError

__all__ = ["PoseRows"]


class PoseRows:
    """Rows precomputed for poses of the objects known in advance (the paper's section 3.2).

    Keyed by the objects' transforms together (a row of a static patch depends on every
    object): for each configuration, the rows of the object patches and of the static patches
    that may see an object there (:func:`~pydynrad.dynamic.occlusion.refresh_order`). A move to a stored configuration
    takes those rows from here instead of hemicubes. Made by :func:`precompute_poses`; held in
    memory, or read from a form-factor store's per-pose part (``store``, each file verified on
    read) with the last configuration read kept.
    """

    def __init__(self, n_patches: int, resolution: int, geometry: tuple[str, tuple[str, ...]], store=None) -> None:
        self.n_patches, self.resolution = int(n_patches), int(resolution)
        # (the static scene's geometry hash, each object's): rows of other geometry with the same
        # patch counts would be taken as these (:meth:`check`).
        self.geometry = (str(geometry[0]), tuple(map(str, geometry[1])))
        self.store = store
        self._rows: dict[bytes, tuple[np.ndarray, sp.csr_matrix]] = {}
        self._last: tuple[bytes, tuple | None] | None = None  # (key, entry) last read from the store
        # A move asks from two threads at once (the objects' rows on a pool thread, the static
        # rows here): one of them reads and verifies the file, the other waits for it.
        self._reading = threading.Lock()

    @staticmethod
    def geometry_of(scene, objects) -> tuple[str, tuple[str, ...]]:
        """The fingerprint :attr:`geometry` of rows made for static ``scene`` and ``objects``."""
        return scene.geometry_hash(), tuple(o.scene.geometry_hash() for o in objects)

    def check(self, scene, objects, resolution: int) -> None:
        """Raise InvalidInputError unless these rows are of ``scene`` with ``objects`` at ``resolution``."""
        n = len(scene) + sum(len(o) for o in objects)
        if self.n_patches != n or self.resolution != resolution:
            raise InvalidInputError(
                f"poses= holds rows of {self.n_patches} patches at R = {self.resolution}; this "
                f"scene with its objects has {n} patches at R = {resolution}"
            )
        static, objs = self.geometry_of(scene, objects)
        if static != self.geometry[0]:
            raise InvalidInputError(
                f"poses= holds rows made for another static scene than {scene.name!r} (its "
                "geometry differs): precompute them for this one"
            )
        if objs != self.geometry[1]:
            raise InvalidInputError(
                f"poses= holds rows made for other objects than {[o.name for o in objects]} (their "
                "geometry differs): precompute them for these"
            )

    @staticmethod
    def key(transforms) -> bytes:
        return np.ascontiguousarray(np.asarray(transforms, np.float64)).tobytes()

    def add(self, transforms, patches: np.ndarray, rows: sp.csr_matrix) -> None:
        order = np.argsort(patches)
        patches, rows = np.asarray(patches, np.int64)[order], sp.csr_matrix(rows)[order]
        if self.store is None:
            self._rows[self.key(transforms)] = (patches, rows)
        else:
            self.store.write_pose(transforms, patches, rows)

    def get(self, transforms):
        """(sorted patch indices, their rows) stored for these transforms, or None."""
        key = self.key(transforms)
        if self.store is None:
            return self._rows.get(key)
        with self._reading:
            if self._last is None or self._last[0] != key:
                self._last = (key, self.store.read_pose(transforms))
            return self._last[1]

    def __contains__(self, transforms) -> bool:
        return self.key(transforms) in self._rows if self.store is None else self.store.has_pose(transforms)

    def __len__(self) -> int:
        return len(self._rows) if self.store is None else len(self.store.pose_files())

    @property
    def nbytes(self) -> int:
        """Host bytes of the rows held in memory (0 for a store's: read per configuration)."""
        return sum(p.nbytes + r.data.nbytes + r.indices.nbytes + r.indptr.nbytes for p, r in self._rows.values())
