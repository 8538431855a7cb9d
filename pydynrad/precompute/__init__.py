"""Work done before a walk: filling form-factor stores (in process or with Dask) and objects' poses.

* :mod:`.distributed`: :func:`precompute_distributed`, a store filled by a Dask cluster
  (the ``dask`` extra);
* :mod:`pydynrad.rows.store`'s :func:`~pydynrad.rows.store.compute_store` fills one in process.
"""

from ..dynamic.moves import PoseRows, precompute_poses, stored_poses
from .distributed import SceneSpec, precompute_distributed

__all__ = ["PoseRows", "SceneSpec", "precompute_distributed", "precompute_poses", "stored_poses"]
